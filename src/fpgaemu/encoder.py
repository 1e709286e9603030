"""Quadrature decoder and position counter per channel (seed: ``positioncounter``).

Counts per wheel turn = 10 × IncSenzRes (the seed's FPGA multiplies the sensor's pulse count
by 10); the counting direction is IncSenzCountDirection (±1). The count is
``floor((angle − offset) × counts_per_turn / 360)`` times the direction, where the offset
puts the angle at power-up (or at ``configure``) in the middle of count 0: a wheel at rest
sits inside a count, not on an edge, so the first hair of movement either way is no edge.

Edges are not simulated one event each: when the wheel is advanced over an interval, the
counter works out how many edges it crossed and the exact cycle of the last one, with the
angle taken as linear in time within the interval (the board advances the wheel at least
every millisecond, so at 90 deg/s the interpolation error is far below one count).

Speed is measured by the time-and-count (M/T) method, as the seed's ``positioncounter`` does:
at each sample, M = edges between the last edge of the previous window and the last edge of
this one, T = the cycles between those two edges on the 100 MHz clock, speed = M / T. When
no edge arrived since the last sample, the speed can be at most one count over the time
since the last edge, so the reading decays towards 0 instead of holding a stale value.

A measurement needs two edges: the first edge after power-up, after ``configure`` or after
more than ``SPEED_TIMEOUT_CYCLES`` without an edge only becomes the reference (wherever in
the window it falls), and the reading stays 0 until an edge after it: timing it from
anything else (power-up, the previous sample) would be arbitrary. The timeout is also why a
wheel at rest reads exactly 0 rather than a 1/t tail: it is 1 s, so the slowest speed
measured is one count per second (0.072 deg/s at the default 5000 counts per turn).
"""

from __future__ import annotations

import math
from typing import Final

from fpgaemu.timeline import CLOCK_HZ

__all__ = ["SPEED_TIMEOUT_CYCLES", "QuadratureEncoder", "SpeedReader"]

#: An edge older than this is no reference for a speed measurement (1 s at 100 MHz).
SPEED_TIMEOUT_CYCLES: Final = CLOCK_HZ


class SpeedReader:
    """A second M/T speed measurement on the same counter, with its own window: the FPGA's
    hardware controller reads speed at its own rate, and must not shorten the window the
    firmware's reading at the timer tick covers."""

    __slots__ = ("_encoder", "count", "cycle", "speed")

    def __init__(self, encoder: QuadratureEncoder) -> None:
        self._encoder = encoder
        self.count = 0
        self.cycle: int | None = None
        self.speed = 0.0

    def sample(self, now: int) -> float:
        """The M/T reading at ``now`` over this reader's window (deg/s, counting direction)."""
        encoder = self._encoder
        counts = encoder.counts_per_turn
        if counts <= 0:
            return 0.0
        deg_per_count = 360.0 / counts
        last = encoder.last_edge_cycle
        if last is None or self.cycle is None:
            self.speed = 0.0
        elif last > self.cycle:
            count = encoder.physical_count
            self.speed = (count - self.count) * deg_per_count * CLOCK_HZ / (last - self.cycle)
            self.count = count
            self.cycle = last
        else:
            since = now - last
            if since > SPEED_TIMEOUT_CYCLES:
                self.speed = 0.0
            elif since > 0:
                bound = deg_per_count * CLOCK_HZ / since
                if abs(self.speed) > bound:
                    self.speed = math.copysign(bound, self.speed)
        return self.speed * encoder.direction


class QuadratureEncoder:
    def __init__(self, pulses_per_turn: int = 500, direction: int = 1) -> None:
        self.counts_per_turn = 10 * pulses_per_turn
        self.direction = direction
        self.end_stop = False  #: the end-stop switch input
        #: the counter before the direction setting (``position`` applies it)
        self.physical_count = 0
        self._angle_offset = self._half_count()
        self.last_edge_cycle: int | None = None
        self._angle = 0.0  #: the wheel angle last followed, deg
        self.edges = 0  #: every edge seen (unsigned)
        #: the firmware's window (sampled at the timer tick) first; a hardware controller may
        #: add its own
        self.firmware_reader = SpeedReader(self)
        self._readers: list[SpeedReader] = [self.firmware_reader]

    def reader(self) -> SpeedReader:
        """A speed measurement of its own (see :class:`SpeedReader`)."""
        reader = SpeedReader(self)
        self._readers.append(reader)
        return reader

    def configure(self, pulses_per_turn: int, direction: int) -> None:
        """New resolution or direction: the count restarts from the wheel's present angle
        (as last followed: bring the wheel up to date first)."""
        self.counts_per_turn = 10 * pulses_per_turn
        self.direction = direction
        self._angle_offset = self._angle + self._half_count()
        self.physical_count = 0
        self.last_edge_cycle = None
        for reader in self._readers:
            reader.count, reader.cycle, reader.speed = 0, None, 0.0

    def power_up(self, angle_deg: float) -> None:
        """The counter starts at 0 with the wheel at ``angle_deg`` (a board that powers up
        beside a wheel that has turned before)."""
        self._angle = angle_deg
        self.configure(self.counts_per_turn // 10, self.direction)

    def _half_count(self) -> float:
        """Minus half a count in degrees (0 without an encoder)."""
        return -180.0 / self.counts_per_turn if self.counts_per_turn > 0 else 0.0

    def _index(self, angle_deg: float) -> int:
        return math.floor((angle_deg - self._angle_offset) * self.counts_per_turn / 360.0)

    def follow(self, cycle0: int, angle0: float, cycle1: int, angle1: float) -> None:
        """The wheel went from ``angle0`` at ``cycle0`` to ``angle1`` at ``cycle1``."""
        self._angle = angle1
        counts = self.counts_per_turn
        if counts <= 0:
            return
        # _index, written out: this runs for each wheel every emulated millisecond.
        offset = self._angle_offset
        n0 = math.floor((angle0 - offset) * counts / 360.0)
        n1 = math.floor((angle1 - offset) * counts / 360.0)
        if n0 == n1:
            return
        up = n1 > n0
        self.edges += n1 - n0 if up else n0 - n1
        step = 360.0 / counts
        span = cycle1 - cycle0
        moved = angle1 - angle0
        # Where the wheel crossed a count boundary, the angle taken as linear in time; the
        # first boundary crossed, then (below) the last.
        fraction = (offset + (n0 + 1 if up else n0) * step - angle0) / moved
        first = cycle0 + round(min(1.0, max(0.0, fraction)) * span)
        previous = self.last_edge_cycle
        stale = previous is None or first - previous > SPEED_TIMEOUT_CYCLES
        for reader in self._readers:
            if reader.cycle is None or stale:
                # No usable reference edge: the first edge of this stretch becomes it.
                reader.cycle = first
                reader.count = n0 + 1 if up else n0 - 1
        # The last boundary crossed: moving up it is where the count became n1, moving down
        # where it left n1 + 1.
        fraction = (offset + (n1 if up else n1 + 1) * step - angle0) / moved
        self.last_edge_cycle = cycle0 + round(min(1.0, max(0.0, fraction)) * span)
        self.physical_count = n1

    @property
    def position(self) -> int:
        """The counter register, as a signed 32-bit value."""
        value = (self.physical_count * self.direction) & 0xFFFF_FFFF
        return value - (1 << 32) if value & 0x8000_0000 else value

    @property
    def settled(self) -> bool:
        """The firmware's reading is 0 and stays 0 while no edge comes: sampling again
        would change nothing."""
        reader = self.firmware_reader
        return reader.speed == 0.0 and (self.last_edge_cycle is None
                                        or reader.cycle is None
                                        or self.last_edge_cycle <= reader.cycle)

    def sample_speed(self, now: int) -> float:
        """The M/T speed reading at ``now`` (deg/s, in the counting direction): the
        firmware's, over the window since its previous reading."""
        return self.firmware_reader.sample(now)
