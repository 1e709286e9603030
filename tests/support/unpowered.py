"""An unpowered robot on the physics body, followed from the moment its boards are disabled:
the scenarios of ``tests/fpgaemu/test_unpowered_body.py`` (a deadman stop's ``RD``, a
watchdog lapse, a board restart), and the figures docs/robot.md shows —
``python -m tests.support.unpowered`` prints them (emulated time only: they do not depend
on the machine)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from fpgalink.protocol.robot import seed_robot
from tests.support.seedtable import Run

__all__ = ["AT_REST", "REACH", "SCENARIOS", "Sample", "disable", "follow", "run_scenario",
           "wheel_dps"]

#: The farthest a wheel is from base_link (m): a yaw rate moves it this much faster.
REACH = math.hypot(0.29, 0.33)
AT_REST = 0.01  #: m/s: issue 40's "speed < 1 cm/s within 1 s of the disable"
#: name → (surface, left, right, how the boards are stopped); speeds in m/s, or deg/s at
#: the wheels for an in-place turn
SCENARIOS: dict[str, tuple[str, float, float, str]] = {
    "RD at 0.2 m/s, gravel": ("gravel", 0.2, 0.2, "rd"),
    "RD at 0.25 m/s, marble": ("marble", 0.25, 0.25, "rd"),
    "RD turning in place, gravel": ("gravel", -25.0, 25.0, "rd"),
    "watchdog lapse at 0.2 m/s": ("gravel", 0.2, 0.2, "lapse"),
    "board L restarts at 0.2 m/s": ("gravel", 0.2, 0.2, "restart"),
}


def wheel_dps(speed: float) -> float:
    return math.degrees(speed / seed_robot().wheel_radius)


@dataclass
class Sample:
    t: float  #: s since the disable
    speed: float  #: m/s: the body's speed plus its yaw rate times REACH (any point's bound)
    x: float
    y: float
    theta: float
    asleep: bool


def disable(run: Run, names: list[str] | None = None) -> None:
    """What the robot's supervision does at a deadman stop: ``RD`` to the boards, no more
    ``RE`` or references."""
    for name, conn in run.conns.items():
        if names is None or name in names:
            conn.disable(run.now_ms / 1000)
            run.robot.boards[name].host_write(conn.data_to_send())
    run.hold_wheels(None, None)


def follow(run: Run, seconds: float, since: float = 0.0) -> list[Sample]:
    """The body every 10 ms of emulated time from now (time ``-since`` = now)."""
    start = run.now_ms
    body = run.robot.physics
    assert body is not None
    out = []
    end = run.now_ms + round(seconds * 1000)
    while run.now_ms < end:
        run.run(0.01)
        truth = run.robot.truth()
        out.append(Sample((run.now_ms - start) / 1000 - since,
                          abs(truth.v) + abs(truth.omega) * REACH,
                          truth.pose.x, truth.pose.y, truth.pose.theta, body.asleep))
    return out


def run_scenario(surface: str, left: float, right: float, how: str,
                 seconds: float = 4.0) -> list[Sample]:
    """Drive 3 s, stop the boards as ``how`` says, and follow the body: time 0 is when the
    last board's enable fell (``rd``: at once; ``lapse``: 300 ms after the last ``RE``;
    ``restart``: board L power-cycles, the robot's supervision stops R 80 ms later)."""
    turning = left != right
    faults = {"L": ["restart=3.0"]} if how == "restart" else None
    run = Run.make(surface, "mujoco", faults=faults)
    run.hold_wheels(left if turning else wheel_dps(left), right if turning else wheel_dps(right))
    run.run(3.0)
    if how == "rd":
        disable(run)
        return follow(run, seconds)
    if how == "lapse":
        run.hold_wheels(None, None)  # nothing more sent: the last RE was at 2.9 s
        return [s for s in follow(run, seconds + 0.2, since=0.2) if s.t >= 0]
    assert how == "restart"
    run.hold_wheels(None, None)  # L restarts now; nothing more is sent to it
    run.run(0.08)
    assert run.robot.boards["L"].power_cycles == 1
    disable(run, ["R"])
    return follow(run, seconds)


def main() -> None:
    print(f"{'scenario':<30} {'< 1 cm/s after':>15} {'asleep after':>13} "
          f"{'rolled':>8} {'came back':>10}")
    for name, (surface, left, right, how) in SCENARIOS.items():
        samples = run_scenario(surface, left, right, how)
        rest = next(s.t for i, s in enumerate(samples)
                    if all(x.speed < AT_REST for x in samples[i:]))
        asleep = next(s.t for s in samples if s.asleep)
        first = samples[0]
        rolled = math.hypot(samples[-1].x - first.x, samples[-1].y - first.y)
        # how far the body came back from the farthest it rolled (the rocking)
        ahead = [math.hypot(s.x - first.x, s.y - first.y) for s in samples]
        back = max(max(ahead[: i + 1]) - a for i, a in enumerate(ahead))
        print(f"{name:<30} {rest:>13.2f} s {asleep:>11.2f} s {rolled * 100:>6.1f} cm "
              f"{back * 1000:>7.1f} mm")


if __name__ == "__main__":
    main()
