"""Helpers shared by the benchmark scripts: where they run, how long things took, and how
the results are shown and kept.

Every script records the machine, the interpreter and the package versions beside its
numbers, because a rate means nothing once it is separated from what produced it. Results go
to ``benchmarks/results/<name>.json`` (ignored by git: they describe one machine on one day).
"""

from __future__ import annotations

import datetime as _dt
import gc
import json
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fpgalink import _bench

__all__ = [
    "RESULTS_DIR",
    "Summary",
    "machine_info",
    "package_versions",
    "print_table",
    "python_info",
    "summarize",
    "time_once",
    "timestamp",
    "write_results",
]

RESULTS_DIR = Path(__file__).resolve().parent / "results"

#: ``{"median": …, "min": …, "max": …}`` of a set of repetitions.
Summary = dict[str, float]


# Where the numbers came from: one implementation, shared with ``fpgalink-cli bench``.
machine_info = _bench.machine_info
python_info = _bench.python_info
package_versions = _bench.package_versions


def timestamp() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def summarize(values: Sequence[float]) -> Summary:
    """Median and range of the repetitions. The median, not the mean: one repetition slowed
    by another process on a small machine should not move the headline number."""
    if not values:
        raise ValueError("no repetitions to summarize")
    return {
        "median": statistics.median(values),
        "min": min(values),
        "max": max(values),
    }


def time_once(fn: Callable[[], object]) -> tuple[float, object]:
    """Wall time of one call to ``fn`` (``perf_counter``) and what it returned.

    Garbage from earlier work is collected first, so one case does not pay for another's
    leftovers; the collector stays on while timing, as it would be in real use.
    """
    gc.collect()
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def print_table(
    headers: Sequence[str],
    rows: Sequence[Sequence[str]],
    *,
    align: str | None = None,
    file: Any = None,
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
    # temporary name keeps the .json suffix so that git ignores it too.
    tmp = target.with_name(f".{target.stem}.tmp{target.suffix}")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=False) + "\n", encoding="utf-8")
    tmp.replace(target)
    return target
