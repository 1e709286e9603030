"""``drive``: drive the robot at a body speed and turn rate for a while, holding the
deadman, with a live view; stop and disable at the end, on Ctrl-C, or when supervision
stops it."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from fpgalink.cli.formats import format_option
from fpgalink.cli.options import ConnectionOptions
from fpgalink.cli.output import EXIT_CODES_HELP, FiniteRange, SignedNumbers
from fpgalink.cli.robotsession import (
    RobotRun,
    live,
    output_options,
    robot_options,
    stopped_error,
)
from fpgalink.cli.session import run, stop_exit_code, wait_or_stop

if TYPE_CHECKING:
    from fpgalink.live import LiveAddress

__all__ = ["drive"]


@click.command(cls=SignedNumbers, epilog=EXIT_CODES_HELP)
@click.option("--v", "speed", type=FiniteRange(-10, 10), default=0.0, show_default=True,
              help="Body speed, m/s (forward positive).")
@click.option("--omega", type=FiniteRange(-3600, 3600), default=0.0, show_default=True,
              help="Turn rate, deg/s (counter-clockwise positive).")
@click.option("--for", "duration", type=FiniteRange(min=0, min_open=True, max=86400),
              help="How long, s (default: until Ctrl-C).")
@output_options
@format_option
@robot_options
def drive(speed: float, omega: float, duration: float | None, plot: Path | None,
          record: Path | None, rosbag: Path | None, foxglove: LiveAddress | None,
          force: bool, fmt: str, robot_file: Path | None,
          surface: str | None, truth_url: str | None, conn: ConnectionOptions) -> int:
    """Drive the robot at --v and --omega, holding the deadman, with a live view.

    A command beyond the robot's limits (speed, turn rate, any wheel's maximum) is scaled
    down keeping its curvature. Ends after --for seconds or on Ctrl-C, stopped and disabled.
    Exit 7 when supervision stopped it (a board went silent).
    """
    session = RobotRun(conn, robot_file, surface, truth_url, plot, record, rosbag, foxglove,
                       "fpgalink-cli drive", force=force)
    try:
        code = run(_drive(session, speed, math.radians(omega), duration))
    finally:  # a fault stop too: where it stopped is what the user asks first
        if session.robot is not None:
            session.print_summary(fmt, {"command": {"v_mps": speed, "omega_dps": omega,
                                                    "for_s": duration}})
            session.finish(f"drive v={speed:g} m/s, ω={omega:g} deg/s")
    return code


async def _drive(session: RobotRun, v: float, omega: float, duration: float | None) -> int:
    from fpgalink.robot.robot import RobotStopped
    from fpgalink.robot.supervision import State

    async with session.opened() as robot:
        started = time.monotonic()

        def status() -> str:
            elapsed = time.monotonic() - started
            of = f" of {duration:g} s" if duration else ""
            return f"driving {elapsed:.1f} s{of} — Ctrl-C stops"

        try:
            async with robot.enabled():
                command = robot.drive(v, omega)
                if command.scale < 1.0:
                    click.echo(f"fpgalink-cli: command scaled to {command.scale:.0%} to stay "
                               f"within the robot's limits: v {command.v:.3f} m/s, ω "
                               f"{math.degrees(command.omega):.1f} deg/s", err=True)
                with live(session, status) as refresh:
                    end = None if duration is None else started + duration
                    while not session.stop.is_set():
                        if robot.state is not State.ENABLED:
                            break
                        if end is not None and time.monotonic() >= end:
                            break
                        robot.drive(v, omega)
                        refresh()
                        wait = robot.control_period if end is None else min(
                            robot.control_period, max(0.0, end - time.monotonic()))
                        await wait_or_stop(session.stop, wait)
        except RobotStopped as exc:
            raise stopped_error(exc.event, str(exc)) from None
        stop = robot.last_stop
        if stop is not None and stop.reason is not None and stop.reason.name != "REQUESTED":
            raise stopped_error(stop, f"the robot was {stop.describe()}")
        await asyncio.sleep(0)
    return stop_exit_code(session.stop)
