"""The live view for Foxglove does not slow the control path: the robot (two boards at 1 kHz
telemetry over ptys from ``fpgaemu serve --robot``, 1 MBd) driven for a while with no live
view, with a live view nobody watches, and with one Foxglove client subscribed to every
channel (a separate process speaking the protocol, tests/support/foxglove.py). Per case:
telemetry lost, the host's TM inter-arrival p50/p99/max, this process's CPU, and what the
client decoded. The cases are interleaved, repeated, and the medians compared.

    python -m benchmarks.liveview [--quick] [--seconds S] [--repeat N]
"""

from __future__ import annotations

import asyncio
import itertools
import json
import signal
import statistics
import subprocess
import sys
import time
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    percentile,
    print_table,
    report_header,
    write_results,
)
from tests.support.serving import Served, start_serve

NAME = "liveview"
CASES = ("no live view", "live view, no client", "live view, 1 client")
DEFAULT_SECONDS, QUICK_SECONDS = 10.0, 3.0

CLIENT = """
import asyncio, json, sys
from tests.support.foxglove import watch
try:
    got = asyncio.run(watch(sys.argv[1], float(sys.argv[2])))
    print(json.dumps({"channels": len(got.channels),
                      "messages": sum(len(m) for m in got.messages.values())}))
except OSError as exc:  # the case ended before the client connected (a stop)
    print(json.dumps({"channels": 0, "messages": 0, "error": str(exc)}))
"""


async def _serve_robot() -> tuple[Served, dict[str, str]]:
    served = await asyncio.to_thread(start_serve, "--robot", "--body", "kinematic", "--pty")
    return served, dict(served.ready)


async def _one(robot: Any, case: str, seconds: float) -> dict[str, Any]:
    from fpgalink.live import LiveView, parse_address

    view = None
    client = None
    if case != CASES[0]:
        view = LiveView(parse_address("0"), "benchmarks.liveview")
        view.start()
        view.add_robot(robot)
    if case == CASES[2]:
        assert view is not None
        client = subprocess.Popen([sys.executable, "-c", CLIENT, view.url, str(seconds)],
                                  stdout=subprocess.PIPE, text=True)
        await asyncio.sleep(1.0)  # subscribed before the window opens
    arrivals: dict[str, list[float]] = {name: [] for name in robot.links}
    lost0 = {name: link.stats.lost for name, link in robot.links.items()}

    async def listen(name: str) -> None:
        async for received, _ in robot.links[name].stamped_telemetry(maxsize=1 << 16):
            arrivals[name].append(received)

    from fpgalink.robot.robot import RobotStopped

    tasks = [asyncio.ensure_future(listen(name)) for name in robot.links]
    cpu0, wall0 = time.process_time(), time.monotonic()
    stopped = None  # a fault stop is a finding of the case (a loaded machine's stall, or
    try:            # this host too late for the boards): said, counted, not hidden
        async with robot.enabled():
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                robot.drive(0.2, 0.1)
                await asyncio.sleep(robot.control_period)
    except RobotStopped as exc:
        stopped = str(exc)
        print(f"{case}: {stopped}", file=sys.stderr)
    cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    published = view.stats.published if view is not None else 0
    if view is not None:
        await view.close()
    decoded = None
    if client is not None:
        out, _ = client.communicate(timeout=30)
        decoded = json.loads(out.strip().splitlines()[-1])["messages"]
    gaps = [b - a for times in arrivals.values() for a, b in itertools.pairwise(times)]
    return {"case": case, "tm": sum(len(t) for t in arrivals.values()),
            "lost": sum(link.stats.lost - lost0[n] for n, link in robot.links.items()),
            "gap_p50_ms": percentile(gaps, 50) * 1e3, "gap_p99_ms": percentile(gaps, 99) * 1e3,
            "gap_max_ms": max(gaps) * 1e3, "cpu_pct": 100 * cpu / wall,
            "published": published, "decoded": decoded, "stopped": stopped}


async def run(seconds: float, repeat: int) -> list[dict[str, Any]]:
    from fpgalink.protocol.robot import seed_robot
    from fpgalink.robot import Robot

    serve, ports = await _serve_robot()
    results = []
    try:
        async with Robot.open(seed_robot(), ports) as robot:
            for _ in range(repeat):
                for case in CASES:
                    results.append(await _one(robot, case, seconds))
                    await asyncio.sleep(0.5)  # a stopped robot is ready again
    finally:
        await serve.stopped(signal.SIGINT)
        serve.discard()
    return results


def main() -> None:
    parser = common_parser(__doc__, NAME, f"{QUICK_SECONDS:g} s per case, 1 repetition")
    parser.add_argument("--seconds", type=float, default=None)
    parser.add_argument("--repeat", type=int, default=None)
    args = parser.parse_args()
    seconds = args.seconds or (QUICK_SECONDS if args.quick else DEFAULT_SECONDS)
    repeat = args.repeat or (1 if args.quick else 3)
    report = report_header(NAME, ["foxglove-sdk", "websockets"])
    results = asyncio.run(run(seconds, repeat))
    report["config"] = {"seconds": seconds, "repeat": repeat, "boards": 2,
                        "telemetry_hz": 1000, "baud": 1_000_000}
    report["results"] = results
    print(environment_line(report))
    rows = []
    for case in CASES:
        mine = [r for r in results if r["case"] == case]

        def median(key: str, mine: list[dict[str, Any]] = mine) -> float:
            return float(statistics.median(r[key] for r in mine))

        decoded = [r["decoded"] for r in mine if r["decoded"] is not None]
        rows.append([case, f"{median('tm'):,.0f}", str(sum(r["lost"] for r in mine)),
                     f"{median('gap_p50_ms'):.3f}", f"{median('gap_p99_ms'):.3f}",
                     f"{median('gap_max_ms'):.1f}", f"{median('cpu_pct'):.1f}",
                     f"{median('published'):,.0f}",
                     f"{statistics.median(decoded):,.0f}" if decoded else "-",
                     str(sum(r["stopped"] is not None for r in mine))])
    print(f"median of {repeat}, {seconds:g} s each, cases interleaved")
    print_table(["case", "TM", "TM lost", "gap p50 ms", "gap p99 ms", "gap max ms",
                 "CPU %", "sent", "decoded", "stops"], rows)
    print(f"results: {write_results(NAME, report, args.output)}")


if __name__ == "__main__":
    main()
