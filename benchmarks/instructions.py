"""Instructions per emulated millisecond, counted by valgrind's callgrind: a figure beside
wall time that no other process on the machine can move.

The cases are ``benchmarks.emulator``'s (``board``, ``robot``, and ``board+host``,
``board.idle``), each run in a fresh process on the compiled build and on pure Python
(``FPGALINK_PURE=1``) under callgrind, with instrumentation off until the scenario is
built and on only while it runs (``callgrind_control -i on|off``), so start-up, imports
and the scenario's own set-up are not counted; beside them ``benchmarks.ceiling``'s flat
loop of one millisecond's arithmetic with ``TM`` and ``RV`` (pure Python). Counts are exact
and repeat from run to run (string hashing seeded, the address space not randomised), so a
short run is enough: ``--seconds`` of emulated time (default 0.5).

Run ``python -m benchmarks.instructions`` from the repository root (a few minutes: a
program runs about 50 times slower under callgrind); ``--quick`` is 0.05 s emulated and the
board alone. Without valgrind it says so and writes no figures.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import Any

from benchmarks._common import (
    BUILDS,
    build_env,
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)

NAME = "instructions"
DEFAULT_SECONDS, QUICK_SECONDS = 0.5, 0.05
CASES = ("board", "robot", "board+host", "board.idle")
QUICK_CASES = ("board",)
FLAT = "flat loop (+ RV)"


def _scenario(case: str, seconds: float) -> Callable[[], object]:
    from benchmarks.emulator import IDLE_STRETCH, idle_scenario, robot_scenario, scenario

    if case == FLAT:
        from benchmarks.ceiling import arithmetic_loop

        return arithmetic_loop(round(seconds * 1000), True, True)
    if case == "robot":
        return robot_scenario(seconds)
    if case == "board.idle":
        return idle_scenario(seconds * IDLE_STRETCH)
    return scenario(seconds, decode=case == "board+host", rv_stream=True)


def _callgrind(on: bool) -> None:
    subprocess.run(["callgrind_control", "-i", "on" if on else "off", str(os.getpid())],
                   check=True, capture_output=True)


def child(case: str, seconds: float) -> int:
    """Under callgrind: build the case, count only its run, and leave without the
    interpreter's tear-down (nothing after the count matters)."""
    from fpgalink.buildinfo import BUILD

    run = _scenario(case, seconds)
    gc.collect()
    _callgrind(True)
    run()
    _callgrind(False)
    print(json.dumps({"build": BUILD}), flush=True)
    os._exit(0)


def measure(case: str, seconds: float, build: str) -> dict[str, Any]:
    """One case on one build under callgrind: its instruction count and build."""
    with tempfile.TemporaryDirectory(prefix="fpgalink-callgrind-") as scratch:
        env = {**build_env(build), "PYTHONHASHSEED": "0"}
        command = ["valgrind", "--tool=callgrind", "--instr-atstart=no",
                   "--trace-children=yes",  # a .pth may re-execute the interpreter
                   f"--callgrind-out-file={scratch}/callgrind.%p.out",
                   sys.executable, "-m", "benchmarks.instructions", "--child", case,
                   "--seconds", repr(seconds)]
        if shutil.which("setarch") is not None:  # the same addresses every run
            command = ["setarch", os.uname().machine, "-R", *command]
        done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    counts = re.findall(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or not counts:
        raise RuntimeError(f"{case} on the {build} build under callgrind failed: "
                           f"{done.stderr.strip()[-500:]}")
    said = json.loads(done.stdout.strip().splitlines()[-1])
    emulated_ms = seconds * 1000 * (10 if case == "board.idle" else 1)
    return {"build": said["build"], "instructions": int(counts[-1]),
            "per_emulated_ms": int(counts[-1]) / emulated_ms, "emulated_ms": emulated_ms}


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, f"{QUICK_SECONDS:g} s emulated, the board alone")
    parser.add_argument("--seconds", type=float, default=None,
                        help=f"emulated seconds per case (default {DEFAULT_SECONDS:g})")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else DEFAULT_SECONDS)
    if args.child is not None:
        return child(args.child, seconds)
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        print("valgrind (callgrind) is not installed: no instruction counts", file=sys.stderr)
        return 0
    started = time.perf_counter()
    cases = QUICK_CASES if args.quick else CASES
    results: dict[str, dict[str, Any]] = {}
    for case in cases:
        for build in BUILDS:
            results.setdefault(case, {})[build] = measure(case, seconds, build)
        print(f"{case} done", file=sys.stderr)
    results[FLAT] = {"pure": measure(FLAT, seconds, "pure")}
    compiled_here = all(r["compiled"]["build"].startswith("compiled")
                        for k, r in results.items() if k != FLAT)
    rows = []
    for case, by_build in results.items():
        pure = by_build["pure"]["per_emulated_ms"]
        compiled = by_build.get("compiled", {}).get("per_emulated_ms")
        ratio = pure / compiled if compiled else None
        if ratio is not None:
            by_build["pure_over_compiled"] = ratio
        rows.append([case, "–" if compiled is None else f"{compiled:,.0f}", f"{pure:,.0f}",
                     "–" if ratio is None else f"{ratio:.2f}×"])
    flat = results[FLAT]["pure"]["per_emulated_ms"]
    board = results["board"]["compiled"]["per_emulated_ms"]
    payload = {**report_header(NAME, ["mypy"]),
               "config": {"quick": args.quick, "emulated_s": seconds,
                          "argv": sys.argv[1:] if argv is None else list(argv)},
               "compiled_build_present": compiled_here,
               "cases": results,
               "board_compiled_over_flat_loop": board / flat,
               "timing": {"total_s": time.perf_counter() - started}}
    path = write_results(NAME, payload, args.output)
    print(f"instructions per emulated millisecond (callgrind, the run alone; {seconds:g} s "
          "emulated, board.idle ten times that)")
    print(environment_line(payload))
    print_table(["case", "compiled", "pure", "pure/compiled"], rows)
    if not compiled_here:
        print("(no compiled build here: the 'compiled' column ran pure Python)")
    print(f"the compiled board's millisecond: {board / flat:.2f}× the flat loop's "
          "instructions")
    print(f"results in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
