"""PWM stage: clamp, gating by global_enable, and the notice a motor gets before the output
changes."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.pwm import MAX_DUTY, Pwm


@given(st.integers(-100_000, 100_000), st.booleans())
def test_pwm_clamps_and_gates(duty: int, enabled: bool) -> None:
    pwm = Pwm()
    pwm.set_global_enable(enabled, 0)
    pwm.write_duty(duty, 0)
    assert pwm.duty_register == max(-MAX_DUTY, min(MAX_DUTY, duty))
    assert pwm.applied_duty == (pwm.duty_register if enabled else 0)
    assert pwm.direction == (pwm.applied_duty > 0) - (pwm.applied_duty < 0)


def test_pwm_output_is_low_until_enabled_and_again_after() -> None:
    pwm = Pwm()
    pwm.write_duty(-12000, 0)
    assert pwm.applied_duty == 0 and pwm.direction == 0
    pwm.set_global_enable(True, 0)
    assert pwm.applied_duty == -12000 and pwm.direction == -1
    pwm.set_global_enable(False, 0)
    assert pwm.applied_duty == 0
    assert pwm.duty_register == -12000  # the register keeps what the processor wrote


def test_listeners_hear_of_a_change_before_it_happens_and_only_of_real_changes() -> None:
    pwm = Pwm()
    seen: list[tuple[int, int]] = []
    pwm.on_change(lambda cycle: seen.append((cycle, pwm.applied_duty)))
    pwm.set_global_enable(True, 10)
    pwm.write_duty(500, 20)
    pwm.write_duty(500, 30)  # same value: nothing changes
    pwm.set_global_enable(True, 40)
    pwm.set_global_enable(False, 50)
    # Each listener sees the output as it was, at the cycle it is about to change.
    assert seen == [(10, 0), (20, 0), (50, 500)]
