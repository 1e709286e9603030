"""``codegen``: the board's side of the protocol, generated from its declarations (the same
as ``python -m fpgalink.codegen``; see docs/firmware.md)."""

from __future__ import annotations

from pathlib import Path

import click

from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, echo_out

__all__ = ["codegen"]


@click.command(epilog=EXIT_CODES_HELP)
@click.argument("language", type=click.Choice(["c"]))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
def codegen(language: str, outdir: Path) -> int:
    """Generate the board's protocol code (C: header, codec, self-test, Makefile) into OUTDIR.

    Then `make -C OUTDIR` builds it and `make -C OUTDIR check` runs its golden vectors.
    """
    from fpgalink.codegen import write_c

    try:
        written = write_c(outdir)
    except OSError as exc:
        raise CliError(f"{outdir}: cannot write: {exc.strerror or exc}",
                       ExitCode.FAILURE) from None
    for path in written:
        echo_out(str(path))
    return ExitCode.OK
