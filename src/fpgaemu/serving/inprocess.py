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

__all__ = ["FAR_END_LAG_EXTRA", "HOST_DUE_EXTRA", "TRUTH_EXTRA", "WRITE_BUFFER_HIGH",
           "EmulatedTransport", "FarEnd", "open_emulated_transport"]

#: ``transport.get_extra_info(FAR_END_LAG_EXTRA)`` on an in-process emulated board: a
#: function giving how far, in seconds, the board's time trails the host's clock at the
#: loop time it is given (:meth:`PacedBoard.behind`). fpgalink's link keeps its time that
#: much behind, so a host process starved together with its board does not take the
#: board's unmade samples for a board that stopped (the name is fpgalink's, which never
#: imports the emulator).
FAR_END_LAG_EXTRA = "fpgalink.far_end_lag"

#: ``transport.get_extra_info(HOST_DUE_EXTRA)`` on an in-process emulated board: a function
#: the host calls once with its own ``due()`` (when its next timer falls, on the board's
#: time, or ``None``). The board is not run past a deadline of its host that has come and
#: not been met (:mod:`fpgaemu.serving.hosts`), so host and board catch up together after
#: the process was not scheduled.
HOST_DUE_EXTRA = "fpgalink.host_due"

#: ``transport.get_extra_info(TRUTH_EXTRA)`` on an emulated robot's board: a function that
#: returns the body's true state as a JSON-ready dict (fpgalink reads it without importing
#: the emulator).
TRUTH_EXTRA = "fpgaemu.truth"


#: asyncio's own defaults for a transport's write buffer: the protocol is asked to pause
#: writing above the high mark and to resume at the low one.
WRITE_BUFFER_HIGH = 64 * 1024


class FarEnd:
    """What is at the far end of one or more in-process transports: a board, or a robot
    whose boards each have a transport. One :class:`~fpgaemu.serving.loop.Pacer` for all of
    them, so a robot wakes once per due deadline, not once per transport: each wake-up runs
    the far end up to the present (``run``), then hands every transport what its board sent.
    A transport whose reading is paused (batched reads) asks for no wake-up of its own: a
    far end all of whose transports are paused is left until one reads or writes again, and
    runs up to the present then (what it sent in between waits on its TX line, as in a
    port's buffer)."""

    def __init__(self, run: Callable[[], None],
                 wake: Callable[[list[PacedBoard]], float | None]) -> None:
        self._run = run
        self._wake = wake  #: when to run next, for the boards whose transports read now
        self.transports: list[EmulatedTransport] = []
        self.pacer = Pacer(self._tick, self._next_wake)

    def join(self, transport: EmulatedTransport) -> None:
        self.transports.append(transport)
        if len(self.transports) == 1:
            self.pacer.start()
        else:
            self.pacer.poke()

    def leave(self, transport: EmulatedTransport) -> None:
        self.transports.remove(transport)
        if not self.transports:
            asyncio.get_running_loop().create_task(self.pacer.stop())

    def _tick(self) -> None:
        self._run()
        for transport in list(self.transports):
            transport.hand_out()

    def _next_wake(self) -> float | None:
        reading = [t.paced for t in self.transports if t.is_reading()]
        wakes = [w for t in self.transports if (w := t.feed_wake()) is not None]
        if reading and (run := self._wake(reading)) is not None:
            wakes.append(run)
        return min(wakes, default=None)


class EmulatedTransport(asyncio.Transport):
    """An asyncio transport whose far end is a board in this process. What the host writes
    is never dropped: it waits in the transport's buffer and goes onto the RX line as the
    line makes room, as a serial transport's buffer drains into its port; the protocol's
    ``pause_writing()``/``resume_writing()`` are called at the buffer's limits, as asyncio's
    own transports do (:meth:`set_write_buffer_limits`, :meth:`get_write_buffer_size`).
    ``pause_reading()``/``resume_reading()`` hold what the board sends back, as a paused
    port's buffer does, and hand it over, all at once, on resuming: a host that reads in
    batches (fpgalink's ``Link.set_read_latency``) is woken once per batch."""

    def __init__(self, paced: PacedBoard, protocol: asyncio.Protocol, far_end: FarEnd) -> None:
        super().__init__()
        self.paced = paced
        self._protocol = protocol
        self._far_end = far_end
        self._closing = False
        self._reading = True
        self._buffer = bytearray()  #: written by the host, not yet on the RX line
        self._high = WRITE_BUFFER_HIGH
        self._low = WRITE_BUFFER_HIGH // 4
        self._protocol_paused = False
        far_end.join(self)

    @property
    def pacer(self) -> Pacer:
        """The pacer of this transport's far end (shared by a robot's boards' transports)."""
        return self._far_end.pacer

    def feed_wake(self) -> float | None:
        """When the host's buffered bytes can go on (the line has room again), if any wait."""
        return self.paced.rx_resume_at() if self._buffer else None

    def hand_out(self) -> None:
        """After the far end ran: what its board sent, to the protocol (unless reading is
        paused), and the host's buffered bytes onto the line as it has room."""
        self._feed()
        if self._reading and not self._closing:
            out = self.paced.take_bytes()
            if out:
                self._protocol.data_received(out)

    def pause_reading(self) -> None:
        self._reading = False

    def resume_reading(self) -> None:
        if not self._reading and not self._closing:
            self._reading = True
            self.pacer.poke()

    def is_reading(self) -> bool:
        return self._reading and not self._closing

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
        self.paced.hosts.forget(self)
        self._far_end.leave(self)
        asyncio.get_running_loop().call_soon(self._protocol.connection_lost, None)
        if isinstance(self.paced, RobotSide):
            self.paced.release()

    def abort(self) -> None:
        self._buffer.clear()
        self.close()

    def _follow_host(self, due: Callable[[], float | None]) -> None:
        if not self._closing:
            self.paced.hosts.follow(self, due)

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        if name == "board":
            return self.paced.board
        if name == FAR_END_LAG_EXTRA:
            return self.paced.behind
        if name == HOST_DUE_EXTRA:
            return self._follow_host
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
        shared, far_end = _shared_robot(key, options, baud)
        paced: PacedBoard = shared.side(side_name)
    else:
        paced = PacedBoard(board_from_url(url, baud), clock=asyncio.get_running_loop().time)
        far_end = FarEnd(paced.run, lambda _reading: paced.next_wake())
    protocol = protocol_factory()
    transport = EmulatedTransport(paced, protocol, far_end)
    protocol.connection_made(transport)
    return transport, protocol


#: In-process robots, by their URL options (without the board), shared by the links to
#: their boards, with the far end their transports share; dropped when the last closes.
_ROBOTS: dict[tuple[str, int], tuple[PacedRobot, FarEnd]] = {}


def _shared_robot(key: str, options: dict[str, list[str]], baud: int
                  ) -> tuple[PacedRobot, FarEnd]:
    shared = _ROBOTS.get((key, baud))
    if shared is None:
        # Paced by the loop's own clock: the wall clock on asyncio's loops, emulated time on
        # a campaign's (fpgalink.aio.virtual_time_loop), where the board runs as fast as it goes.
        paced = PacedRobot(robot_from_options(options, baud), asyncio.get_running_loop().time)
        shared = _ROBOTS[(key, baud)] = (paced, FarEnd(
            paced.advance, lambda reading: paced.next_wake(side.board for side in reading)))

        def forget() -> None:
            _ROBOTS.pop((key, baud), None)

        paced.on_release = forget
    return shared
