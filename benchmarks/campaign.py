"""Campaign throughput: the same campaign run in this process, on every local core, and on a
Dask LocalCluster, each timed whole (wall clock, start-up included), with the results checked
equal between them.

* the campaign: ``--scenarios`` copies (seeds 0…) of an in-place turn on gravel on the
  kinematic body, ``--seconds`` of emulated time each;
* per-scenario overhead: a campaign of scenarios of 0.1 s emulated, whose wall time is
  almost all set-up (a fresh robot, its boards' power-up and configuration), over their
  number;
* ratios (speed-up over one process) are of the same run.

Run ``python -m benchmarks.campaign`` from the repository root (a few minutes on 2 cores);
``--quick`` is the smoke test.
"""

from __future__ import annotations

import statistics
import sys
import time
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)
from fpgalink.campaign import Campaign, parse_campaign, run_campaign
from fpgalink.campaign.results import deterministic_rows
from fpgalink.campaign.runner import default_jobs

NAME = "campaign"


def turns(count: int, seconds: float) -> Campaign:
    return parse_campaign({
        "campaign": {"name": "turns", "body": "kinematic", "surface": "gravel"},
        "grid": {"seed": list(range(count))},
        "scenario": [{"name": "turn", "script": [
            {"wheels": [50, -50], "seconds": seconds, "label": "turn"}]}]})


def timed(campaign: Campaign, **how: Any) -> tuple[float, list[Any]]:
    started = time.perf_counter()
    results = run_campaign(campaign, **how)
    return time.perf_counter() - started, results


def main(argv: list[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, "two short scenarios per way (the smoke test)")
    parser.add_argument("--scenarios", type=int, default=None)
    parser.add_argument("--seconds", type=float, default=None)
    parser.add_argument("--reps", type=int, default=None)
    args = parser.parse_args(argv)
    count = args.scenarios or (2 if args.quick else 8)
    seconds = args.seconds or (0.5 if args.quick else 10.0)
    reps = args.reps or (1 if args.quick else 3)
    jobs = default_jobs()
    campaign = turns(count, seconds)
    ways: list[tuple[str, dict[str, Any]]] = [("1 process", {"jobs": 1}),
                                              (f"{jobs} processes", {"jobs": jobs})]
    try:
        import dask.distributed  # noqa: F401
        ways.append((f"Dask LocalCluster, {jobs} workers", {"dask": "local", "jobs": jobs}))
    except ImportError:
        print("dask.distributed is not installed: no Dask row", file=sys.stderr)
    rows: dict[str, dict[str, Any]] = {}
    reference = None
    for rep in range(reps):
        for label, how in ways:
            wall, results = timed(campaign, **how)
            table = deterministic_rows(results)
            reference = reference or table
            row = rows.setdefault(label, {"walls": [], "same": True, "failed": 0})
            row["walls"].append(wall)
            row["same"] &= table == reference
            row["failed"] += sum(not r.ok for r in results)
        print(f"repetition {rep + 1}/{reps} done", file=sys.stderr)
    base = statistics.median(rows["1 process"]["walls"])
    for row in rows.values():
        row["median_s"] = statistics.median(row["walls"])
        row["speedup"] = base / row["median_s"]
        row["x_real_time"] = count * seconds / row["median_s"]
    # The per-scenario overhead: scenarios of 0.1 s emulated, in this process.
    tiny = 4 if args.quick else 16
    overhead_wall, _ = timed(turns(tiny, 0.1), jobs=1)
    overhead = overhead_wall / tiny
    payload = {
        **report_header(NAME, ["dask", "distributed"]),
        "config": {"quick": args.quick, "scenarios": count, "emulated_s_each": seconds,
                   "reps": reps,
                   "jobs": jobs},
        "ways": {label: {k: v for k, v in row.items()} for label, row in rows.items()},
        "overhead_s_per_scenario": overhead,
    }
    path = write_results(NAME, payload, args.output)
    print(f"campaign speed: {count} scenarios of {seconds:g} s emulated, median of {reps}")
    print(environment_line(payload))
    print_table(("way", "wall s", "range", "speed-up", "× real time", "same table",
                 "failed"),
                [(label, f"{row['median_s']:.2f}",
                  f"{min(row['walls']):.2f}–{max(row['walls']):.2f}",
                  f"{row['speedup']:.2f}×", f"{row['x_real_time']:.1f}×",
                  "yes" if row["same"] else "NO", str(row["failed"]))
                 for label, row in rows.items()])
    print(f"per-scenario overhead (a fresh robot started, 0.1 s emulated, in this process): "
          f"{overhead * 1000:.0f} ms")
    print(f"results in {path}")
    same = all(row["same"] and not row["failed"] for row in rows.values())
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
