"""An unpowered robot stays put on the physics body (issue 40): its worm gears do not
back-drive, so after a deadman stop (``RD`` to every board), a watchdog lapse (no more
``RE``) or a board restart the body comes to rest within 1 s and then does not move at all.

Before, the self-locking was friction on the motor's rotor only, and the wheel rang on the
gearbox's compliance behind it: disabled at 0.2 m/s the body rocked (−2.7, +2.0, −1.5 cm/s,
period 0.61 s) and slept only 2.1 s after the disable.

Emulated time only (no wall clock): the boards are driven through their UARTs
(``tests.support.unpowered``) and the truth is read every 10 ms of emulated time.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from fpgaemu import physics
from tests.support.unpowered import AT_REST, SCENARIOS, Sample, run_scenario

pytestmark = pytest.mark.skipif(not physics.available(), reason=physics.why_unavailable()
                                or "")


def assert_comes_to_rest(samples: list[Sample], what: str) -> None:
    moving = [s for s in samples if s.t >= 1.0 and s.speed >= AT_REST]
    assert not moving, (f"{what}: {moving[0].speed * 100:.2f} cm/s at {moving[0].t:.2f} s "
                        "after the disable")
    late = [s for s in samples if s.t >= 1.0]
    first, last = late[0], late[-1]
    # Then no motion: the pose does not change by a tenth of a millimetre or a hundredth of
    # a degree, and the physics sleeps (so a robot at rest costs nothing).
    assert math.hypot(last.x - first.x, last.y - first.y) < 1e-4, what
    assert abs(last.theta - first.theta) < math.radians(0.01), what
    asleep = next((s.t for s in samples if s.asleep), None)
    assert asleep is not None and asleep <= 1.5, f"{what}: asleep at {asleep}"
    assert all(s.asleep for s in samples if s.t >= asleep), f"{what}: woke up again"


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_an_unpowered_robot_comes_to_rest_and_stays(scenario: str) -> None:
    """RD (what a deadman stop sends every board) at speed and turning in place; a watchdog
    lapse (a frozen host); board L restarting while driving, R stopped by the robot's
    supervision 80 ms later."""
    assert_comes_to_rest(run_scenario(*SCENARIOS[scenario]), scenario)


async def test_the_robots_deadman_stop_leaves_the_body_at_rest() -> None:
    """Through the library's robot, supervision as it runs: renewed while the body speeds up
    to 0.2 m/s, then not (a caller gone): the deadman lapses and every board gets RD. The
    body, read from the emulator's truth in emulated time, is below 1 cm/s within 1 s of the
    boards' disable and then does not move."""
    import asyncio

    from fpgalink.protocol.robot import seed_robot
    from fpgalink.robot import Robot

    query = "surface=gravel&body=mujoco"
    robot = Robot.open(seed_robot(), {b: f"emu://robot/{b}?{query}" for b in ("L", "R")})
    records: list[dict[str, Any]] = []
    async with robot:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60.0
        started: float | None = None
        while loop.time() < deadline:
            truth = robot.truth()
            assert truth is not None
            records.append(truth)
            started = float(truth["t"]) if started is None else started
            if float(truth["t"]) < started + 2.5:  # renewed for 2.5 s of emulated time
                robot.enable()
                robot.drive(0.2, 0.0)
            fell = [b["disabled_s"] for b in truth["boards"].values()
                    if b["disabled_by"] == "RD"]
            if len(fell) == 2 and float(truth["t"]) > max(fell) + 3.0:
                break
            await asyncio.sleep(0.01)
    last_stop = robot.last_stop
    assert last_stop is not None and last_stop.reason is not None
    assert last_stop.reason.name == "DEADMAN", last_stop.describe()
    disabled = max(float(b["disabled_s"]) for b in records[-1]["boards"].values())
    assert max(abs(float(r["v"])) for r in records if r["t"] < disabled) > 0.15  # driving
    late = [r for r in records if float(r["t"]) >= disabled + 1.0]
    assert late and all(abs(float(r["v"])) + abs(float(r["omega"])) * 0.44 < 0.01
                        for r in late)
    assert (late[0]["x"], late[0]["y"]) == (late[-1]["x"], late[-1]["y"])
