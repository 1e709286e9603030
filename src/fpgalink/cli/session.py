"""The streaming session shared by ``monitor``, ``record`` and ``step``: running a command's
coroutine, stopping cleanly on a signal, opening every board, switching telemetry on and
back, the board clock, and telemetry as flat rows (one schema for CSV, JSON lines, MCAP)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import signal
import sys
import time
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass, field
from typing import Any, TypeVar

from fpgalink.aio.link import Link, LinkState
from fpgalink.boardclock import BoardClock
from fpgalink.cli.options import ConnectionOptions, Endpoint
from fpgalink.cli.output import (
    CliError,
    ExitCode,
    classify,
    note,
    stdout_errors,
    wire_crc_advice,
)
from fpgalink.errors import FpgalinkError
from fpgalink.events import (
    BoardFound,
    BoardRestarted,
    BoardSilent,
    PortLost,
    PortRestored,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import (
    ChannelTelemetry,
    CountedMessage,
    DirectCommand,
    Event,
    Malformed,
    Message,
    Parsed,
)

# Telemetry as rows lives below the CLI, beside the MCAP writer (campaigns write them too).
from fpgalink.recording import (
    CHANNEL_FIELDS,
    TELEMETRY_FIELDS,
    compact,
    json_safe,
    telemetry_row,
    telemetry_schema,
)

__all__ = [
    "CHANNEL_FIELDS",
    "TELEMETRY_FIELDS",
    "BoardSession",
    "Streaming",
    "check_boards_answered",
    "compact",
    "gather_all",
    "install_stop_signals",
    "json_safe",
    "on_messages",
    "open_sessions",
    "restore_streaming",
    "run",
    "start_streaming",
    "stop_exit_code",
    "telemetry_row",
    "telemetry_schema",
    "wait_or_stop",
    "write_stdout",
]

T = TypeVar("T")


# --- running ----------------------------------------------------------------------------------


def run(coro: Coroutine[Any, Any, T], where: str = "") -> T:
    """Run one command's coroutine; library errors become :class:`CliError`."""
    try:
        return asyncio.run(coro)
    except FpgalinkError as exc:
        raise classify(exc, where) from None


def install_stop_signals(stop: asyncio.Event) -> list[signal.Signals]:
    """SIGINT/SIGTERM set ``stop`` so a long command can close its files and say goodbye;
    returns the signals that were hooked (and will report which one fired via ``stop``)."""
    loop = asyncio.get_running_loop()
    hooked: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, functools.partial(_on_signal, stop, sig))
            hooked.append(sig)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - not on Unix
            pass
    return hooked


def _on_signal(stop: asyncio.Event, sig: signal.Signals) -> None:
    stop.signal = sig  # type: ignore[attr-defined]
    stop.set()


def stop_exit_code(stop: asyncio.Event) -> int:
    sig = getattr(stop, "signal", None)
    return 0 if sig is None else 128 + int(sig)


async def wait_or_stop(stop: asyncio.Event, timeout: float | None) -> None:
    """Wait for ``stop`` or ``timeout`` seconds, whichever first (``None``: only ``stop``)."""
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), timeout)


async def gather_all(*aws: Awaitable[T]) -> list[T]:
    """``asyncio.gather`` that cancels the siblings when one fails."""
    tasks = [asyncio.ensure_future(a) for a in aws]
    try:
        return list(await asyncio.gather(*tasks))
    except BaseException:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        raise


_RECEIVED = Message | CountedMessage | DirectCommand | Malformed


def on_messages(link: Link | Callable[[Callable[[Event], None]], Callable[[], None]],
                callback: Callable[[Parsed], None]) -> Callable[[], None]:
    """Call ``callback`` with every message ``link`` receives (``PA`` echoes, unknown IDs,
    ``E`` … not only telemetry); returns the function that stops it. ``link`` may also be
    an ``add_listener`` of its own (a robot's board: ``functools.partial(robot.boards.
    add_listener, name)``)."""

    def listener(event: Event) -> None:
        if isinstance(event, _RECEIVED):
            callback(event)

    add_listener = link if callable(link) else link.add_listener
    return add_listener(listener)


def write_stdout(text: str) -> None:
    """Write to stdout, unflushed (a stream of rows), under
    :func:`~fpgalink.cli.output.stdout_errors`."""
    with stdout_errors():
        sys.stdout.write(text)


def flag_letters(channel: ChannelTelemetry) -> str:
    return "".join(letter if on else "-" for letter, on in
                   (("E", channel.enabled), ("S", channel.end_stop), ("X", channel.saturated)))


@dataclass
class Streaming:
    """Turns ``GetDataPeriodical`` on for the duration of a command and restores what was
    there before, so watching a board leaves it as it was found."""

    link: Link
    previous: int | float | None = None
    changed: bool = field(default=False)

    async def start(self) -> None:
        self.previous = await self.link.get_param("GetDataPeriodical")
        if self.previous != 1:
            await self.link.set_param("GetDataPeriodical", 1)
            self.changed = True

    async def restore(self) -> None:
        if self.changed and self.previous is not None and self.link.board_alive:
            # Best effort: the board may be gone, and we are on our way out anyway.
            with contextlib.suppress(FpgalinkError):
                await self.link.set_param("GetDataPeriodical", self.previous)


# --- several boards ---------------------------------------------------------------------------


@dataclass
class BoardSession:
    """One board being watched: its link, streaming switch, clock and rate estimate."""

    endpoint: Endpoint
    link: Link
    streaming: Streaming
    clock: BoardClock = field(default_factory=BoardClock)
    rate: float = 0.0
    _rate_mark: tuple[float, int] | None = None
    #: when (host epoch) the board went silent or its port vanished, while it is so
    lost_at: float | None = None
    #: (lost at, back at or None) for every time it was lost during the command
    episodes: list[tuple[float, float | None]] = field(default_factory=list)
    #: (when, what) for each of the board's faults during the command: restarts, watchdog
    #: lapses, telemetry stopping
    faults: list[tuple[float, str]] = field(default_factory=list)

    async def follow(self, report: Callable[[str, str, float], None] | None = None) -> None:
        """Keep :attr:`lost_at` and :attr:`episodes` true to the link's events, and hand
        each event to ``report(kind, detail, epoch time)``."""
        async for event in self.link.watch():
            at = time.time()
            if isinstance(event, BoardSilent | PortLost):
                if self.lost_at is None:
                    self.lost_at = at
                    self.episodes.append((at, None))
            elif (isinstance(event, BoardFound | PortRestored)
                  and self.lost_at is not None and self.link.board_alive):
                self.episodes[-1] = (self.lost_at, at)
                self.lost_at = None
            elif isinstance(event, FAULTS):
                self.faults.append((at, event.describe()))
            if report is not None:
                report(event.name, event.describe(), at)

    def update_rate(self, now: float) -> None:
        received = self.link.stats.telemetry_received
        if self._rate_mark is not None:
            then, count = self._rate_mark
            if now - then >= 0.5:
                self.rate = (received - count) / (now - then)
                self._rate_mark = (now, received)
        else:
            self._rate_mark = (now, received)

    @property
    def status(self) -> str:
        if self.link.state is LinkState.RECONNECTING:
            return "port lost, reconnecting"
        if self.link.board_alive:
            return "alive"
        return "waiting" if self.link.stats.messages_received == 0 else "SILENT"


async def open_sessions(stack: contextlib.AsyncExitStack, conn: ConnectionOptions, *,
                        passive: bool = False) -> list[BoardSession]:
    """Open every board's link (closed by ``stack``). Long-running commands keep reconnecting
    after a lost port and use the library's liveness timeout, so their view shows the truth.
    Each board is asked who it is as it opens, unless ``passive``: then its link sends
    nothing at all (``Settings.listen_only``), as ``--passive`` promises."""
    sessions = []
    for endpoint in conn.endpoints:
        link = conn.link(endpoint, reconnect=True, liveness_timeout=0.7, identify=not passive,
                         listen_only=passive)
        await stack.enter_async_context(link)
        sessions.append(BoardSession(endpoint, link, Streaming(link)))
    return sessions


#: The status events that are a board's faults (its restarts, watchdog lapses, telemetry
#: stopping): said on stderr, never passed over.
FAULTS = (BoardRestarted, WatchdogLapsed, TelemetryStale)


def check_boards_answered(sessions: list[BoardSession], started: float) -> None:
    """A board lost and back during the command, or one that restarted, disabled itself or
    whose telemetry stopped, is told on stderr; a board not answering at the end ends the
    command with "board not answering" (exit 4), saying since when. A board whose frames
    came in the other wire-CRC mode is told how to connect, and ends the command (exit 4)
    when nothing usable came from it."""
    unusable: list[str] = []
    for session in sessions:
        link = session.link
        if link.stats.crc_mode_mismatches:
            advice = wire_crc_advice(board_crc=not link.connection.wire_crc.on)
            if link.stats.telemetry_received == 0:
                unusable.append(f"board {session.endpoint.name}: {advice}")
            else:
                note(f"board {session.endpoint.name}: {advice}")
        for at, what in session.faults:
            note(f"board {session.endpoint.name} {what} at {_clock(at)} "
                 f"({at - started:.1f} s into the run)")
        for lost, back in session.episodes:
            if back is not None:
                note(f"board {session.endpoint.name} was not answering from "
                     f"{_clock(lost)} to {_clock(back)} ({back - lost:.1f} s; "
                     f"{lost - started:.1f} s into the run)")
    if unusable:
        raise CliError("; ".join(unusable), ExitCode.NO_ANSWER)
    gone = [s for s in sessions if s.lost_at is not None]
    if gone:
        first = gone[0]
        assert first.lost_at is not None
        names = ", ".join(s.endpoint.name for s in gone)
        raise CliError(f"board not answering: {names} since {_clock(first.lost_at)} "
                       f"({first.lost_at - started:.1f} s into the run)", ExitCode.NO_ANSWER)


def _clock(epoch: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(epoch)) + f".{int(epoch % 1 * 10)}"


async def start_streaming(sessions: list[BoardSession], passive: bool) -> None:
    if passive:
        return
    for session in sessions:
        await session.streaming.start()


async def restore_streaming(sessions: list[BoardSession], passive: bool) -> None:
    if passive:
        return
    for session in sessions:
        await session.streaming.restore()
