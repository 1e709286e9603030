"""The sans-I/O link: bytes in, events out; requests in, bytes out; time passed in.

Modelled on h11 and aioquic. Nothing here reads a clock, opens a port or imports asyncio;
the caller passes ``now`` (seconds, any monotonic origin) wherever time matters and drives

* ``receive_data(data, now)``, then ``next_event()`` until it returns ``None``;
* ``send(message, now)``, ``enable(now)``, ``set_param(…, now)`` …, then ``data_to_send()``:
  the one way out for bytes, whoever produced them (the caller's messages, heartbeats,
  resends);
* ``get_timer()`` → when to call ``handle_timer(now)`` next;
* ``port_lost(now, reason)`` and ``reconnected(now)`` when the transport goes and comes back.

:class:`Connection` keeps the API and the one event queue, in stream order, and hands the
work to one module per concern: :mod:`.frames` (bytes ↔ frames, the wire CRC),
:mod:`.requests` (parameter requests and every retry), :mod:`.liveness` (heartbeat,
silence, stale telemetry, watchdog lapses) and :mod:`.restart` (restarts and the resync).

The board's real life is reported, never silent, and the connection never drives on
blind: a restart (:class:`~fpgalink.events.BoardRestarted`) or a watchdog lapse
(:class:`~fpgalink.events.WatchdogLapsed`) stops its heartbeat (``RD``: the caller enables
again when it is safe), and after a restart every parameter this side had set is set
again (:class:`~fpgalink.events.BoardResynced`); telemetry configured on that stops coming
is :class:`~fpgalink.events.TelemetryStale`. ``docs/robot.md`` (Faults) has the table.

Bad input from the board never raises: it is an :class:`~fpgalink.protocol.Event`
(:class:`~fpgalink.protocol.Malformed`, :class:`~fpgalink.protocol.NoiseDropped`,
:class:`~fpgalink.events.CounterGap` …) and a counter in :attr:`Connection.stats`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any, Unpack

from fpgalink.connection.counting import Counting, from_router
from fpgalink.connection.frames import FrameLayer, telemetry_runs
from fpgalink.connection.identity import KnownIdentity
from fpgalink.connection.liveness import Hearing, Heartbeat, Liveness, TelemetryWatch
from fpgalink.connection.pacing import LinePacing
from fpgalink.connection.queue import EventQueue
from fpgalink.connection.requests import Outcome, Request, Requests
from fpgalink.connection.restart import Continuity
from fpgalink.connection.settings import Options, Settings
from fpgalink.connection.stats import LinkStats
from fpgalink.errors import BoardLost, LinkClosed, LocalProtocolError
from fpgalink.events import (
    BoardFound,
    BoardSilent,
    Closed,
    PortLost,
    PortRestored,
    RequestDone,
    RequestFailed,
    RestartEvidence,
)
from fpgalink.protocol import (
    FLOAT32_MAX,
    MESSAGE_TYPES,
    TELEMETRY_RUN_MIN,
    Alive,
    CountedMessage,
    CounterTracker,
    DirectCommand,
    Disable,
    Enable,
    Event,
    FramingError,
    Malformed,
    Message,
    Param,
    ParamAck,
    ParamNack,
    References,
    Role,
    Telemetry,
    parse_content,
    parse_telemetry_run,
)
from fpgalink.protocol.crc import HostWireCrc

__all__ = ["Connection"]


def _sendable(role: Role) -> frozenset[type]:
    """The message types ``role`` sends, by their wire IDs: every catalogued one whose ID
    says this side sends it (a generic counted message is anyone's)."""
    direct = (Enable(), Disable(), Alive())
    return frozenset({*(cls for cls in MESSAGE_TYPES if cls.msg_id.sender is role),
                      *(type(cmd) for cmd in direct if cmd.msg_id.sender is role),
                      CountedMessage})


_SENDABLE = {role: _sendable(role) for role in Role}
#: Bytes decoded between two checks of the event cap, so one huge read cannot fill memory.
_RECEIVE_SLICE = 1 << 16


class Connection:
    """One link to one board (or, with ``role=Role.BOARD``, the board's side of it).
    Settings (:class:`~fpgalink.connection.Settings`) are given whole (``settings=``) or as
    keywords (``Connection(baud=None, request_tries=3)``); references are paced (:mod:`.pacing`)."""

    def __init__(self, role: Role = Role.HOST, settings: Settings | None = None,
                 **options: Unpack[Options]) -> None:
        settings = Settings(**options) if settings is None else replace(settings, **options)
        self.role = role
        self.stats = LinkStats()
        self._events = EventQueue(self.stats)
        self._counting = Counting(self.stats, self._events.append)
        self.latest_telemetry: Telemetry | None = None
        self._sendable = _SENDABLE[role]
        self._outbox: list[bytes] = []
        self._port_up = True
        self._line = LinePacing(settings, self.stats)
        emit = self._events.append
        self._frames = FrameLayer(settings.framing, self.stats, emit, settings.wire_crc)
        self._heartbeat = Heartbeat(settings, self.stats, send=self._queue, emit=emit,
                                    port_up=lambda: self._port_up)
        self._hearing = Hearing(settings)
        self._stream = TelemetryWatch(settings, self.stats, emit)
        self._requests = Requests(settings, self.stats, send=self._queue, emit=emit,
                                  heard=lambda: self.liveness is Liveness.ALIVE,
                                  crc_mismatch=lambda: self._frames.mismatch,
                                  settled=self._settled)
        self._continuity = Continuity(self._requests, self.stats, emit=emit,
                                      restart=self._restarted)
        self._settings = settings
        self.identity = KnownIdentity(emit)  #: who the board said it is (its part)

    @property
    def settings(self) -> Settings:
        return self._settings

    @settings.setter
    def settings(self, settings: Settings) -> None:
        """New settings for the running connection (its framing stays)."""
        if settings.framing != self._settings.framing:
            raise ValueError("a connection's framing is fixed when it is made")
        self._settings = settings
        for part in (self._heartbeat, self._hearing, self._stream, self._requests, self._line):
            part.settings = settings

    @property
    def counter_tracker(self) -> CounterTracker:
        """The board's message counter as followed: gaps, duplicates, late arrivals."""
        return self._counting.tracker

    @property
    def baud(self) -> int | None:
        """The line's bit rate (``None``: not known, no pacing)."""
        return self._settings.baud

    # --- receiving ------------------------------------------------------------------------

    def receive_data(self, data: bytes | bytearray | memoryview, now: float) -> None:
        """Feed bytes from the wire that arrived at ``now``."""
        self.stats.bytes_received += len(data)
        if len(data) <= _RECEIVE_SLICE:
            self._receive(data, now)
            return
        view = memoryview(data)
        for start in range(0, len(view), _RECEIVE_SLICE):
            self._receive(view[start : start + _RECEIVE_SLICE], now)

    def _receive(self, data: bytes | bytearray | memoryview, now: float) -> None:
        items, all_frames = self._frames.feed(data, now)
        if items:
            if len(items) < TELEMETRY_RUN_MIN:
                self._each(items, now)
            # Every item a frame and every frame a TM: the 1 kHz case, a chunk at a time;
            # else runs long enough to gain a run at a time, the rest one by one, in order.
            elif not all_frames or not self._telemetry(items, now):
                for maybe, part in telemetry_runs(items):
                    if not (maybe and self._telemetry(part, now)):
                        self._each(part, now)
        self._events.trim(self._settings.max_events)
        if self.liveness is Liveness.ALIVE:
            self._hearing.heard(now)
            self._continuity.go_on(now)

    def _telemetry(self, frames: list[Any], now: float) -> bool:
        """Take ``frames`` as TM events if every one is a well-formed TM (what
        ``parse_content`` would make of each); otherwise leave them and return False."""
        telemetry = parse_telemetry_run(frames)
        if telemetry is None:
            return False
        n = len(telemetry)
        counters: list[int] = [tm.counter for tm in telemetry]  # type: ignore[misc]
        if self.liveness is not Liveness.ALIVE:
            self._found(now)  # the board is known to be there before the message that shows it
        first = counters[0]
        if (counters == list(range(first, first + n)) and not self._continuity.doubting
                and self._counting.tracker.observe_in_order(first, n)):
            self._continuity.went_on(now)
            self._heartbeat.watch(telemetry, now)
            self._events.extend(telemetry)
            self._stream.arrived(telemetry[0], telemetry[-1], now)
        else:
            for msg in telemetry:
                self._one_telemetry(msg, now)
        stats = self.stats
        stats.frames_received += n
        stats.messages_received += n
        stats.telemetry_received += n
        self.latest_telemetry = telemetry[-1]
        return True

    def _one_telemetry(self, msg: Telemetry, now: float) -> None:
        """A TM off the in-order fast path: its counter and clock judged, in stream order."""
        counter = msg.counter
        assert counter is not None
        tracker, continuity = self._counting.tracker, self._continuity
        in_order = tracker.observe_in_order(counter)
        if not in_order:
            verdict = continuity.judge_clock(msg.t_us, self._stream.last_t_us, now)
        else:
            verdict = continuity.judge_doubt(msg.t_us, now) if continuity.doubting else None
        if verdict is not None:
            evidence, detail = verdict
            self._restarted(evidence, f"{detail}, counter {counter:05d} where "
                            f"{tracker.expected:05d} was expected", now)
            tracker.observe(counter)
        elif in_order:
            continuity.went_on(now)
        else:
            self._count_out_of_order(counter, now)
        self._heartbeat.watch((msg,), now)
        self._events.append(msg)
        self._stream.arrived(msg, msg, now)

    def _count(self, counter: int, now: float) -> None:
        if not self._counting.tracker.observe_in_order(counter):
            self._count_out_of_order(counter, now)
        else:
            self._continuity.went_on(now)

    def _count_out_of_order(self, counter: int, now: float) -> None:
        observation, restart = self._counting.judge(counter)
        if restart is not None:
            self._restarted(RestartEvidence.COUNTER_RESET, restart, now)
            self._counting.tracker.observe(counter)
            return
        self._continuity.went_on(now)
        self._counting.say(observation, counter)

    def _each(self, items: list[bytes | FramingError], now: float) -> None:
        """Items one at a time: framing errors, and frames through ``parse_content``."""
        stats = self.stats
        append = self._events.append
        frames = telemetry = counted = 0
        latest: Telemetry | None = None
        found = self.liveness is Liveness.ALIVE
        for item in items:
            if type(item) is not bytes:
                assert isinstance(item, FramingError)
                stats.count_framing_error(item)
                append(item)
                continue
            frames += 1
            msg = parse_content(item)
            if isinstance(msg, Malformed):
                if self._frames.unexpected(item, now):
                    continue  # the other wire-CRC mode's: counted and said, never a message
                stats.count_malformed(msg)
                append(msg)
                continue
            # fpgalink-cli router's own PN 5 settles its request; it is no word of the board's
            board_said = not from_router(msg)
            if not found and board_said:
                self._found(now)  # the board is known to be there before the message
                found = True
            if type(msg) is Telemetry:
                telemetry += 1
                self._one_telemetry(msg, now)
                latest = msg
                continue
            if isinstance(msg, DirectCommand):
                if type(msg) is Alive:
                    stats.alive_received += 1
                append(msg)
                continue
            if type(msg) is ParamAck or type(msg) is ParamNack:
                self._frames.answered(msg.param_id, msg.value if type(msg) is ParamAck else None)
                self._requests.answer(msg, now)
            if board_said:
                counted += 1
                assert msg.counter is not None
                self._count(msg.counter, now)
            append(msg)
        stats.frames_received += frames
        stats.messages_received += counted + telemetry
        if telemetry:
            stats.telemetry_received += telemetry
            self.latest_telemetry = latest

    def _found(self, now: float) -> None:
        self._hearing.liveness = Liveness.ALIVE
        self._events.append(BoardFound(at=now))
        self._continuity.heard(now, self.wire_crc.on, self._stream.last_t_us,
                               self._stream.last_at, ask=not self._settings.listen_only)

    def next_event(self) -> Event | None:
        """The oldest pending event, or ``None`` when there is none."""
        return self._events.popleft() if self._events else None

    def events(self) -> Iterator[Event]:
        """Drain every pending event."""
        events = self._events  # the one queue, for the connection's life
        while events:
            yield events.popleft()

    @property
    def pending_events(self) -> int:
        return len(self._events)

    # --- sending --------------------------------------------------------------------------

    def send(self, message: Message | CountedMessage | DirectCommand, now: float) -> None:
        """Queue ``message`` for :meth:`data_to_send`; a counted message takes the next
        counter value when it goes out. A reference may wait for line room (see the class)."""
        if type(message) not in self._sendable:
            raise LocalProtocolError(f"a {self.role.value} does not send {type(message).__name__}")
        if type(message) is References:
            if not (abs(message.ref_a) <= FLOAT32_MAX and abs(message.ref_b) <= FLOAT32_MAX):
                # NaN fails the comparison too. Checked here, not at encoding: a held
                # reference is encoded later, where an error would surface far from its cause.
                raise LocalProtocolError(
                    f"references must be finite numbers within the float32 range, got "
                    f"({message.ref_a!r}, {message.ref_b!r})"
                )
            if self._line.hold(message, now):
                return
        self._queue(message, now)

    def data_to_send(self) -> bytes:
        """Every byte to write to the port now, in order."""
        outbox = self._outbox
        if not outbox:
            return b""
        out = outbox[0] if len(outbox) == 1 else b"".join(outbox)
        outbox.clear()
        return out

    def _queue(self, message: Message | CountedMessage | DirectCommand, now: float) -> None:
        wire = self._frames.encode(message)
        self._outbox.append(wire)
        self._line.sent(len(wire), now)

    @property
    def next_counter(self) -> int:
        """The counter value the next counted message will carry."""
        return self._frames.next_counter

    @property
    def wire_crc(self) -> HostWireCrc:
        """The optional wire CRC's state (:class:`~fpgalink.protocol.crc.HostWireCrc`)."""
        return self._frames.wire_crc

    # --- heartbeat and liveness -----------------------------------------------------------

    def start(self, now: float) -> None:
        """Begin expecting the board: silence from ``now`` on counts."""
        self._hearing.start(now)

    def enable(self, now: float) -> None:
        """Send ``RE`` now and every ``heartbeat_interval`` until :meth:`disable` (or until
        the board restarts or its watchdog lapses: then enable again)."""
        self._heartbeat.enable(now)

    def disable(self, now: float) -> None:
        """Stop the heartbeat and send ``RD`` (the board drops enable at once)."""
        self._heartbeat.disable(now)

    @property
    def enabled(self) -> bool:
        """This side sends ``RE`` every heartbeat interval."""
        return self._heartbeat.enabled

    @property
    def liveness(self) -> Liveness:
        return self._hearing.liveness

    @property
    def boards_time(self) -> bool:
        """``now`` is the board's own time (see :class:`~.liveness.TelemetryWatch`)."""
        return self._stream.boards_time

    @boards_time.setter
    def boards_time(self, value: bool) -> None:
        self._stream.boards_time = value

    @property
    def telemetry_stale(self) -> bool:
        """Telemetry is configured on, and not arriving."""
        return self._stream.stale

    @property
    def telemetry_period(self) -> float | None:
        """The board's telemetry period, s, as confirmed or as seen (``None``: not known)."""
        return self._stream.period

    @property
    def verifying(self) -> bool:
        """Heard again after a silence or on a reconnected port, and not yet known whether
        the board restarted meanwhile."""
        return self._continuity.verifying

    @property
    def resyncing(self) -> bool:
        """The board restarted and the configuration this side holds is being set again."""
        return self._continuity.resyncing

    def get_timer(self) -> float | None:
        """The next time :meth:`handle_timer` has work to do, or ``None``."""
        port_up = self._port_up
        deadlines = (self._requests.deadline(),
                     self._heartbeat.next_at if port_up else None,
                     self._hearing.deadline(),
                     self._line.deadline(),
                     self._stream.deadline() if port_up else None)
        return min((d for d in deadlines if d is not None), default=None)

    def handle_timer(self, now: float) -> None:
        self._heartbeat.due(now)
        if (held := self._line.due(now)) is not None:
            self._queue(held, now)
        silence = self._hearing.deadline()
        if silence is not None and now >= silence:
            origin = self._hearing.silent_since
            assert origin is not None
            self._hearing.liveness = Liveness.LOST
            self.stats.heartbeat_misses += 1
            self._events.append(BoardSilent(now - origin, at=now))
            self._continuity.lost("", origin)
            self._requests.fail_all(BoardLost(f"board silent for {now - origin:.3f} s"), now)
        self._requests.expire(now)
        if (self._port_up and self._stream.check(now)
                and self.liveness is Liveness.ALIVE and not self._settings.listen_only):
            self._continuity.ask(now, self.wire_crc.on)

    # --- the port -------------------------------------------------------------------------

    def port_lost(self, now: float, reason: str, cause: str = "") -> None:
        """The transport went away (:class:`~fpgalink.events.PortLost`, saying ``cause``):
        pending requests fail (:class:`~fpgalink.errors.BoardLost` with ``reason``),
        nothing is sent until :meth:`reconnected`."""
        self.stats.port_losses += 1
        self._events.append(PortLost(cause or reason, at=now))
        self._port_up = False
        self._continuity.lost(", on the reconnected port", now)
        self._hearing.liveness = Liveness.LOST
        # No heartbeat can reach the board: its watchdog lapses. Nothing enables it again
        # by itself when the port comes back; the caller decides.
        self._heartbeat.stop()
        self._outbox.clear()
        self._line.held = None
        self._requests.fail_all(BoardLost(reason), now)

    def reconnected(self, now: float) -> None:
        """A new transport to the board: liveness is judged anew from ``now``. The link was
        disabled when the port went; when the board is heard again its counter says whether
        it restarted meanwhile (:class:`~fpgalink.events.BoardRestarted`: what this side
        holds is set again) or went on (:class:`~fpgalink.events.BoardBack`: what it sent
        meanwhile is counted lost). The caller enables again when it is safe."""
        self.stats.reconnects += 1
        self._events.append(PortRestored(at=now))
        self._port_up = True
        self._frames.reset()
        self._hearing.reconnected(now)
        self._line.free_at = now

    def close(self, now: float, reason: str = "") -> None:
        """Stop the heartbeat (queueing ``RD`` if enabled), fail pending requests with
        :class:`~fpgalink.errors.LinkClosed`; :class:`~fpgalink.events.Closed` (why:
        ``reason``) is the last status event."""
        if self.enabled:
            self.disable(now)
        self._heartbeat.stop()
        self._line.held = None
        self._requests.fail_all(LinkClosed("link closed while the request was pending"), now)
        self._events.append(Closed(reason, at=now))

    # --- parameter requests and the configuration held ------------------------------------

    def set_param(self, param: Param, channel: int, value: int | float, now: float) -> int:
        """Send ``PS`` (already validated by the caller via :meth:`Param.coerce`); returns
        a request id that a :class:`RequestDone` or :class:`RequestFailed` event will carry."""
        self._continuity.superseded(param, channel)
        request_id = self._requests.start(param, channel, value, now,
                                          self._settings.unanswered_rounds)
        self._continuity.config.sent(param, channel, value, request_id)
        return request_id

    def get_param(self, param: Param, channel: int, now: float) -> int:
        return self._requests.start(param, channel, None, now, self._settings.unanswered_rounds)

    def cancel_request(self, request_id: int, now: float) -> None:
        """The caller gave up on a request of its own: it is withdrawn, never sent again.
        A set that went out may still land: :class:`~fpgalink.events.SetWithdrawn` says so,
        the parameter is read back, and found at another value than the one last confirmed
        it is set back to it (:class:`~fpgalink.events.WithdrawnSetLanded`)."""
        self._continuity.withdraw(request_id, now)

    @property
    def pending_requests(self) -> int:
        return len(self._requests.pending)

    @property
    def held(self) -> dict[tuple[int, int], tuple[Param, int, int | float]]:
        """Every parameter this side set and the board confirmed, in the order first set:
        the configuration it holds, set again after the board restarts."""
        return self._continuity.config.held

    def hold(self, param: Param, channel: int, value: int | float) -> None:
        """Keep ``value`` (the board's, as read) as this side's configuration for
        ``param``: set again after the board restarts, as a value set here would be."""
        self._continuity.config.hold(param, channel, value)

    def resync(self, now: float) -> None:
        """Set again, one at a time, every parameter this side holds, as after a restart
        (done by itself then); :class:`~fpgalink.events.BoardResynced` says how it went.
        The caller asks for it again after one that failed for want of answers."""
        self._continuity.resync(now)

    def _settled(self, request: Request, outcome: Outcome, result: RequestDone | RequestFailed,
                 now: float) -> None:
        """A request ended: a confirmed value is held (a set's) and followed (what the
        telemetry stream should be); the restart logic learns of its own questions."""
        if isinstance(result, RequestDone):
            if request.value is not None:
                self._continuity.config.confirmed(request.param, request.channel, result.value)
            self._stream.confirmed(request.param, result.value, now)
        self._continuity.settled(request, outcome, result, now)

    def _restarted(self, evidence: RestartEvidence, detail: str, now: float) -> None:
        """The board restarted (or may have): it runs its power-up state — disabled,
        telemetry off, parameters at their power-up values, counters from 0, the plain wire.
        Stop keeping it enabled, follow its new counter sequence, set again what is held."""
        self.stats.restarts += 1
        self.identity.forget()
        self._continuity.restarted(evidence, detail, now)
        self._counting.restarted()
        self._heartbeat.board_restarted(now)
        self.latest_telemetry = None
        self._frames.board_restarted()
        self._stream.board_restarted()
        self._continuity.resync(now)
