"""The FPGA's controller module per channel (``ActiveController`` 1 and 3: the hardware speed
and current PID), as a System Generator block would build it: a fixed-point PID that runs at
its own fixed rate, :data:`HW_PERIOD_CYCLES` (10 kHz), independent of ``TsTimerPeriod``.

The firmware writes its registers — mode, coefficients, reference, output limit — and the
module does the rest: at each of its ticks, while enabled, it reads its input (the speed
from its own M/T window on the position counter, or the Hall sensor's current), computes
the law and writes the PWM duty. A reference written between two timer interrupts takes
effect at the module's next tick, not at the next timer interrupt.

**Arithmetic.** Signed fixed point with 16 fraction bits: the reference, the measurement,
the error and the integrator in 32-bit registers (Q16.16, range ±32768, saturating); the
coefficients and the derivative path in 48-bit ones (Q32.16: Kp·Td/dt reaches 10⁵ and
more); products are full width and shifted back (truncating towards −∞, as an arithmetic
shift does); the output is the integer part, clamped to ±MaxControlSignal. The
coefficients are precomputed by the firmware from the standard-form gains, as a System
Generator design would receive them over AXI:

    kp = Kp,  ki = Kp·dt/Ti,  kd = Kp·Td/dt,  alpha = dt/(Td/N + dt)   (dt = 100 µs, N = 10)

The law is the software PID's (:mod:`fpgaemu.pid`): derivative on the measurement through a
first-order filter, conditional integration while the output is clamped.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Final

from fpgaemu.pid import DERIVATIVE_FILTER_N, PidGains
from fpgaemu.timeline import CLOCK_HZ, EventHandle

if TYPE_CHECKING:
    from fpgaemu.board import Board, ChannelIo
    from fpgaemu.encoder import SpeedReader

__all__ = ["FRACTION_BITS", "HW_PERIOD_CYCLES", "Coefficients", "HardwareController",
           "LoopInput"]

#: 10 kHz: ten times the fastest timer period, a hundredth of the wheel's time constant
HW_PERIOD_CYCLES: Final = 10_000
FRACTION_BITS: Final = 16
COEFFICIENT_BITS: Final = 48
#: the derivative path: Kp·Td·Δspeed/dt is far beyond the output range before the filter
WIDE_BITS: Final = 48
ONE: Final = 1 << FRACTION_BITS


class LoopInput(Enum):
    SPEED = "speed"  #: deg/s, from the module's own M/T window
    CURRENT = "current"  #: A, from the Hall sensor


def to_fixed(value: float, bits: int = 32) -> int:
    """A register value with 16 fraction bits, saturated to ``bits`` (32: Q16.16)."""
    if not math.isfinite(value):
        return 0
    top = (1 << (bits - 1)) - 1
    return max(-top - 1, min(top, round(value * ONE)))


def _saturate(value: int, bits: int = 32) -> int:
    top = (1 << (bits - 1)) - 1
    return max(-top - 1, min(top, value))


@dataclass(frozen=True, slots=True)
class Coefficients:
    """The module's coefficient registers, Q16.16."""

    kp: int
    ki: int
    kd: int
    alpha: int

    @classmethod
    def from_gains(cls, gains: PidGains, dt: float) -> Coefficients:
        td = gains.td
        alpha = dt / (td / DERIVATIVE_FILTER_N + dt) if td > 0 else 1.0
        return cls(to_fixed(gains.kp, COEFFICIENT_BITS),
                   to_fixed(gains.kp * dt / gains.ti, COEFFICIENT_BITS),
                   to_fixed(gains.kp * td / dt, COEFFICIENT_BITS), to_fixed(alpha))


class HardwareController:
    """One channel's module. ``configure`` it, ``start`` it when enabled in a hardware mode,
    ``stop`` it otherwise; the PWM is its while it runs."""

    def __init__(self, board: Board, io: ChannelIo) -> None:
        self._board = board
        self._io = io
        self._speed: SpeedReader = io.encoder.reader()
        self.loop = LoopInput.SPEED
        self.coefficients = Coefficients(0, 0, 0, ONE)
        self.reference = 0  #: Q16.16, deg/s or A
        self.limit = 32760
        self.integral = 0  #: Q16.16 PWM counts
        self._derivative = 0
        self._last_measurement: int | None = None
        self.saturated = False
        self.ticks = 0
        self._event: EventHandle | None = None
        #: called after every tick with the cycle (a logic analyser, a test)
        self.on_tick: Callable[[int], None] | None = None

    @property
    def running(self) -> bool:
        return self._event is not None

    def configure(self, loop: LoopInput, gains: PidGains, limit: int) -> None:
        self.loop = loop
        self.coefficients = Coefficients.from_gains(gains, HW_PERIOD_CYCLES / CLOCK_HZ)
        self.limit = limit

    def write_reference(self, value: float) -> None:
        self.reference = to_fixed(value)

    def reset(self) -> None:
        self.integral = 0
        self._derivative = 0
        self._last_measurement = None
        self.saturated = False

    def start(self, cycle: int) -> None:
        """Run from the next module tick after ``cycle`` (ticks are on its own 10 kHz grid)."""
        if self._event is None:
            first = (cycle // HW_PERIOD_CYCLES + 1) * HW_PERIOD_CYCLES
            self._event = self._board.schedule(first, self._tick)

    def stop(self) -> None:
        if self._event is not None:
            self._event.cancel()
            self._event = None
        self.reset()

    def _measure(self, cycle: int) -> int:
        if self.loop is LoopInput.SPEED:
            return to_fixed(self._speed.sample(cycle))
        return to_fixed(self._io.current_a)

    def _tick(self, cycle: int) -> None:
        self._event = self._board.schedule(cycle + HW_PERIOD_CYCLES, self._tick)
        self._board.settle(cycle)
        measurement = self._measure(cycle)
        self._io.pwm.write_duty(self.update(measurement), cycle)
        self.ticks += 1
        if self.on_tick is not None:
            self.on_tick(cycle)

    def update(self, measurement: int) -> int:
        """One module tick on a Q16.16 measurement; the PWM duty it writes."""
        c = self.coefficients
        error = _saturate(self.reference - measurement)
        proportional = (c.kp * error) >> FRACTION_BITS
        if c.kd and self._last_measurement is not None:
            raw = _saturate(-((c.kd * (measurement - self._last_measurement))
                              >> FRACTION_BITS), WIDE_BITS)
            self._derivative = _saturate(
                self._derivative + ((c.alpha * (raw - self._derivative)) >> FRACTION_BITS),
                WIDE_BITS)
        self._last_measurement = measurement
        step = (c.ki * error) >> FRACTION_BITS
        candidate = proportional + self.integral + step + self._derivative
        limit = self.limit << FRACTION_BITS
        if candidate > limit:
            if step < 0:
                self.integral = _saturate(self.integral + step)
            self.saturated, candidate = True, limit
        elif candidate < -limit:
            if step > 0:
                self.integral = _saturate(self.integral + step)
            self.saturated, candidate = True, -limit
        else:
            self.integral = _saturate(self.integral + step)
            self.saturated = False
        return candidate >> FRACTION_BITS
