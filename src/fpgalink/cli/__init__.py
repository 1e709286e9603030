"""``fpgalink-cli``: talk to a board (or the built-in emulator) from the shell.

Commands: ``send``, ``param get|set|list|load|dump``, ``monitor``, ``record``, ``step``,
``budget``. Every failure is one line on stderr and a documented exit code
(:class:`~fpgalink.cli.output.ExitCode`); see ``docs/cli.md``.
"""

from __future__ import annotations

import sys

import click

from fpgalink import __version__
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, quiet_stdout

__all__ = ["cli", "main"]


@click.group(
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
    epilog=EXIT_CODES_HELP,
)
@click.version_option(__version__, prog_name="fpgalink-cli")
def cli() -> None:
    """Talk to an FPGA motor-controller board over its UART protocol.

    Every command that talks to a board takes --port (a device path, socket://HOST:PORT or
    emu://), --baud, --timeout and --retries, also read from FPGALINK_PORT / FPGALINK_BAUD.
    With no port anywhere it runs against the built-in emulator (emu://).
    """


def _register() -> None:
    # Imported here so `fpgalink-cli --help` stays quick and each module owns its command.
    from fpgalink.cli import budget, monitor, param, record, send, step

    for command in (send.send, param.param, monitor.monitor, record.record, step.step,
                    budget.budget):
        cli.add_command(command)


_register()


def main(argv: list[str] | None = None) -> None:
    """Console-script entry: run the CLI and turn every outcome into an exit code."""
    try:
        result = cli.main(args=argv, prog_name="fpgalink-cli", standalone_mode=False)
    except CliError as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.ClickException as exc:  # usage errors: click's own message, exit 2
        exc.show()
        sys.exit(exc.exit_code)
    except (click.Abort, KeyboardInterrupt):
        click.echo("fpgalink-cli: interrupted", err=True)
        sys.exit(ExitCode.INTERRUPTED)
    except BrokenPipeError:
        quiet_stdout()
        sys.exit(ExitCode.OK)
    sys.exit(result if isinstance(result, int) else ExitCode.OK)

