"""Shared driver for the reliability tests: an emulated board and a sans-I/O host Connection
on one emulated clock. No wall clock anywhere, so 60 s of 1 kHz telemetry runs in seconds.

The host loop is what an asyncio Link does, in steps: run the board to the next step, feed
the TX bytes that have completed to the Connection, drain its events, fire its timer when
due, and put what it wants to send on the RX pin at that moment.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fpgaemu.board import Board
from fpgaemu.build import build_board
from fpgaemu.firmware import Firmware
from fpgaemu.motor import Motors, WheelPlant
from fpgaemu.timeline import CLOCK_HZ, seconds_to_cycles
from fpgalink import Connection
from fpgalink.protocol import Message, Telemetry, encode_message, parse_content

#: FPGALINK_LONG=1 runs every guarantee at full scale (see docs/reliability.md).
LONG = os.environ.get("FPGALINK_LONG") == "1"

STREAMING = {"TsTimerPeriod": 1, "GetDataPeriodical": 1}


def scale(ci: int, full: int) -> int:
    return full if LONG else ci


@dataclass
class Rig:
    board: Board
    firmware: Firmware
    conn: Connection
    step_s: float = 0.001
    host_alive: bool = True
    #: TM content the firmware queued, by counter (recorded at the firmware's send call)
    sent_tm: dict[int, bytes] = field(default_factory=dict)
    #: cycle each host write's last stop bit ends, and the bytes
    writes: list[tuple[int, bytes]] = field(default_factory=list)

    @property
    def now(self) -> float:
        return self.board.now / CLOCK_HZ

    def wheel(self, code: int) -> WheelPlant:
        motors = self.board.peripherals["motors"]
        assert isinstance(motors, Motors)
        return motors.wheels[code]

    def write(self, data: bytes) -> None:
        if data:
            self.writes.append((self.board.host_write(data), data))

    def send(self, message: Message) -> None:
        """What the host's link does for one message: queue it, put its bytes on the wire."""
        self.conn.send(message, self.now)
        self.write(self.conn.data_to_send())

    def step(self, on_event: Callable[[Any], None] | None = None) -> None:
        board, conn = self.board, self.conn
        board.run_until(board.now + seconds_to_cycles(self.step_s))
        now = self.now
        conn.receive_data(board.read_host_bytes(), now)
        for event in conn.events():
            if on_event is not None:
                on_event(event)
        if not self.host_alive:
            return
        deadline = conn.get_timer()
        if deadline is not None and deadline <= now:
            conn.handle_timer(now)
            for event in conn.events():
                if on_event is not None:
                    on_event(event)
        self.write(conn.data_to_send())

    def run(self, seconds: float, on_event: Callable[[Any], None] | None = None) -> None:
        end = self.board.now + seconds_to_cycles(seconds)
        while self.board.now < end:
            self.step(on_event)


def make_rig(
    *, seed: int = 0, faults: list[str] | None = None, settings: dict[str, Any] | None = None,
    record_tm: bool = False, **conn_options: Any,
) -> Rig:
    board = build_board(seed=seed, settings=settings or {}, faults=faults or [])
    firmware = board.peripherals["firmware"]
    assert isinstance(firmware, Firmware)
    rig = Rig(board, firmware, Connection(**conn_options))
    if record_tm:

        def recording(content: bytes, cycle: int) -> None:
            if content[:2] == b"TM":
                rig.sent_tm[int(content[2:7])] = content

        board.uartsend.on_frame(recording)
    return rig


def content_of(message: Telemetry) -> bytes:
    """The frame content a delivered Telemetry stands for (its fields as received)."""
    assert message.counter is not None, "a received message always has its counter"
    return encode_message(message, message.counter)


def body_of(content: bytes) -> bytes:
    return content[7:]


def parses_as_telemetry(content: bytes) -> bool:
    return isinstance(parse_content(content), Telemetry)
