"""Drive the part-2 models together the way the firmware does, without a timeline: the plant
advanced in ≤ 1 ms pieces, the encoder following each piece, the PID run at every timer tick
on the encoder's M/T speed reading."""

from __future__ import annotations

from dataclasses import dataclass, field

from fpgaemu.encoder import QuadratureEncoder
from fpgaemu.motor import WheelPlant, turn
from fpgaemu.pid import Pid, PidGains
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol import float32, lookup

#: The power-up tuning from the parameter table, as the board stores it (float32).
DEFAULT_GAINS = PidGains(*(float32(float(lookup(name).default))
                           for name in ("Kp_Wheel_Pid", "Ti_Wheel_Pid", "Td_Wheel_Pid")))


def advance(plant: WheelPlant, encoder: QuadratureEncoder, start: int, end: int) -> int:
    """Hold the plant's duty from ``start`` to ``end`` (cycles), feeding the encoder."""
    turn(plant, encoder, start, end)
    return end


@dataclass
class StepRun:
    """One closed-loop run, sampled at every timer tick."""

    reference: float
    period_s: float
    times: list[float] = field(default_factory=list)
    true_speed: list[float] = field(default_factory=list)  #: the plant's wheel speed
    measured: list[float] = field(default_factory=list)  #: the encoder's M/T reading
    duty: list[int] = field(default_factory=list)

    def overshoot(self, signal: list[float] | None = None) -> float:
        values = self.true_speed if signal is None else signal
        if self.reference >= 0:
            return max(0.0, max(values) / self.reference - 1.0)
        return max(0.0, min(values) / self.reference - 1.0)

    def settling_time(self, band: float = 0.02, signal: list[float] | None = None) -> float:
        """The last time the signal was outside ±band·|reference| (0 if it never was)."""
        values = self.true_speed if signal is None else signal
        limit = band * abs(self.reference)
        last = 0.0
        for t, v in zip(self.times, values, strict=True):
            if abs(v - self.reference) > limit:
                last = t
        return last


def step_response(reference: float, gains: PidGains = DEFAULT_GAINS, period_ms: int = 1,
                  duration_s: float = 2.0, gear: str = "high", pulses_per_turn: int = 500,
                  limit: int = 32760) -> StepRun:
    """0 → ``reference`` deg/s at t = 0 with the speed PID closed through the encoder."""
    plant = WheelPlant(gear)
    encoder = QuadratureEncoder(pulses_per_turn)
    pid = Pid(gains, limit)
    period = period_ms * CLOCK_HZ // 1000
    run = StepRun(reference, period / CLOCK_HZ)
    cycle = 0
    for _ in range(round(duration_s * CLOCK_HZ / period)):
        speed = encoder.sample_speed(cycle)
        plant.duty = pid.update(reference, speed, period / CLOCK_HZ)
        cycle = advance(plant, encoder, cycle, cycle + period)
        run.times.append(cycle / CLOCK_HZ)
        run.true_speed.append(plant.speed_dps)
        run.measured.append(speed)
        run.duty.append(plant.duty)
    return run
