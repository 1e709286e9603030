"""A campaign's results as one table: a row per scenario (its settings, its grid point, its
figures), written as CSV, JSON or Parquet (when pyarrow is installed), and a summary plot."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fpgalink.campaign.scenario import Result

__all__ = ["columns", "rows", "write_csv", "write_json", "write_parquet"]

#: Columns that say how a row ran rather than what it measured: left out of comparisons
#: (``deterministic_rows``) because they differ from run to run by nature (the recording's
#: path names the run's directory; present only when the scenario was recorded).
RUN_COLUMNS = ("wall_s", "worker", "mcap", "mcap_error")
HEAD = ("index", "scenario", "status", "error", "surface", "body", "seed", "faults")


def rows(results: Sequence[Result]) -> list[dict[str, Any]]:
    out = []
    for r in sorted(results, key=lambda r: r.index):
        row: dict[str, Any] = {"index": r.index, "scenario": r.name, "status": r.status,
                               "error": r.error}
        row.update(r.settings)
        row.update(r.figures)
        row["wall_s"] = round(r.wall_s, 3)
        row["worker"] = r.worker
        if r.mcap is not None or r.mcap_error is not None:
            row["mcap"] = r.mcap
            row["mcap_error"] = r.mcap_error
        out.append(row)
    return out


def deterministic_rows(results: Sequence[Result]) -> list[dict[str, Any]]:
    """:func:`rows` without the columns that say where and how fast a row ran."""
    return [{k: v for k, v in row.items() if k not in RUN_COLUMNS} for row in rows(results)]


def columns(table: Sequence[dict[str, Any]]) -> list[str]:
    """Every column, the fixed ones first, then the rest in first-seen order."""
    seen: dict[str, None] = dict.fromkeys(HEAD)
    for row in table:
        seen.update(dict.fromkeys(row))
    present = {k for row in table for k in row}
    return [c for c in seen if c in present]


def write_csv(path: Path, table: Sequence[dict[str, Any]]) -> None:
    names = columns(table)
    with path.open("w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, names, restval="")
        writer.writeheader()
        for row in table:
            writer.writerow({k: "" if v is None else v for k, v in row.items()})


def _json_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, table: Sequence[dict[str, Any]]) -> None:
    document = [{k: _json_value(v) for k, v in row.items()} for row in table]
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")


def write_parquet(path: Path, table: Sequence[dict[str, Any]]) -> bool:
    """``False`` (nothing written) when pyarrow is not installed."""
    try:
        import pyarrow as pa  # type: ignore[import-not-found,unused-ignore]
        import pyarrow.parquet as pq  # type: ignore[import-not-found,unused-ignore]
    except ImportError:
        return False
    names = columns(table)
    data = {name: [row.get(name) for row in table] for name in names}
    pq.write_table(pa.table(data), str(path))
    return True
