"""``goto``: drive the robot to a point with the seed's position controller (Algorithm 1),
holding the deadman, with progress as it goes."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fpgalink.cli.formats import format_option
from fpgalink.cli.options import ConnectionOptions
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    SignedNumbers,
    echo_out,
)
from fpgalink.cli.robotsession import (
    RobotRun,
    live,
    output_options,
    robot_options,
    stopped_error,
)
from fpgalink.cli.session import run, stop_exit_code

if TYPE_CHECKING:
    from fpgalink.live import LiveAddress

__all__ = ["goto"]


@click.command(cls=SignedNumbers, epilog=EXIT_CODES_HELP)
@click.argument("x", type=FiniteRange(-1e4, 1e4))
@click.argument("y", type=FiniteRange(-1e4, 1e4))
@click.option("--theta", type=FiniteRange(-360, 360),
              help="Final heading, deg (counter-clockwise from the start's x axis).")
@click.option("--time-limit", "time_limit", type=FiniteRange(min=0, min_open=True, max=86400),
              default=60.0, show_default=True,
              help="Give up (and stop) after this many seconds.")
@click.option("--tolerance", type=FiniteRange(min=0.005, max=10), default=0.05,
              show_default=True, help="Arrived within this distance, m.")
@output_options
@format_option
@robot_options
def goto(x: float, y: float, theta: float | None, time_limit: float, tolerance: float,
         plot: Path | None, record: Path | None, rosbag: Path | None,
         foxglove: LiveAddress | None, force: bool, fmt: str,
         robot_file: Path | None, surface: str | None, truth_url: str | None,
         conn: ConnectionOptions) -> int:
    """Drive the robot to X Y (m, in the odometry frame of the start) and stop there.

    Turns towards the goal, drives with a PI distance loop while a PI heading loop corrects,
    stops within --tolerance (then turns to --theta if given). Exit 0 on arrival, 6 when not
    there within --time-limit, 7 when supervision stopped the robot, 130 on Ctrl-C.
    """
    session = RobotRun(conn, robot_file, surface, truth_url, plot, record, rosbag, foxglove,
                       "fpgalink-cli goto", force=force)
    target = f"({x:g}, {y:g})" + ("" if theta is None else f", θ {theta:g}°")
    arrived: list[Any] = []
    try:
        code = run(_goto(session, x, y, None if theta is None else math.radians(theta),
                         time_limit, tolerance, target, fmt, arrived))
    finally:
        if session.robot is not None:
            goal = {"x_m": x, "y_m": y, "theta_deg": theta, "tolerance_m": tolerance}
            session.print_summary(fmt, {"goal": goal, "arrived": bool(arrived)})
            session.finish(f"goto {target}", (x, y))
    return code


async def _goto(session: RobotRun, x: float, y: float, theta: float | None,
                time_limit: float, tolerance: float, target: str, fmt: str,
                arrived: list[Any]) -> int:
    import asyncio
    import dataclasses

    from fpgalink.robot.goto import GoToCommand
    from fpgalink.robot.robot import GoalTimeout, RobotStopped

    async with session.opened() as robot:
        settings = dataclasses.replace(robot.goto_settings, position_tolerance=tolerance)
        last: list[GoToCommand] = []

        def status() -> str:
            if not last:
                return f"going to {target}"
            step = last[-1]
            return (f"going to {target}: {step.phase.value}, {step.distance:.2f} m to go, "
                    f"{math.degrees(step.heading_error):.0f}° off — Ctrl-C stops")

        with live(session, status) as refresh:
            def on_step(step: GoToCommand) -> None:
                last[:] = [step]
                refresh()

            async with robot.enabled():
                task = asyncio.ensure_future(robot.go_to(x, y, theta, timeout=time_limit,
                                                         settings=settings, on_step=on_step))
                stopper = asyncio.ensure_future(session.stop.wait())
                done, _ = await asyncio.wait({task, stopper},
                                             return_when=asyncio.FIRST_COMPLETED)
                stopper.cancel()
                if task not in done:
                    task.cancel()
                    await asyncio.gather(task, return_exceptions=True)
                    return stop_exit_code(session.stop)
                try:
                    pose: Any = task.result()
                except GoalTimeout as exc:
                    raise CliError(str(exc), ExitCode.TIMEOUT) from None
                except RobotStopped as exc:
                    raise stopped_error(exc.event, str(exc)) from None
        arrived.append(pose)
        if fmt == "table":
            echo_out(f"arrived at {target}: x {pose.x:.3f} m, y {pose.y:.3f} m, θ "
                     f"{math.degrees(pose.theta):.1f}°")
    return ExitCode.OK
