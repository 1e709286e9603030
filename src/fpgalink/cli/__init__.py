"""``fpgalink-cli``: talk to a board (or the built-in emulator) from the shell.

Every failure is one line on stderr starting ``fpgalink-cli: error:`` and a documented exit
code (:class:`~fpgalink.cli.output.ExitCode`); see ``docs/cli.md``. Commands load on first
use, so ``--help`` and a quick ``param get`` do not pay for the others' imports.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

import click

from fpgalink import __version__
from fpgalink.buildinfo import BUILD
from fpgalink.cli.options import global_connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, classify, quiet_stdout
from fpgalink.protocol.errors import FpgalinkError

__all__ = ["COMMANDS", "cli", "main"]

#: name → (module, attribute, one-line help). The help is declared here so listing the
#: commands imports none of them; a test checks it matches each command's own.
COMMANDS: dict[str, tuple[str, str, str]] = {
    "param": ("fpgalink.cli.param", "param",
              "Read and write board parameters (confirmed by the board's echo)."),
    "monitor": ("fpgalink.cli.monitor", "monitor",
                "Watch telemetry of both channels and the link's health, live."),
    "record": ("fpgalink.cli.record", "record",
               "Record telemetry, parameter changes and link events into FILE (or a rosbag2)."),
    "step": ("fpgalink.cli.step", "step",
             "Step the speed reference of one channel and measure the response."),
    "send": ("fpgalink.cli.send", "send",
             "Send one message with ID and print it; with --reply, wait for the reply."),
    "drive": ("fpgalink.cli.drive", "drive",
              "Drive the robot at --v and --omega, holding the deadman, with a live view."),
    "goto": ("fpgalink.cli.goto", "goto",
             "Drive the robot to X Y (m, in the odometry frame of the start) and stop there."),
    "budget": ("fpgalink.cli.budget", "budget",
               "Static timing budget: wire bytes per period and utilisation per direction."),
    "plot": ("fpgalink.cli.plot", "plot",
             "Plot fields of a recording against time into a PNG."),
    "ports": ("fpgalink.cli.ports", "ports",
              "List serial ports, mark the board's USB-UART, check its latency timer."),
    "config": ("fpgalink.cli.config", "config",
               "Show the connection settings in force and where each came from."),
    "router": ("fpgalink.cli.router", "router",
               "Share each board among several local clients: one controller, observers "
               "read-only."),
    "campaign": ("fpgalink.cli.campaign", "campaign",
                 "Run the scenarios of SPEC.toml on emulated robots and print their figures."),
    "tune": ("fpgalink.cli.campaign", "tune",
             "Pick the wheel PID gains that settle a step soonest, from a grid."),
    "codegen": ("fpgalink.cli.codegen", "codegen",
                "Generate the board's protocol code (C: header, codec, self-test, Makefile) "
                "into OUTDIR."),
    "identify": ("fpgalink.cli.identify", "identify",
                 "Identify one wheel's plant: duty in, speed out, fitted in the seed's form."),
    "autotune": ("fpgalink.cli.autotune", "autotune",
                 "Tune the wheels' speed PIDs from their identified plants, every board and "
                 "channel."),
    "calibrate": ("fpgalink.cli.calibrate", "calibrate",
                  "Calibrate odometry: χ from a turn in place, the wheel radius from a straight "
                  "run."),
}


class ReaderGone(Exception):
    """stdout's reader went away (``| head -1``). Not an OSError, so click does not turn it
    into a silent exit 1 on its way out: the entry point ends quietly with 0."""


class LazyGroup(click.Group):
    """Imports a command's module only when that command runs (or asks for its help)."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except BrokenPipeError:
            raise ReaderGone from None

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        entry = COMMANDS.get(cmd_name)
        if entry is None:
            return None
        module, attribute, _ = entry
        command = getattr(importlib.import_module(module), attribute)
        assert isinstance(command, click.Command)
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, help_text) for name, (_, _, help_text) in COMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(
    cls=LazyGroup,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
    epilog=EXIT_CODES_HELP,
)
@click.version_option(__version__, prog_name="fpgalink-cli",
                      message=f"%(prog)s, version %(version)s, {BUILD}")
@global_connection_options
@click.pass_context
def cli(ctx: click.Context, /, **options: Any) -> None:
    """Talk to an FPGA motor-controller board over its UART protocol.

    The connection options (--port, --board, --baud, --timeout, --retries, -v, --config) go
    before the command or after it. Without a port anywhere (option, FPGALINK_PORT, the
    config file), commands run against the built-in emulator (emu://).
    """
    ctx.obj = options


def _help_hint(exc: click.ClickException) -> str:
    """Which help a usage error points at: the command's own (``fpgalink-cli param set
    -h``), not only the program's."""
    ctx = getattr(exc, "ctx", None)
    path = ctx.command_path if isinstance(ctx, click.Context) and ctx.command_path else ""
    return f"{path or 'fpgalink-cli'} -h"


def _stdout_failed(exc: OSError) -> None:
    """stdout could not be written (``> /dev/full``): one line, exit 1; what is still
    buffered goes to /dev/null so the interpreter's last flush prints no traceback."""
    click.echo(f"fpgalink-cli: error: cannot write to stdout: {exc.strerror or exc}", err=True)
    quiet_stdout()
    sys.exit(ExitCode.FAILURE)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry: run the CLI and turn every outcome into an exit code."""
    no_args_is_help = getattr(click.exceptions, "NoArgsIsHelpError", None)
    try:
        result = cli.main(args=argv, prog_name="fpgalink-cli", standalone_mode=False)
        sys.stdout.flush()
    except CliError as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except FpgalinkError as exc:  # a library error a command let through: its one line
        error = classify(exc)
        error.show()
        sys.exit(error.exit_code)
    except click.ClickException as exc:
        if no_args_is_help is not None and isinstance(exc, no_args_is_help):
            # A command group without a command (`fpgalink-cli`, `fpgalink-cli param`): its
            # help, exit 0, as fpgaemu does.
            try:
                click.echo(exc.ctx.get_help() if exc.ctx is not None else cli.get_help(
                    click.Context(cli, info_name="fpgalink-cli")))
                sys.stdout.flush()
            except BrokenPipeError:
                quiet_stdout()
            except OSError as error:
                _stdout_failed(error)
            sys.exit(ExitCode.OK)
        # Usage errors: one line, exit 2, pointing at the help of the command concerned.
        message = " ".join(exc.format_message().split())
        click.echo(f"fpgalink-cli: error: {message} (see {_help_hint(exc)})", err=True)
        sys.exit(exc.exit_code)
    except (click.Abort, KeyboardInterrupt):
        click.echo("fpgalink-cli: interrupted", err=True)
        sys.exit(ExitCode.INTERRUPTED)
    except (BrokenPipeError, ReaderGone):
        quiet_stdout()
        sys.exit(ExitCode.OK)
    except OSError as exc:  # click's own output (help, version) into a full disk
        _stdout_failed(exc)
    sys.exit(result if isinstance(result, int) else ExitCode.OK)
