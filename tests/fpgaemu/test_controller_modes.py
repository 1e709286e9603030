"""All four controller modes (SPEC §5 parameter 4): software and hardware speed PID, software
and hardware current PID — accepted on both channels, settling where they should, the
hardware loops acting between timer ticks, switching modes while enabled safely, and the
fixed-point hardware law against a floating-point reference model."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from fpgaemu.build import build_board
from fpgaemu.hwcontrol import (
    FRACTION_BITS,
    HW_PERIOD_CYCLES,
    Coefficients,
    HardwareController,
    LoopInput,
    to_fixed,
)
from fpgaemu.pid import Pid, PidGains
from fpgaemu.timeline import ms
from fpgalink.protocol import ParamAck
from tests.support.emulated import Cable

# Every test runs against the Python firmware model and the C core (tests/support/firmwares.py).
pytestmark = pytest.mark.usefixtures("each_firmware")

TORQUE_COEF = 0.2  #: N·m per A (the power-up TorqueCoef)


def streaming_host(mode: int, *, period_ms: int = 1) -> Cable:
    host = Cable.make()
    for param_id, channel, value_type, value in ((2, 0, 1, 1), (1, 0, 1, period_ms),
                                                 (4, 1, 1, mode), (4, 2, 1, mode)):
        assert isinstance(host.set(param_id, channel, value_type, value), ParamAck)
    host.start_enabled()
    host.run(0.01)
    return host


@pytest.mark.parametrize("mode", [0, 1, 2, 3])
def test_every_mode_is_accepted_echoed_and_read_back_on_both_channels(mode: int) -> None:
    host = Cable.make()
    for channel in (1, 2):
        reply = host.set(4, channel, 1, mode)
        assert isinstance(reply, ParamAck) and reply.value == mode
        back = host.get(4, channel)
        assert isinstance(back, ParamAck) and back.value == mode


@pytest.mark.parametrize("mode", [2, 3])
def test_a_torque_step_settles_on_the_current_torque_coef_implies(mode: int) -> None:
    host = streaming_host(mode)
    host.wheel(1).stall()  # held: the current is what the loop makes it, not back-EMF's
    host.wheel(2).stall()
    host.references(1.0, -0.5)  # N·m
    host.run(0.2)
    tail = host.telemetry[-50:]
    assert all(tm.a.reference == pytest.approx(1.0) for tm in tail)  # TM: N·m in this mode
    assert all(tm.b.reference == pytest.approx(-0.5) for tm in tail)
    assert sum(tm.a.current for tm in tail) / 50 == pytest.approx(1.0 / TORQUE_COEF, rel=0.01)
    assert sum(tm.b.current for tm in tail) / 50 == pytest.approx(-0.5 / TORQUE_COEF, rel=0.01)
    assert not any(tm.a.flags & 4 for tm in tail)  # settled, not clamped


def test_torque_beyond_what_the_duty_can_drive_is_flagged_saturated() -> None:
    host = streaming_host(3)
    host.wheel(1).stall()
    host.references(100.0, 0.0)  # 500 A: the supply gives 24 A at full duty
    host.run(0.1)
    last = host.telemetry[-1]
    assert last.a.pwm == 32760 and last.a.flags & 4
    assert last.a.current == pytest.approx(24.0, rel=0.01)


@pytest.mark.parametrize("mode", [0, 1])
def test_both_speed_loops_settle_a_step(mode: int) -> None:
    host = streaming_host(mode)
    host.references(45.0, -30.0)
    host.run(1.5)
    tail = host.telemetry[-100:]
    assert sum(tm.a.speed for tm in tail) / 100 == pytest.approx(45.0, rel=0.02)
    assert sum(tm.b.speed for tm in tail) / 100 == pytest.approx(-30.0, rel=0.02)


@pytest.mark.parametrize(("mode", "reacts_before_the_tick"), [(0, False), (1, True),
                                                              (2, False), (3, True)])
def test_the_hardware_loops_react_between_timer_ticks(mode: int,
                                                      reacts_before_the_tick: bool) -> None:
    host = streaming_host(mode, period_ms=10)  # ticks 10 ms apart
    # An RV that arrives 1 ms after a tick: where is the duty 5 ms later, before the next?
    next_tick = host.timer.next_tick
    assert next_tick is not None
    host.run_to(next_tick + ms(1))
    duty_before = host.io(1).pwm.duty_register
    host.references(40.0 if mode < 2 else 1.0, 0.0)
    host.run_to(next_tick + ms(6))
    changed = host.io(1).pwm.duty_register != duty_before
    assert changed == reacts_before_the_tick


def test_changing_mode_while_enabled_starts_the_new_controller_from_rest() -> None:
    host = streaming_host(0)
    host.references(45.0, 45.0)
    host.run(0.5)
    assert host.io(1).pwm.duty_register != 0
    assert isinstance(host.set(4, 1, 1, 2), ParamAck)  # speed → torque, while enabled
    firmware = host.firmware
    assert firmware.channels[1].reference == 0.0  # a speed is not a torque
    assert firmware.channels[2].reference == 45.0  # the other channel is untouched
    host.run(0.05)
    assert host.telemetry[-1].a.reference == 0.0
    assert abs(host.telemetry[-1].a.current) < 0.5  # the torque loop holds zero current
    assert isinstance(host.set(4, 1, 1, 1), ParamAck)  # → hardware speed, from rest too
    hardware = firmware.channels[1].hardware
    assert hardware is not None and hardware.running
    assert hardware.reference == 0 and firmware.channels[1].reference == 0.0


def test_disabling_stops_the_hardware_loop_and_re_enabling_starts_it_from_rest() -> None:
    host = streaming_host(1)
    hardware = host.firmware.channels[1].hardware
    assert hardware is not None and hardware.running
    host.references(45.0, 0.0)
    host.run(0.3)
    host.keep_enabled = False
    host.disable()
    host.run(0.01)
    assert not hardware.running and host.io(1).pwm.applied_duty == 0
    assert hardware.integral == 0 and hardware.reference == 0
    host.start_enabled()
    host.run(0.01)
    assert hardware.running


def test_the_hardware_runs_at_its_own_fixed_rate() -> None:
    host = streaming_host(1, period_ms=7)
    hardware = host.firmware.channels[1].hardware
    assert hardware is not None
    ticks: list[int] = []
    hardware.on_tick = ticks.append
    host.run(0.05)
    assert all(t % HW_PERIOD_CYCLES == 0 for t in ticks)
    assert [b - a for a, b in itertools.pairwise(ticks)] == \
        [HW_PERIOD_CYCLES] * (len(ticks) - 1)
    assert len(ticks) == pytest.approx(500, abs=2)  # 10 kHz for 50 ms


@pytest.mark.parametrize("td", [0.0, 0.02])
def test_the_fixed_point_law_follows_the_floating_point_pid(td: float) -> None:
    """The reference model: the software PID in floating point, at the module's period."""
    gains = PidGains(kp=520.0, ti=0.24, td=td)
    dt = HW_PERIOD_CYCLES / 100e6
    reference_model = Pid(gains, limit=32760)
    board = build_board()
    module = HardwareController(board, board.channels[1])
    module.configure(LoopInput.SPEED, gains, 32760)
    assert module.coefficients == Coefficients.from_gains(gains, dt)
    module.write_reference(30.0)
    rng = random.Random(5)
    speed = 0.0
    for _ in range(3000):
        speed += (rng.random() - 0.45) * 2.0
        expected = reference_model.update(30.0, speed, dt)
        got = module.update(to_fixed(speed))
        # The law is the same; fixed point differs by its rounding, a few counts at most.
        assert abs(got - expected) <= 3, (got, expected)
        assert module.saturated == reference_model.saturated or abs(abs(expected) - 32760) < 4
    assert math.isclose(module.integral / (1 << FRACTION_BITS), reference_model.integral,
                        rel_tol=1e-3, abs_tol=2.0)
