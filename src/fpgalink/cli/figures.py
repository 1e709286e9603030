"""Figures for ``step --plot`` and ``plot``: matplotlib's object API with the Agg canvas (no
pyplot global state, no display), and a path check done before any work. A figure is
written as every file a command writes is (:mod:`fpgalink.cli.files`): an existing one
refused unless ``--force``, the image put in place whole."""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO, TYPE_CHECKING

from fpgalink.cli.files import check_output, write_file
from fpgalink.cli.output import CliError, ExitCode

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PLOT_SUFFIXES", "check_plot_path", "new_figure", "save_figure"]

PLOT_SUFFIXES = (".png", ".svg", ".pdf")  #: what --plot can write (Agg, SVG and PDF backends)


def check_plot_path(path: Path, option: str = "--plot", *, force: bool) -> None:
    """Refuse a plot path that cannot be written, before any work is done: a step takes
    seconds, and its result must not be lost to a typo at the end (or to a file that is
    there, unless ``force``)."""
    if path.suffix.lower() not in PLOT_SUFFIXES:
        raise CliError(f"{option} {path}: the file name must end in "
                       f"{', '.join(PLOT_SUFFIXES)} (the format is taken from it)",
                       ExitCode.BAD_INPUT)
    if path.is_dir():
        raise CliError(f"{option} {path}: is a directory", ExitCode.BAD_INPUT)
    parent = path.parent
    if not parent.is_dir():
        raise CliError(f"{option} {path}: no such directory {parent}", ExitCode.BAD_INPUT)
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and
                                                     not os.access(path, os.W_OK)):
        raise CliError(f"{option} {path}: not writable", ExitCode.BAD_INPUT)
    check_output(path, force=force)
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CliError(f"{option} needs matplotlib: pip install 'fpgalink[plot]'",
                       ExitCode.NOT_INSTALLED) from None


def new_figure(size: tuple[float, float]) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def save_figure(figure: Figure, path: Path, *, force: bool) -> None:
    """Save, whole or not at all, with a failure (full disk, a path gone since the check)
    as one line."""
    def draw(stream: IO[bytes]) -> None:
        figure.savefig(stream, format=path.suffix.lower().lstrip("."), dpi=100)

    write_file(path, draw, force=force)
