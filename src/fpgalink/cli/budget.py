"""``budget``: the static timing-budget calculator (placeholder until fpgalink.budget lands)."""

from __future__ import annotations

import click

from fpgalink.cli._common import CliError, ExitCode

__all__ = ["budget"]


@click.command()
def budget() -> int:
    """Static timing budget per direction (not available yet)."""
    raise CliError("budget: fpgalink.budget is not available yet", ExitCode.FAILURE)
