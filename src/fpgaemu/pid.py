"""The firmware's software PID, one per channel and loop (seed §3.3): the speed loop with
SPEC §5 parameters 8–10 (PWM counts per deg/s), and the current loop of ``ActiveController``
2 with the firmware's own gains (PWM counts per A; :mod:`fpgaemu.firmware`).

Parallel form in the seed's parameters: u = Kp·(e + (1/Ti)∫e dt + Td·de/dt), with
* the derivative taken on the measurement (a reference step does not kick the output) and
  filtered with time constant Td/N, N = 10;
* the output clamped to ±MaxControlSignal;
* anti-windup by conditional integration: while the output is clamped, the integrator only
  moves in the direction that leaves the clamp;
* ``reset()`` while disabled, so re-enabling starts from rest;
* a non-finite reference or measurement (a broken sensor, a bug upstream) outputs 0 and
  resets the state, so no NaN or infinity ever enters the integrator — where a NaN would
  make every later comparison with the clamp false and latch the output at its limit.
Units: error in deg/s (or A), output in PWM counts (32760 = 100 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import isfinite
from typing import Final

__all__ = ["Pid", "PidGains"]

DERIVATIVE_FILTER_N: Final = 10.0


@dataclass(frozen=True, slots=True)
class PidGains:
    kp: float  #: PWM counts per deg/s (per A in a current loop)
    ti: float  #: s
    td: float  #: s


class Pid:
    def __init__(self, gains: PidGains, limit: int = 32760) -> None:
        self.gains = gains
        self.limit = limit
        self.integral = 0.0
        self._derivative = 0.0
        self._last_measurement: float | None = None
        self.saturated = False

    def reset(self) -> None:
        self.integral = 0.0
        self._derivative = 0.0
        self._last_measurement = None
        self.saturated = False

    @property
    def at_rest(self) -> bool:
        """Reset: no state that the next update would carry."""
        return (self.integral == 0.0 and self._derivative == 0.0
                and self._last_measurement is None and not self.saturated)

    def update(self, reference: float, measurement: float, dt: float) -> int:
        """One controller period; returns the duty command."""
        if not (isfinite(reference) and isfinite(measurement)):
            self.reset()
            return 0
        g = self.gains
        kp = g.kp
        error = reference - measurement
        proportional = kp * error
        if g.td > 0.0 and self._last_measurement is not None and dt > 0:
            tf = g.td / DERIVATIVE_FILTER_N
            raw = -kp * g.td * (measurement - self._last_measurement) / dt
            self._derivative += (raw - self._derivative) * dt / (tf + dt)
        self._last_measurement = measurement
        step = kp * dt / g.ti * error
        candidate = proportional + self.integral + step + self._derivative
        limit = self.limit
        if candidate > limit:
            if step < 0:
                self.integral += step
            self.saturated = True
            return round(limit)
        if candidate < -limit:
            if step > 0:
                self.integral += step
            self.saturated = True
            return round(-limit)
        if candidate != candidate:
            # NaN (both tests above fail): gains beyond any parameter's range overflowed to
            # inf − inf. Nothing is driven by it, and the controller starts again from rest.
            self.reset()
            return 0
        self.integral += step
        self.saturated = False
        return round(candidate)
