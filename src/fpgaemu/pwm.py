"""PWM stage per channel: a signed 16-bit duty register (sign = direction, magnitude = duty,
32760 = 100 %), whose output is forced low while ``global_enable`` is low.

Simplification: the switching waveform itself is not modelled; the motor sees the average
(duty), which is what the identified plant was measured against.
"""

from __future__ import annotations

__all__ = ["MAX_DUTY", "Pwm"]

MAX_DUTY = 32760


class Pwm:
    def __init__(self) -> None:
        self.duty_register = 0  #: what the processor last wrote
        self.global_enable = False

    def write_duty(self, duty: int) -> None:
        """Processor write. The register is 16 bits but the stage saturates at ±32760."""
        self.duty_register = max(-MAX_DUTY, min(MAX_DUTY, int(duty)))

    def set_global_enable(self, enabled: bool) -> None:
        self.global_enable = enabled

    @property
    def applied_duty(self) -> int:
        """What the H-bridge applies: 0 while disabled."""
        return self.duty_register if self.global_enable else 0

    @property
    def direction(self) -> int:
        """Direction output: 1 forward, -1 reverse, 0 when not driving."""
        duty = self.applied_duty
        return (duty > 0) - (duty < 0)
