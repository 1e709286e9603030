"""How the robot meets its faults: for a board that restarts mid-drive, one board's telemetry
stopping, a board going silent, and a host frozen past the boards' watchdog — how long after
the fault the robot was stopped, when the other board's enable fell, and how long until the
robot could drive again. The figures of docs/robot.md's Faults table come from this script.

The first three run the emulated robot in this process (``emu://robot/…?fault=…``), so the
fault's moment and each board's response are read off the boards, cycle-exact, in emulated
time (paced to the wall clock). The frozen host is ``fpgalink-cli drive`` against
``fpgaemu serve --robot``, stopped with SIGSTOP for 0.4 s. A quiet machine gives the
figures worth quoting: a loaded one adds its own delays (and its own faults).

    python -m benchmarks.faults [--quick] [--output FILE]
"""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import os
import signal
import sys
import time
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    summarize,
    write_results,
)
from fpgaemu.board import Board
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol.robot import seed_robot
from fpgalink.robot import Robot, RobotStopped
from fpgalink.robot.supervision import State, SupervisionEvent
from tests.support.serving import start_serve

NAME = "faults"
#: Emulated seconds from power-up at which the fault comes: the robot is driving by then.
FAULT_AT_S = 1.5
PATIENCE_S = 20.0


def _board(robot: Robot, name: str) -> Board:
    board = robot.links[name].get_extra_info("board")
    assert isinstance(board, Board)
    return board


async def _drive_until(robot: Robot, done: Any, give_up: float) -> None:
    loop = asyncio.get_running_loop()
    while not done():
        if loop.time() > give_up:
            raise TimeoutError("the robot did not get there")
        if robot.state is not State.ENABLED:
            try:
                robot.enable()
            except RobotStopped:
                await asyncio.sleep(0.01)
                continue
        robot.drive(0.2, 0.0)
        robot.enable()
        await asyncio.sleep(0.02)


async def _in_process(fault: str, faulty: str, window_s: float) -> dict[str, float]:
    """One run: drive, meet ``fault`` on board ``faulty``, drive again when ready."""
    query = f"surface=ideal&fault={faulty}:{fault}"
    ports = {b: f"emu://robot/{b}?{query}" for b in ("L", "R")}
    loop = asyncio.get_running_loop()
    async with Robot.open(seed_robot().on_surface("ideal"), ports) as robot:
        bad, other = _board(robot, faulty), _board(robot, "R" if faulty == "L" else "L")
        stop_cycle: list[int] = []
        ready_cycle: list[int] = []
        other_fell: list[int] = []
        events = robot.events()

        async def watch() -> None:
            async for event in events:
                _note(event, bad, stop_cycle, ready_cycle)

        watcher = asyncio.ensure_future(watch())
        other.uartcommand.on_enable_change(
            lambda change: other_fell.append(change.cycle) if not change.enabled
            and change.cycle >= FAULT_AT_S * CLOCK_HZ else None)
        poses: list[tuple[float, float]] = []

        async def sample() -> None:
            while True:
                poses.append((robot.pose.x, robot.pose.y))
                await asyncio.sleep(0.005)

        sampler = asyncio.ensure_future(sample())
        give_up = loop.time() + PATIENCE_S
        try:
            await _drive_until(robot, lambda: bool(stop_cycle), give_up)
            end = (FAULT_AT_S + window_s) * CLOCK_HZ
            await _drive_until(robot, lambda: robot.state is State.ENABLED
                               and bad.now > end and (ready_cycle or not window_s), give_up)
        finally:
            sampler.cancel()
            watcher.cancel()
            await asyncio.gather(sampler, watcher, return_exceptions=True)
        fault_cycle = FAULT_AT_S * CLOCK_HZ
        truth = robot.truth()
        assert truth is not None
        jumps = [math.dist(a, b) for a, b in itertools.pairwise(poses)]
        result = {
            "stopped_ms": (stop_cycle[0] - fault_cycle) / CLOCK_HZ * 1e3,
            "other_board_disabled_ms": (other_fell[0] - fault_cycle) / CLOCK_HZ * 1e3
            if other_fell else math.nan,
            "odometry_largest_step_mm": max(jumps) * 1e3,
            "odometry_off_mm": math.hypot(truth["x"] - robot.pose.x,
                                          truth["y"] - robot.pose.y) * 1e3,
        }
        if ready_cycle:
            result["ready_again_ms"] = (ready_cycle[0] - fault_cycle) / CLOCK_HZ * 1e3
        return result


def _note(event: SupervisionEvent, bad: Board, stops: list[int], ready: list[int]) -> None:
    if bad.now < FAULT_AT_S * CLOCK_HZ:
        return
    if event.recovered:
        ready.append(bad.now)
    elif event.reason is not None and not stops and event.reason.name != "REQUESTED":
        stops.append(bad.now)


async def _frozen_host(freeze_s: float) -> dict[str, float]:
    """``fpgalink-cli drive`` against a served robot, frozen with SIGSTOP for ``freeze_s``."""
    server = await asyncio.to_thread(start_serve, "--robot", "--pty", "--body", "kinematic",
                                     "--surface", "ideal")
    try:
        ready = dict(server.ready)
        assert server.truth is not None
        host, port = server.truth.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))
        env = {k: v for k, v in os.environ.items() if not k.startswith("FPGALINK_")}
        cli = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "fpgalink", *(f"--port={n}={u}" for n, u in ready.items()),
            "drive", "--v", "0.1", "--for", "60", env=env, stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
        latest: dict[str, Any] = {}
        give_up = time.monotonic() + PATIENCE_S
        while not latest or latest["v"] < 0.05:
            if time.monotonic() > give_up or cli.returncode is not None:
                if cli.returncode is None:
                    cli.kill()
                _, err = await cli.communicate()
                raise RuntimeError(f"the CLI did not drive within {PATIENCE_S:g} s: "
                                   f"{err.decode(errors='replace').strip()}")
            latest = json.loads(await asyncio.wait_for(reader.readline(), PATIENCE_S))
        cli.send_signal(signal.SIGSTOP)
        frozen_at = latest["t"]
        while latest["t"] < frozen_at + freeze_s:
            latest = json.loads(await asyncio.wait_for(reader.readline(), PATIENCE_S))
        cli.send_signal(signal.SIGCONT)
        resumed = time.monotonic()
        _, err = await asyncio.wait_for(cli.communicate(), PATIENCE_S)
        reported_ms = (time.monotonic() - resumed) * 1e3
        latest = json.loads(await asyncio.wait_for(reader.readline(), PATIENCE_S))
        writer.close()
        lapses = [b["disabled_s"] - b["last_re_s"] for b in latest["boards"].values()
                  if b["disabled_by"] == "watchdog"]
        return {"exit_code": float(cli.returncode or 0),
                "reported_and_exited_ms": reported_ms,
                "watchdog_after_last_re_ms": max(lapses) * 1e3 if lapses else math.nan,
                "said_why": float("watchdog: host silent" in err.decode())}
    finally:
        await server.stopped()
        server.discard()


CASES = (
    ("restart", "L", "restart=1.5", 0.0,
     "board L power-cycles mid-drive (a brown-out)"),
    ("telemetry loss", "L", "tm-loss=1.5:1", 1.0,
     "board L's TM frames lost for 1 s (E and PA pass)"),
    ("board silent", "L", "disconnect=1.5:1", 1.0,
     "board L's cable cut for 1 s, both ways"),
)


def main() -> None:
    parser = common_parser(__doc__, NAME, "one repetition per case (a smoke run)")
    args = parser.parse_args()
    repetitions = 1 if args.quick else 5
    report = report_header(NAME, [])
    report["config"] = {"quick": args.quick, "repetitions": repetitions,
                        "fault_at_s": FAULT_AT_S}
    print(environment_line(report))
    cases: dict[str, Any] = {}
    rows = []
    for name, board, fault, window, what in CASES:
        runs = [asyncio.run(_in_process(fault, board, window)) for _ in range(repetitions)]
        cases[name] = {"what": what, "repetitions": runs,
                       "summary": {k: summarize([r[k] for r in runs if k in r])
                                   for k in runs[0]}}
        s = cases[name]["summary"]
        rows.append([name, f"{s['stopped_ms']['median']:.0f}",
                     f"{s['other_board_disabled_ms']['median']:.0f}",
                     f"{s['ready_again_ms']['median']:.0f}" if "ready_again_ms" in s else "-",
                     f"{s['odometry_largest_step_mm']['median']:.1f}",
                     f"{s['odometry_off_mm']['median']:.0f}"])
    frozen = [asyncio.run(_frozen_host(0.4)) for _ in range(repetitions)]
    cases["host frozen"] = {"what": "fpgalink-cli drive stopped with SIGSTOP for 0.4 s",
                            "repetitions": frozen,
                            "summary": {k: summarize([r[k] for r in frozen])
                                        for k in frozen[0]}}
    print_table(["fault", "stopped ms", "other board off ms", "ready again ms",
                 "odometry step mm", "odometry off mm"], rows)
    s = cases["host frozen"]["summary"]
    print(f"\nhost frozen 0.4 s (fpgalink-cli drive, SIGSTOP): boards disabled by their "
          f"watchdog {s['watchdog_after_last_re_ms']['median']:.0f} ms after the last RE; "
          f"on SIGCONT the CLI said why and exited (code "
          f"{s['exit_code']['median']:.0f}) in {s['reported_and_exited_ms']['median']:.0f} ms")
    print("(ms after the fault, emulated time paced to the wall clock; medians of "
          f"{repetitions})")
    report["cases"] = cases
    path = write_results(NAME, report, args.output)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
