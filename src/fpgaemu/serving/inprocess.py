"""``emu://`` in the host's own process: a board (or one of a robot's boards) paced by the
host's event loop, behind an asyncio transport (:class:`EmulatedTransport`) that fpgalink
opens through its URL scheme registry (:func:`open_emulated_transport`)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from fpgaemu.build import board_from_url
from fpgaemu.robot import robot_from_options, robot_from_url
from fpgaemu.serving.loop import Pacer
from fpgaemu.serving.pacing import PacedBoard, PacedRobot, RobotSide

__all__ = ["FAR_END_LAG_EXTRA", "TRUTH_EXTRA", "WRITE_BUFFER_HIGH", "EmulatedTransport",
           "open_emulated_transport"]

#: ``transport.get_extra_info(FAR_END_LAG_EXTRA)`` on an in-process emulated board: a
#: function giving how far, in seconds, the board's time trails the host's clock
#: (:meth:`PacedBoard.behind`). fpgalink's link keeps its time that much behind, so a host
#: process starved together with its board does not take the board's unmade samples for a
#: board that stopped (the name is fpgalink's, which never imports the emulator).
FAR_END_LAG_EXTRA = "fpgalink.far_end_lag"

#: ``transport.get_extra_info(TRUTH_EXTRA)`` on an emulated robot's board: a function that
#: returns the body's true state as a JSON-ready dict (fpgalink reads it without importing
#: the emulator).
TRUTH_EXTRA = "fpgaemu.truth"


#: asyncio's own defaults for a transport's write buffer: the protocol is asked to pause
#: writing above the high mark and to resume at the low one.
WRITE_BUFFER_HIGH = 64 * 1024


class EmulatedTransport(asyncio.Transport):
    """An asyncio transport whose far end is a board in this process. What the host writes
    is never dropped: it waits in the transport's buffer and goes onto the RX line as the
    line makes room, as a serial transport's buffer drains into its port; the protocol's
    ``pause_writing()``/``resume_writing()`` are called at the buffer's limits, as asyncio's
    own transports do (:meth:`set_write_buffer_limits`, :meth:`get_write_buffer_size`)."""

    def __init__(self, paced: PacedBoard, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.paced = paced
        self._protocol = protocol
        self._closing = False
        self._buffer = bytearray()  #: written by the host, not yet on the RX line
        self._high = WRITE_BUFFER_HIGH
        self._low = WRITE_BUFFER_HIGH // 4
        self._protocol_paused = False
        self.pacer = Pacer(self._tick, self._next_wake)
        self.pacer.start()

    def _next_wake(self) -> float | None:
        wake = self.paced.next_wake()
        if self._buffer:
            feed = self.paced.rx_resume_at()
            wake = feed if wake is None else min(wake, feed)
        return wake

    def _tick(self) -> None:
        out = self.paced.advance()
        self._feed()
        if out and not self._closing:
            self._protocol.data_received(out)

    def _feed(self, everything: bool = False) -> None:
        """Move buffered bytes onto the RX line as far as it has room (all of them when the
        transport closes: they were written before it did)."""
        if self._buffer:
            # The host in this process lives on the board's time (FAR_END_LAG_EXTRA): what
            # it writes enters the line at the board's present, even when the board trails
            # the wall clock, so heartbeats reach the board as far apart as they were sent.
            now = self.paced.clock() - self.paced.behind()
            room = len(self._buffer) if everything else self.paced.rx_room(now)
            if room > 0:
                self.paced.host_write(bytes(self._buffer[:room]), now)
                del self._buffer[:room]
        self._flow()

    def _flow(self) -> None:
        size = len(self._buffer)
        if not self._protocol_paused and size > self._high:
            self._protocol_paused = True
            self._protocol.pause_writing()
        elif self._protocol_paused and size <= self._low:
            self._protocol_paused = False
            self._protocol.resume_writing()

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not self._closing and data:
            self._buffer += data
            self._feed()
            self.pacer.poke()

    def get_write_buffer_size(self) -> int:
        return len(self._buffer)

    def get_write_buffer_limits(self) -> tuple[int, int]:
        return self._low, self._high

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None
                                ) -> None:
        if high is None:
            high = WRITE_BUFFER_HIGH if low is None else 4 * low
        if low is None:
            low = high // 4
        if not high >= low >= 0:
            raise ValueError(f"high ({high!r}) must be >= low ({low!r}) must be >= 0")
        self._high, self._low = high, low
        self._flow()

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._feed(everything=True)
        self._closing = True
        loop = asyncio.get_running_loop()
        self._stopping = loop.create_task(self.pacer.stop())
        loop.call_soon(self._protocol.connection_lost, None)
        if isinstance(self.paced, RobotSide):
            self.paced.release()

    def abort(self) -> None:
        self._buffer.clear()
        self.close()

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        if name == "board":
            return self.paced.board
        if name == FAR_END_LAG_EXTRA:
            return self.paced.behind
        if name == TRUTH_EXTRA and isinstance(self.paced, RobotSide):
            return self.paced.robot.truth_record
        return default


async def open_emulated_transport(
    url: str, baud: int, protocol_factory: Callable[[], asyncio.Protocol]
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    """The ``emu://`` opener ``fpgalink`` finds through the ``fpgalink.transports`` entry
    point: a board built from the URL's options, paced to the wall clock in this process.
    ``emu://robot/L`` and ``emu://robot/R`` (same options) are the two boards of one
    emulated robot. ``ValueError`` for an option the emulator does not understand."""
    if "unplug=" in url:
        raise ValueError("unplug= is a fault of fpgaemu serve's pty or TCP link: a board in "
                         "this process has no port to pull out")
    robot = robot_from_url(url)
    if robot is not None:
        key, side_name, options = robot
        paced: PacedBoard = _shared_robot(key, options, baud).side(side_name)
    else:
        paced = PacedBoard(board_from_url(url, baud), clock=asyncio.get_running_loop().time)
    protocol = protocol_factory()
    transport = EmulatedTransport(paced, protocol)
    protocol.connection_made(transport)
    return transport, protocol


#: In-process robots, by their URL options (without the board), shared by the links to
#: their boards; dropped when the last of those closes.
_ROBOTS: dict[tuple[str, int], PacedRobot] = {}


def _shared_robot(key: str, options: dict[str, list[str]], baud: int) -> PacedRobot:
    paced = _ROBOTS.get((key, baud))
    if paced is None:
        # Paced by the loop's own clock: the wall clock on asyncio's loops, emulated time on
        # a campaign's (fpgalink.aio.virtual_time_loop), where the board runs as fast as it goes.
        paced = _ROBOTS[(key, baud)] = PacedRobot(robot_from_options(options, baud),
                                                  asyncio.get_running_loop().time)

        def forget() -> None:
            _ROBOTS.pop((key, baud), None)

        paced.on_release = forget
    return paced
