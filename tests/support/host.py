"""A host at the end of an emulated board's cable, sans I/O: fpgalink's ``Connection`` encodes
what the host sends and decodes what the board's TX pin produced. Everything runs on the
board's timeline (integer 100 MHz cycles); nothing sleeps."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from fpgaemu.board import Board, ChannelIo
from fpgaemu.build import build_board
from fpgaemu.cfirmware import CFirmware
from fpgaemu.firmware import Firmware
from fpgaemu.motor import Motors, WheelPlant
from fpgaemu.timeline import CLOCK_HZ, ms
from fpgaemu.timer import Timer
from fpgalink import Connection, Telemetry
from fpgalink.events import BoardFound
from fpgalink.protocol import (
    Disable,
    Enable,
    Message,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
)

MS = ms(1)  #: cycles per millisecond
#: the host's heartbeat: well inside the board's 300 ms watchdog
RE_EVERY_MS = 100
#: the firmware ``Host.make()`` builds boards with (tests/support/firmwares.py sets it)
DEFAULT_FIRMWARE = "python"


@dataclass
class Host:
    """One board and the host's side of its link."""

    board: Board
    firmware: Firmware | CFirmware
    conn: Connection = field(default_factory=lambda: Connection(baud=None))
    telemetry: list[Telemetry] = field(default_factory=list)
    replies: list[ParamAck | ParamNack] = field(default_factory=list)
    other: list[object] = field(default_factory=list)
    wire_bytes_read: int = 0
    #: send ``RE`` every RE_EVERY_MS while :meth:`run` advances time
    keep_enabled: bool = False
    _next_re: int = 0

    # --- building -------------------------------------------------------------------------

    @classmethod
    def make(cls, *, baud: int = 1_000_000, gear: str = "high",
             settings: dict[str, Any] | None = None, firmware_kind: str | None = None) -> Host:
        board = build_board(baud=baud, gear=gear, settings=settings,
                            firmware=firmware_kind or DEFAULT_FIRMWARE)
        firmware = board.peripherals["firmware"]
        assert isinstance(firmware, Firmware | CFirmware)
        return cls(board, firmware)

    # --- the board's parts ----------------------------------------------------------------

    def io(self, code: int) -> ChannelIo:
        """Channel ``code``'s PWM stage, encoder and current sensor."""
        return self.board.channels[code]

    def wheel(self, code: int) -> WheelPlant:
        """Channel ``code``'s motor and wheel (brought up to the last sample)."""
        motors = self.board.peripherals["motors"]
        assert isinstance(motors, Motors)
        return motors.wheels[code]

    @property
    def timer(self) -> Timer:
        return self.board.timer

    @property
    def now_s(self) -> float:
        return self.board.now / CLOCK_HZ

    # --- the cable ------------------------------------------------------------------------

    def send(self, message: Message | Enable | Disable, cycle: int | None = None) -> int:
        """Put ``message`` on the RX pin (now, or at ``cycle``); returns its STOP's cycle."""
        self.conn.send(message, self.now_s)
        return self.board.host_write(self.conn.data_to_send(), cycle)

    def enable(self) -> int:
        return self.send(Enable())

    def disable(self) -> int:
        return self.send(Disable())

    def drain(self) -> None:
        """Decode every byte the board finished sending by now."""
        data = self.board.read_host_bytes()
        self.wire_bytes_read += len(data)
        self.conn.receive_data(data, self.now_s)
        for event in self.conn.events():
            if isinstance(event, Telemetry):
                self.telemetry.append(event)
            elif isinstance(event, ParamAck | ParamNack):
                self.replies.append(event)
            elif not isinstance(event, BoardFound):
                self.other.append(event)

    def run(self, seconds: float, step_ms: int = 10) -> None:
        """Advance ``seconds`` in ``step_ms`` slices, draining the TX pin after each slice
        and sending ``RE`` on schedule while ``keep_enabled``."""
        end = self.board.now + round(seconds * CLOCK_HZ)
        while self.board.now < end:
            if self.keep_enabled and self.board.now >= self._next_re:
                self.enable()
                self._next_re = self.board.now + RE_EVERY_MS * MS
            target = min(end, self.board.now + step_ms * MS)
            if self.keep_enabled:
                target = min(target, max(self._next_re, self.board.now + 1))
            self.board.run_until(target)
            self.drain()

    def run_to(self, cycle: int) -> None:
        self.run((cycle - self.board.now) / CLOCK_HZ, step_ms=1)

    def start_enabled(self) -> None:
        self.keep_enabled = True
        self._next_re = self.board.now

    # --- parameters -----------------------------------------------------------------------

    def request(self, message: ParamSet | ParamGet) -> ParamAck | ParamNack:
        """Send one request and return the board's one reply (PA or PN)."""
        before = len(self.replies)
        self.send(message)
        self.run(0.003, step_ms=1)
        new = self.replies[before:]
        assert len(new) == 1, f"expected one reply to {message}, got {new}"
        return new[0]

    def set(self, param_id: int, channel: int, value_type: int,
            value: int | float) -> ParamAck | ParamNack:
        return self.request(ParamSet(param_id, channel, value_type, value))

    def get(self, param_id: int, channel: int) -> ParamAck | ParamNack:
        return self.request(ParamGet(param_id, channel))

    def references(self, ref_a: float, ref_b: float) -> int:
        return self.send(References(ref_a, ref_b))

    # --- reading the TM stream ------------------------------------------------------------

    def telemetry_since(self, cycle: int) -> list[Telemetry]:
        t_us = cycle // 100
        return [tm for tm in self.telemetry if tm.t_us >= t_us]


@dataclass
class StepFigures:
    overshoot: float  #: fraction of the step
    settling_s: float  #: last time outside the ±band, from the step
    final: float


def step_figures(samples: list[tuple[float, float]], start: float, reference: float,
                 band: float = 0.02) -> StepFigures:
    """Overshoot and settling time of ``(time_s, value)`` samples for a step from 0 to
    ``reference`` at ``start``."""
    after = [(t - start, v) for t, v in samples if t >= start]
    peak = max(v / reference for _, v in after)
    limit = band * abs(reference)
    last = 0.0
    for t, v in after:
        if abs(v - reference) > limit:
            last = t
    return StepFigures(max(0.0, peak - 1.0), last, after[-1][1])


def counts_floor(angle_deg: float, counts_per_turn: int) -> int:
    return math.floor(angle_deg * counts_per_turn / 360.0)
