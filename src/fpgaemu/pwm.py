"""PWM stage per channel: a signed 16-bit duty register (sign = direction, magnitude = duty,
32760 = 100 %), whose output is forced low while ``global_enable`` is low.

Simplification: the switching waveform itself is not modelled; the motor sees the average
(duty), which is what the identified plant was measured against.

Whatever the output drives is told *before* the output changes (``on_change``), with the
cycle of the change, so a motor model can integrate up to that exact cycle with the old
duty.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

__all__ = ["MAX_DUTY", "Pwm"]

MAX_DUTY: Final = 32760


class Pwm:
    __slots__ = ("_listeners", "duty_register", "global_enable")

    def __init__(self) -> None:
        self.duty_register = 0  #: what the processor last wrote
        self.global_enable = False
        self._listeners: list[Callable[[int], None]] = []

    def on_change(self, listener: Callable[[int], None]) -> None:
        """``listener(cycle)`` runs just before the applied duty may change at ``cycle``."""
        self._listeners.append(listener)

    def write_duty(self, duty: int, cycle: int) -> None:
        """Processor write. The register is 16 bits but the stage saturates at ±32760."""
        value = int(duty)
        if value > MAX_DUTY:
            value = MAX_DUTY
        elif value < -MAX_DUTY:
            value = -MAX_DUTY
        if value != self.duty_register:
            for listener in self._listeners:
                listener(cycle)
            self.duty_register = value

    def set_global_enable(self, enabled: bool, cycle: int) -> None:
        if enabled != self.global_enable:
            for listener in self._listeners:
                listener(cycle)
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
