"""The files a command writes (recordings, bags, plots, CSV, parameter dumps, a campaign's
results): one rule for all, through :mod:`fpgalink.recording.files`. A target that exists is
refused unless ``--force`` (one line naming it and the flag, exit 2), checked before any
work; what is written goes under ``NAME.partial`` and is renamed into place only when
complete; a target another process is writing now is refused (exit 5)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import IO, TypeVar

import click

from fpgalink.cli.output import classify
from fpgalink.recording import Output, RecordingError, check_target

__all__ = ["FORCE_HELP", "check_output", "force_option", "write_file"]

T = TypeVar("T")

FORCE_HELP = ("Replace what this writes if it exists already (without --force an existing "
              "file or directory is refused, exit 2).")


def force_option(func: Callable[..., T]) -> Callable[..., T]:
    """``--force``: the command may replace the files it writes."""
    return click.option("--force", is_flag=True, help=FORCE_HELP)(func)


def check_output(path: Path, *, force: bool, directory: bool = False) -> None:
    """Refuse, before any work, a target this command cannot write: it exists (without
    ``--force``), is of the wrong kind, its directory is missing, or another process is
    writing it now — one line and its exit code."""
    try:
        check_target(path, force=force, directory=directory)
    except RecordingError as exc:
        raise classify(exc) from None


def write_file(path: Path, data: bytes | Callable[[IO[bytes]], None], *, force: bool) -> None:
    """Write a whole file through ``NAME.partial`` and put it in place: ``data``, or what
    ``data(stream)`` writes into the stream it is given. Any failure is one line (exit 1 for a
    write error), nothing left behind."""
    try:
        output = Output(path, force=force)
        try:
            with output.file() as stream:
                if isinstance(data, bytes):
                    stream.write(data)
                else:
                    data(stream)
        except OSError as exc:
            output.discard()
            raise RecordingError(f"{path}: cannot write: {exc.strerror or exc}; nothing was "
                                 "left") from None
        except BaseException:
            output.discard()
            raise
        output.commit()
    except RecordingError as exc:
        raise classify(exc) from None
