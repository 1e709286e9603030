"""Helpers shared by the benchmark scripts: where they ran, how long things took, how the
results are shown and kept, and the emulator process the paced benchmarks talk to.

Every script records the machine (CPU model included), the interpreter and the package
versions beside its numbers, and prints them above its table, because a rate means nothing
once it is separated from what produced it. Results go to ``benchmarks/results/<name>.json``
(ignored by git: they describe one machine on one day).

This is the only copy of these helpers: a script that needs another one adds it here.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime as _dt
import gc
import importlib.metadata
import json
import os
import platform
import signal
import statistics
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, TextIO, TypeVar

from tests.support.serving import Served, start_serve

__all__ = [
    "BUILDS",
    "RESULTS_DIR",
    "Summary",
    "build_env",
    "chunked",
    "common_parser",
    "environment_line",
    "machine_info",
    "package_versions",
    "percentile",
    "print_table",
    "python_info",
    "report_header",
    "start_emulator",
    "stop_emulator",
    "summarize",
    "time_once",
    "timestamp",
    "write_results",
]

T = TypeVar("T")

RESULTS_DIR = Path(__file__).resolve().parent / "results"

#: ``{"median": …, "min": …, "max": …}`` of a set of repetitions.
Summary = dict[str, float]

#: How long ``fpgaemu serve`` may take to print its ``ready`` lines: an interpreter start and
#: a board build, which a loaded machine can stretch to seconds.
EMULATOR_READY_TIMEOUT_S = 30.0


# --- where the numbers came from --------------------------------------------------------------


def cpu_model() -> str:
    # platform.processor() is empty on most Linux builds; /proc/cpuinfo names the part.
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, Any]:
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    return {
        "hostname": platform.node(),
        "system": platform.system(),
        "release": platform.release(),
        "machine": platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        # A container may see all host CPUs but be allowed only a few of them.
        "cpus_usable": len(affinity) if affinity is not None else None,
    }


def python_info() -> dict[str, Any]:
    return {
        "version": platform.python_version(),
        "implementation": platform.python_implementation(),
        "compiler": platform.python_compiler(),
        "build": list(platform.python_build()),
        "executable": sys.executable,
    }


def package_versions(names: Iterable[str]) -> dict[str, str | None]:
    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def timestamp() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def report_header(name: str, packages: Iterable[str]) -> dict[str, Any]:
    """The keys every result file starts with, so any report can be read the same way."""
    return {
        "benchmark": name,
        "created": timestamp(),
        "machine": machine_info(),
        "python": python_info(),
        "packages": package_versions(["fpgalink", *packages]),
    }


def environment_line(report: dict[str, Any]) -> str:
    """One line naming the machine and software, printed above every table."""
    m, py = report["machine"], report["python"]
    usable = m["cpus_usable"] if m["cpus_usable"] is not None else m["cpu_count"]
    versions = ", ".join(f"{k} {v}" for k, v in report["packages"].items() if v is not None)
    return (f"{m['cpu_model']} ({usable} of {m['cpu_count']} CPUs usable), {m['system']} "
            f"{m['machine']}, {py['implementation']} {py['version']}; {versions}; "
            f"{report['created']}")


# --- timing -----------------------------------------------------------------------------------


def summarize(values: Sequence[float]) -> Summary:
    """Median and range of the repetitions. The median, not the mean: one repetition slowed
    by another process on a small machine should not move the headline number."""
    if not values:
        raise ValueError("no repetitions to summarize")
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0..100), linear between closest ranks (numpy's default),
    without importing numpy into scripts that do not otherwise need it."""
    if not values:
        raise ValueError("no values")
    ordered = sorted(values)
    rank = (len(ordered) - 1) * q / 100
    low = int(rank)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (rank - low)


def time_once(fn: Callable[[], T]) -> tuple[float, T]:
    """Wall time of one call to ``fn`` (``perf_counter``) and what it returned.

    Garbage from earlier work is collected first, so one case does not pay for another's
    leftovers; the collector stays on while timing, as it would be in real use.
    """
    gc.collect()
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def chunked(wire: bytes, size: int) -> list[bytes]:
    # Sliced up front, so the timed loops measure the code under test and not the slicing.
    return [wire[i : i + size] for i in range(0, len(wire), size)]


# --- the two builds ----------------------------------------------------------------------------

#: The builds a benchmark compares: the compiled one (mypyc, where it is installed) and pure
#: Python (``FPGALINK_PURE=1``), each run in processes of its own.
BUILDS = ("compiled", "pure")


def build_env(build: str) -> dict[str, str]:
    """The environment for a child process on ``build`` (``compiled`` or ``pure``)."""
    env = {k: v for k, v in os.environ.items() if k != "FPGALINK_PURE"}
    if build == "pure":
        env["FPGALINK_PURE"] = "1"
    return env


# --- showing and keeping the results ----------------------------------------------------------


def common_parser(doc: str | None, name: str, quick_help: str) -> argparse.ArgumentParser:
    """A parser with the options every script has: ``--quick`` and ``--output``."""
    parser = argparse.ArgumentParser(
        prog=f"python -m benchmarks.{name}",
        description=doc.split("\n\n", 1)[0] if doc else None,
    )
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--output", type=Path, default=None,
                        help=f"JSON path (default benchmarks/results/{name}.json)")
    return parser


def print_table(
    headers: Sequence[str],
    rows: Sequence[Sequence[str]],
    *,
    align: str | None = None,
    file: TextIO | None = None,
) -> None:
    """An aligned plain-text table. ``align`` has one ``<`` or ``>`` per column (default:
    first column left, the rest right, which suits a name followed by numbers)."""
    out = file if file is not None else sys.stdout
    ncols = len(headers)
    if align is None:
        align = "<" + ">" * (ncols - 1)
    if len(align) != ncols or any(len(row) != ncols for row in rows):
        raise ValueError("every row and the alignment need one entry per column")
    widths = [max(len(headers[c]), *(len(row[c]) for row in rows)) for c in range(ncols)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(f"{cell:{a}{w}}" for cell, a, w in zip(cells, align, widths, strict=True))

    print(line(headers).rstrip(), file=out)
    print("  ".join("-" * w for w in widths), file=out)
    for row in rows:
        print(line(row).rstrip(), file=out)


def write_results(name: str, payload: dict[str, Any], path: Path | None = None) -> Path:
    """Write ``payload`` as JSON to ``path`` (default ``benchmarks/results/<name>.json``)."""
    target = path if path is not None else RESULTS_DIR / f"{name}.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    # Write then rename, so an interrupted run never leaves half a file for a reader. The
    # temporary name keeps the .json suffix so that git ignores it too. allow_nan=False: a
    # NaN would make the file unreadable to strict JSON parsers; a script must say None.
    tmp = target.with_name(f".{target.stem}.tmp{target.suffix}")
    tmp.write_text(json.dumps(payload, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    tmp.replace(target)
    return target


# --- the emulator in its own process ----------------------------------------------------------


async def start_emulator(boards: int, baud: int) -> tuple[Served, list[tuple[str, str]]]:
    """``fpgaemu serve --pty`` in a separate process (tests/support/serving.py, the one way
    it is started), so the board's CPU is not the host's; returns it and ``(board name, pty
    path)`` per board."""
    served = await asyncio.to_thread(start_serve, "--pty", "--boards", str(boards), "--baud",
                                     str(baud), ready_timeout=EMULATOR_READY_TIMEOUT_S)
    return served, list(served.ready.items())


async def stop_emulator(served: Served) -> tuple[int | None, str]:
    """SIGINT (serve's clean stop, which reports any lag on stderr); its exit code and what
    it said."""
    code = await served.stopped(signal.SIGINT)
    said = served.log_text().strip()
    served.discard()
    return code, said
