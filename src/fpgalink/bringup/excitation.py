"""What drives a wheel while it is identified: a pseudo-random binary sequence (PRBS) of
duty between two levels, after a first level held to let the wheel settle.

The board takes no duty directly, but its speed PID can be made a unit gain: with
``Kp_Wheel_Pid`` = 1 PWM count per deg/s, ``Ti_Wheel_Pid`` = 10⁹ s and ``Td_Wheel_Pid`` = 0
the PID's output is ``reference − speed`` (its integral adds under a count in a minute), so a
reference of N "deg/s" is a duty of N counts less the wheel's speed in deg/s — at most 90,
0.3 % of full duty. That is open loop in all but name, and the fit does not care: it uses
the duty the board reports applying (``TM``'s ``pwm``), not the one asked for.
``MaxControlSignal`` set to the user's limit clamps whatever is asked.

* Wheels in the air: the duty steps between 40 % and 100 % of the limit, one way round
  (no reversal through the gearbox's backlash, no stop on the worm gear's lock: the seed
  linearised around 50 % duty for the same reason).
* Wheels on the ground: between −100 % and +100 % of the limit, so the robot rocks about
  where it stands instead of driving away.

A maximum-length sequence's spectrum is flat up to about 1/(3·bit time) and it has the
fewest level changes for that: with the default 0.2 s bit (near the seed's plants' 0.24 s
time constant) it excites 0.05–5 rad/s and up, where the speed loop's crossover will be.
Sans-I/O."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["OPEN_LOOP_GAINS", "Excitation", "prbs"]

#: The speed PID as a unit gain (Kp PWM counts per deg/s, Ti s, Td s): reference → duty.
OPEN_LOOP_GAINS = (1.0, 1e9, 0.0)
#: Feedback taps of maximum-length LFSRs (Fibonacci, XNOR-free), by order.
_TAPS = {5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4), 9: (9, 5), 10: (10, 7)}


def prbs(order: int, seed: int = 1) -> list[int]:
    """One period (2^order − 1 bits) of a maximum-length sequence of 0 and 1."""
    if order not in _TAPS:
        raise ValueError(f"PRBS order must be one of {sorted(_TAPS)}, got {order}")
    state = (seed % ((1 << order) - 1)) + 1  # never the all-zero state
    taps = _TAPS[order]
    bits = []
    for _ in range((1 << order) - 1):
        bits.append(state & 1)
        feedback = 0
        for tap in taps:
            feedback ^= (state >> (order - tap)) & 1
        state = (state >> 1) | (feedback << (order - 1))
    return bits


@dataclass(frozen=True, slots=True)
class Excitation:
    """The duty over time: ``settle_s`` at the high level, then a PRBS of ``bit_s`` bits
    between ``low`` and ``high`` (PWM counts) for the rest of ``duration_s``."""

    low: int
    high: int
    duration_s: float = 20.0
    bit_s: float = 0.2
    settle_s: float = 1.0
    order: int = 6
    seed: int = 1

    def __post_init__(self) -> None:
        for name, value in (("duration_s", self.duration_s), ("bit_s", self.bit_s),
                            ("settle_s", self.settle_s)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number ≥ 0, got {value!r}")
        if self.bit_s <= 0 or self.duration_s <= self.settle_s:
            raise ValueError("the bit time must be positive and the duration longer than "
                             "the settling")
        if self.low == self.high:
            raise ValueError("the two levels must differ")

    @classmethod
    def for_wheels(cls, wheels: str, limit: int, **options: float | int) -> Excitation:
        """The levels for ``wheels`` ``"air"`` or ``"ground"`` under a duty ``limit``."""
        if not 0 < limit <= 32760:
            raise ValueError(f"the duty limit must be 1..32760 PWM counts, got {limit}")
        if wheels == "air":
            return cls(round(0.4 * limit), limit, **options)  # type: ignore[arg-type]
        if wheels == "ground":
            return cls(-limit, limit, **options)  # type: ignore[arg-type]
        raise ValueError(f"wheels must be 'air' or 'ground', got {wheels!r}")

    def changes(self) -> list[tuple[float, int]]:
        """(time s, duty) at every change, from 0; the last entry is (duration, 0)."""
        out: list[tuple[float, int]] = [(0.0, self.high)]
        bits = prbs(self.order, self.seed)
        t, i = self.settle_s, 0
        level = self.high
        while t < self.duration_s - 1e-9:
            new = self.high if bits[i % len(bits)] else self.low
            if new != level:
                out.append((t, new))
                level = new
            t += self.bit_s
            i += 1
        out.append((self.duration_s, 0))
        return out

    def duty_at(self, t: float) -> int:
        """The duty asked at ``t`` s (0 before the start and from the end)."""
        if t < 0:
            return 0
        duty = 0
        for at, value in self.changes():
            if at > t:
                break
            duty = value
        return duty
