"""Serving emulated boards as devices: a pseudo-terminal or a TCP port per board, or an
in-process asyncio transport for ``emu://``, all paced to the wall clock.

A pty does not enforce a baud rate, so the pacing is ours: the board's cycle count follows
real time, host bytes enter ``uartread`` at the cycle they arrived (queuing at line rate
behind earlier ones, as on a wire), and TX bytes are handed out when their stop bit has
ended in emulated time. The serving loop sleeps until the board's next deadline — the next
event that may change something a host could see, or the next TX byte's stop bit — or until
host bytes arrive; an idle board is not woken for timer ticks that change nothing. If the
process is starved of CPU the board falls behind real time; it then catches up in bounded
slices, loses nothing, and the lag (how late a deadline was met) is reported.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fpgaemu.board import Board
from fpgaemu.build import board_from_url
from fpgaemu.robot import EmulatedRobot, robot_from_options, robot_from_url
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol import PARAMETERS

PARAMETERS_BY_ID = {p.id: p for p in PARAMETERS}

__all__ = [
    "TRUTH_EXTRA",
    "EmulatedTransport",
    "LagReport",
    "PacedBoard",
    "PacedRobot",
    "PtyEndpoint",
    "RobotSide",
    "TcpEndpoint",
    "TruthEndpoint",
    "open_emulated_transport",
]

#: Longest slice of emulated time run in one go while catching up, so I/O stays served.
CATCH_UP_SLICE_S = 0.05
#: A deadline met later than this counts as lag.
LAG_THRESHOLD_S = 0.005
#: The longest the serving loop sleeps without a deadline (a safety net, not a tick).
MAX_SLEEP_S = 1.0


#: The USB-UART's buffer toward the board (the CmodA7's FT2232H holds 4 KiB per channel).
#: Bytes a host writes while this much is still waiting for the line are dropped and
#: counted: a real chip would hold the host's write back, but the emulator cannot block its
#: host, and an unbounded queue would apply the host's bytes seconds late.
HOST_FIFO_BYTES = 4096


@dataclass(slots=True)
class LagReport:
    """How far the board fell behind the wall clock: how late its deadlines were met."""

    lag_events: int = 0
    worst_lag_s: float = 0.0
    current_lag_s: float = 0.0
    _lagging: bool = False

    def observe(self, late_s: float) -> None:
        self.current_lag_s = max(0.0, late_s)
        if self.current_lag_s > LAG_THRESHOLD_S:
            if not self._lagging:
                self.lag_events += 1
                self._lagging = True
            self.worst_lag_s = max(self.worst_lag_s, self.current_lag_s)
        else:
            self._lagging = False


@dataclass
class PacedBoard:
    """A board whose emulated time follows a monotonic clock."""

    board: Board
    clock: Callable[[], float] = time.monotonic
    lag: LagReport = field(default_factory=LagReport)

    def __post_init__(self) -> None:
        self._origin = self.clock() - self.board.now / CLOCK_HZ
        self._due: int | None = None  #: the deadline the last wake-up was for
        #: host bytes dropped because the host wrote faster than the line carries them
        self.dropped_rx = 0

    def target_cycle(self, now: float | None = None) -> int:
        now = self.clock() if now is None else now
        return int((now - self._origin) * CLOCK_HZ)

    def host_write(self, data: bytes, now: float | None = None) -> int:
        """Bytes the host wrote at wall time ``now`` enter the RX pin then (or as soon as
        the board has caught up to that moment — never earlier than its present), queued
        behind what the line has not carried yet, up to :data:`HOST_FIFO_BYTES`; beyond it
        they are dropped and counted in :attr:`dropped_rx`. Returns the bytes accepted."""
        if not data:
            return 0
        cycle = max(self.board.now, self.target_cycle(now))
        line = self.board.uartread
        queued = max(0, -(-(line.line_free_at - cycle) // line.cycles_per_byte))
        room = max(0, HOST_FIFO_BYTES - queued)
        if len(data) > room:
            self.dropped_rx += len(data) - room
            data = data[:room]
        if data:
            self.board.host_write(data, cycle)
        return len(data)

    def host_gone(self, now: float | None = None) -> int:
        """The host went away: what it wrote that the line had not begun to carry is
        discarded, as it would be with the cable. Returns how many bytes."""
        return self.board.host_unplugged(max(self.board.now, self.target_cycle(now)))

    def advance(self, now: float | None = None) -> bytes:
        """Run the board up to ``now`` (in slices while catching up) and return the TX bytes
        whose stop bit ended by then."""
        target = self.target_cycle(now)
        if self._due is not None and target >= self._due:
            self.lag.observe((target - self._due) / CLOCK_HZ)
            self._due = None
        step_to = target
        deadline = self.board.next_deadline()
        if deadline is not None and deadline <= target:
            # Work to do on the way: in slices, so I/O is served while catching up. (Up to
            # the next deadline there are only ticks that change nothing: no slicing.)
            step_to = min(target, max(deadline, self.board.now
                                      + int(CATCH_UP_SLICE_S * CLOCK_HZ)))
        if step_to > self.board.now:
            self.board.run_until(step_to)
        return self.board.read_host_bytes()

    def next_wake(self) -> float | None:
        """When :meth:`advance` next has something to do (monotonic seconds): the board's
        next deadline (now, if it is already past: catching up) or the end of the frame now
        on its TX pin; ``None`` when nothing is scheduled at all."""
        return self._wake_at(self.board.next_deadline(), self.board.uartwrite.next_completion)

    def _wake_at(self, *cycles: int | None) -> float | None:
        due = min((c for c in cycles if c is not None), default=None)
        self._due = due
        # One cycle past the deadline: a float round trip must not land a cycle short.
        return None if due is None else self._origin + (due + 1) / CLOCK_HZ


#: ``transport.get_extra_info(TRUTH_EXTRA)`` on an emulated robot's board: a function that
#: returns the body's true state as a JSON-ready dict (fpgalink reads it without importing
#: the emulator).
TRUTH_EXTRA = "fpgaemu.truth"


class PacedRobot:
    """An emulated robot whose boards and body follow the wall clock together: one origin,
    one lag report, every board advanced to the same cycle (:class:`RobotSide` gives each
    board the interface a :class:`PacedBoard` has, for the endpoints)."""

    def __init__(self, robot: EmulatedRobot, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.robot = robot
        self.clock = clock
        self.lag = LagReport()
        self._origin = clock() - robot.now / CLOCK_HZ
        self._due: int | None = None
        self._sides: dict[str, RobotSide] = {}
        self._open: set[str] = set()
        self.on_release: Callable[[], None] | None = None

    def target_cycle(self, now: float | None = None) -> int:
        now = self.clock() if now is None else now
        return int((now - self._origin) * CLOCK_HZ)

    def side(self, name: str) -> RobotSide:
        if name not in self.robot.boards:
            raise ValueError(f"the robot has no board {name!r} (boards: "
                             f"{', '.join(self.robot.boards)})")
        if name in self._open:
            raise ValueError(f"robot board {name} is already open in this process")
        side = self._sides.get(name)
        if side is None:
            side = self._sides[name] = RobotSide(self, name)
        self._open.add(name)
        return side

    def release(self, name: str) -> None:
        self._open.discard(name)
        if not self._open and self.on_release is not None:
            self.on_release()

    def advance(self, now: float | None = None) -> None:
        """Boards and body up to ``now``, in bounded slices while catching up."""
        target = self.target_cycle(now)
        if self._due is not None and target >= self._due:
            self.lag.observe((target - self._due) / CLOCK_HZ)
            self._due = None
        # The body moves with the wheels in 1 ms steps: always sliced.
        step_to = min(target, self.robot.now + int(CATCH_UP_SLICE_S * CLOCK_HZ))
        if step_to > self.robot.now:
            self.robot.run_until(step_to)

    def next_wake(self) -> float | None:
        """:meth:`PacedBoard.next_wake` over every board of the robot (the body moves
        with them and needs no wake-up of its own)."""
        if self.robot.now < self.target_cycle() - int(CATCH_UP_SLICE_S * CLOCK_HZ):
            return self.clock()
        cycles = [c for board in self.robot.boards.values()
                  for c in (board.next_deadline(), board.uartwrite.next_completion)
                  if c is not None]
        self._due = min(cycles, default=None)
        return None if self._due is None else self._origin + (self._due + 1) / CLOCK_HZ

    def truth_record(self) -> dict[str, Any]:
        """The body's true state, and each board as the emulator sees it (for tests and
        tools that check what a host reports against what happened)."""
        return {**self.robot.truth().record(),
                "boards": {name: _board_record(board)
                           for name, board in self.robot.boards.items()}}


def _board_record(board: Board) -> dict[str, Any]:
    """A board's state for the truth stream: the last tick (as its TM stamps it), the
    speeds and encoder counts the firmware sampled then (what that TM carries), the
    PWM applied now (global_enable gates it in logic: 0 from the cycle enable fell), the
    enable, when the last RE arrived and when and why enable last fell, the parameters."""
    firmware: Any = board.peripherals["firmware"]
    enable_cycle = board.uartcommand.last_enable_cycle
    disable = board.uartcommand.last_disable
    return {
        "t_us": (firmware.last_tick // 100) & 0xFFFF_FFFF,
        "speed_a": firmware.channels[1].speed, "speed_b": firmware.channels[2].speed,
        "position_a": firmware.channels[1].position,
        "position_b": firmware.channels[2].position,
        "pwm_a": board.channels[1].pwm.applied_duty,
        "pwm_b": board.channels[2].pwm.applied_duty,
        "enabled": board.global_enable,
        "now_s": board.now / CLOCK_HZ,
        "last_re_s": None if enable_cycle is None else enable_cycle / CLOCK_HZ,
        "disabled_s": None if disable is None else disable[0] / CLOCK_HZ,
        "disabled_by": None if disable is None else disable[1].value,
        "params": {PARAMETERS_BY_ID[pid].full_name(ch): value
                   for (pid, ch), value in firmware.values.items()},
    }


class RobotSide(PacedBoard):
    """One board of a :class:`PacedRobot`, as the endpoints see a paced board."""

    def __init__(self, robot: PacedRobot, name: str) -> None:
        super().__init__(robot.robot.boards[name], robot.clock, robot.lag)
        self.robot = robot
        self.name = name

    def target_cycle(self, now: float | None = None) -> int:
        return self.robot.target_cycle(now)

    def advance(self, now: float | None = None) -> bytes:
        self.robot.advance(now)
        return self.board.read_host_bytes()

    def next_wake(self) -> float | None:
        return self.robot.next_wake()

    def release(self) -> None:
        self.robot.release(self.name)


class _Pacer:
    """Runs ``tick()`` (advance the board, hand out its bytes) whenever the board has a
    deadline, and when :meth:`poke` says host bytes arrived — never on a fixed beat."""

    def __init__(self, tick: Callable[[], None], next_wake: Callable[[], float | None]
                 ) -> None:
        self._tick = tick
        self._next_wake = next_wake
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.wakeups = 0

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._wake()

    def poke(self) -> None:
        """Something changed (host bytes arrived): the next deadline may be sooner."""
        if self._loop is not None:
            self._arm()

    def _wake(self) -> None:
        self._timer = None
        self.wakeups += 1
        self._tick()
        self._arm()

    def _arm(self) -> None:
        loop = self._loop
        assert loop is not None
        at = self._next_wake()
        now = loop.time()
        at = now + MAX_SLEEP_S if at is None else min(at, now + MAX_SLEEP_S)
        if self._timer is not None:
            if self._timer.when() <= at:
                return
            self._timer.cancel()
        self._timer = loop.call_at(at, self._wake)

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop = None


# --- pty --------------------------------------------------------------------------------------


#: How long a connection that arrives while another host is served waits for that host to
#: turn out to have left already, before it is turned away.
BUSY_GRACE_S = 0.2

#: TX bytes a pty keeps for a host that is not reading (a busy or starved process), in
#: seconds of line time; beyond it the oldest are dropped and counted, as a USB-UART's
#: buffer overflows. The kernel's own pty buffer holds only about 40 ms at 1 MBd.
TX_BACKLOG_S = 1.0


class PtyEndpoint:
    """One board behind a pseudo-terminal. We keep the slave side open ourselves, so a host
    that closes and reopens the path finds the same board still running."""

    def __init__(self, paced: PacedBoard) -> None:
        self.paced = paced
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.pacer = _Pacer(self._tick, paced.next_wake)
        self._pending_out = bytearray()
        self._writing = False
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        #: TX bytes lost because nobody read the pty for longer than the backlog holds
        self.dropped_tx = 0

    def start(self) -> None:
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        self.pacer.start()

    def _readable(self) -> None:
        try:
            data = os.read(self._master, 65536)
        except BlockingIOError:
            return
        except OSError:
            return  # no reader on the slave side right now; the board keeps running
        self.paced.host_write(data)
        self.pacer.poke()

    def _tick(self) -> None:
        out = self.paced.advance()
        if out:
            self._pending_out += out
        self._flush()

    def _flush(self) -> None:
        if self._pending_out:
            try:
                written = os.write(self._master, self._pending_out)
                del self._pending_out[:written]
            except OSError:
                pass  # the pty is full (nobody reading just now): keep the bytes for later
            excess = len(self._pending_out) - self._backlog
            if excess > 0:
                # Nobody read for longer than the backlog: the oldest bytes are gone, counted
                # rather than blocking the board.
                del self._pending_out[:excess]
                self.dropped_tx += excess
        # Bytes left over go out when the pty has room, not on the next deadline.
        loop = asyncio.get_running_loop()
        if self._pending_out and not self._writing:
            loop.add_writer(self._master, self._flush)
            self._writing = True
        elif not self._pending_out and self._writing:
            loop.remove_writer(self._master)
            self._writing = False

    async def close(self) -> None:
        await self.pacer.stop()
        if self._writing:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_writer(self._master)
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


# --- TCP --------------------------------------------------------------------------------------


class TcpEndpoint:
    """One board on a TCP port, one host at a time, as a serial port has one owner: while a
    host is connected the port does not listen (a second host is refused: "connection
    refused"), and it listens again when that host leaves. What a departed host wrote that
    the line had not begun to carry is discarded. TX bytes a host does not read pile up to
    the same backlog a pty keeps, then the oldest are dropped and counted."""

    def __init__(self, paced: PacedBoard, host: str, port: int) -> None:
        self.paced = paced
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.pacer = _Pacer(self._tick, paced.next_wake)
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        self._closing = False
        self._free = asyncio.Event()
        self.connections = 0
        #: TX bytes lost because the host did not read them for longer than the backlog holds
        self.dropped_tx = 0

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"socket://{host}:{self.port}"

    async def start(self) -> None:
        await self._listen()
        self.pacer.start()

    async def _listen(self) -> None:
        # A backlog of one: while a host is served the port stops listening, and the kernel
        # should queue as few others as possible meanwhile (those it did are closed at once).
        self._server = await asyncio.start_server(self._client, self.host, self.port,
                                                  reuse_address=True, backlog=1)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:
            # Accepted by the kernel before the port stopped listening. Most often the host
            # being served has just left and serve has not seen it yet: give that a moment,
            # else this is a second host, and it is turned away.
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._free.wait(), BUSY_GRACE_S)
            if self._writer is not None:
                writer.close()
                return
        self._writer = writer
        self._free.clear()
        self.connections += 1
        if self._server is not None:
            self._server.close()  # busy: refuse others until this host leaves
            self._server = None
        try:
            while data := await reader.read(65536):
                self.paced.host_write(data)
                self.pacer.poke()
        except (ConnectionError, OSError, asyncio.CancelledError):
            pass
        finally:
            self.paced.host_gone()
            self._writer = None
            self._free.set()
            writer.close()
            if not self._closing:
                with contextlib.suppress(OSError):
                    await self._listen()

    def _tick(self) -> None:
        out = self.paced.advance()
        writer = self._writer
        if out and writer is not None and not writer.is_closing():
            if writer.transport.get_write_buffer_size() + len(out) > self._backlog:
                self.dropped_tx += len(out)  # the host is not reading: like a wire, gone
                return
            writer.write(out)

    async def close(self) -> None:
        self._closing = True
        await self.pacer.stop()
        if self._writer is not None:
            self._writer.close()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()


# --- the robot's truth -------------------------------------------------------------------------

#: How often the truth endpoint sends the body's state (50 Hz: a path plot's resolution).
TRUTH_PERIOD_S = 0.02


class TruthEndpoint:
    """The emulated body's true state for any number of readers on a TCP port: one JSON
    object per line every :data:`TRUTH_PERIOD_S` (``t x y theta v omega distance surface``;
    metres, radians, seconds of emulated time; ``boards``: each board's state, see
    :func:`_board_record`; ``host_time``: the host's epoch time the boards were advanced to,
    so board time maps onto the host clock). Read-only; what a reader sends is ignored."""

    def __init__(self, robot: PacedRobot, host: str, port: int) -> None:
        self.robot = robot
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.Task[None]] = set()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"socket://{host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, self.host, self.port,
                                                  reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients.add(task)
        try:
            while not writer.is_closing():
                self.robot.advance()
                record = self.robot.truth_record()
                record["host_time"] = time.time()  # the boards caught up with this instant
                line = json.dumps(record, separators=(",", ":"))
                writer.write(line.encode() + b"\n")
                if writer.transport.get_write_buffer_size() > 1 << 20:
                    break  # a reader that does not read is let go
                await asyncio.sleep(TRUTH_PERIOD_S)
        except (ConnectionError, OSError, asyncio.CancelledError):
            pass
        finally:
            self._clients.discard(task)
            writer.close()

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
        for task in list(self._clients):
            task.cancel()
        await asyncio.gather(*self._clients, return_exceptions=True)


# --- emu:// in-process ------------------------------------------------------------------------


class EmulatedTransport(asyncio.Transport):
    """An asyncio transport whose far end is a board in this process."""

    def __init__(self, paced: PacedBoard, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.paced = paced
        self._protocol = protocol
        self._closing = False
        self.pacer = _Pacer(self._tick, paced.next_wake)
        self.pacer.start()

    def _tick(self) -> None:
        out = self.paced.advance()
        if out and not self._closing:
            self._protocol.data_received(out)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not self._closing:
            self.paced.host_write(bytes(data))
            self.pacer.poke()

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        loop = asyncio.get_running_loop()
        self._stopping = loop.create_task(self.pacer.stop())
        loop.call_soon(self._protocol.connection_lost, None)
        if isinstance(self.paced, RobotSide):
            self.paced.release()

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        if name == "board":
            return self.paced.board
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
    robot = robot_from_url(url)
    if robot is not None:
        key, side_name, options = robot
        paced: PacedBoard = _shared_robot(key, options, baud).side(side_name)
    else:
        paced = PacedBoard(board_from_url(url, baud))
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
        paced = _ROBOTS[(key, baud)] = PacedRobot(robot_from_options(options, baud))

        def forget() -> None:
            _ROBOTS.pop((key, baud), None)

        paced.on_release = forget
    return paced
