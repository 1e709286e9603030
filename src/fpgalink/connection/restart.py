"""A board's restarts, and the configuration this side keeps on it across them.

The board is in one :class:`Phase` at a time and moves by :data:`TRANSITIONS` alone (h11's
way): out of reach (silent, or its port gone), it may restart unheard; heard again it is
*verifying* until what it sends decides — its counter going on (:class:`BoardBack`), or
evidence of a restart (:class:`BoardRestarted`: its counter back at ``00000``, its clock
behind, a setting this side holds read back at another value). A restarted board is set up
again, one setting at a time, from the :class:`Configuration` this side holds
(:class:`BoardResynced` when done); a silence pauses that, and the board heard going on
resumes it from the setting it was at.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from enum import Enum

from fpgalink.connection.liveness import T_US_WRAP
from fpgalink.connection.requests import Outcome, Request, Requests
from fpgalink.connection.stats import LinkStats
from fpgalink.errors import FpgalinkError
from fpgalink.events import (
    BoardBack,
    BoardRestarted,
    BoardResynced,
    RequestDone,
    RequestFailed,
    RestartEvidence,
    SetWithdrawn,
    WithdrawnSetLanded,
)
from fpgalink.protocol import Event, Param, ParamType, float32, lookup

__all__ = ["RESYNC_ROUNDS", "TRANSITIONS", "Configuration", "Continuity", "Cue", "Phase"]

#: A setting a restart's resync sets again is asked this many more rounds when unanswered
#: (each with the request's own tries) before it counts as failed: answers that come later
#: than one round (a loaded machine) still confirm it.
RESYNC_ROUNDS = 4
_GET_DATA = lookup("GetDataPeriodical")
_WIRE_CRC = lookup("WireCrc")
#: How far behind this host's time a board's clock may fall over a silence and still be the
#: same run (a sample buffered before this host read it, the host's own timer lateness).
_CLOCK_SLACK_S = 0.1
_CLOCK_SLACK_SHARE = 0.1

Setting = tuple[Param, int, int | float]


class Phase(Enum):
    IN_STEP = "heard, and running as this side knows it"
    OUT_OF_REACH = "silent, or its port gone: it may restart unheard"
    VERIFYING = "heard again after it was out of reach: whether it restarted is not known"
    RESYNCING = "restarted: the configuration this side holds is being set again"
    RESYNC_PAUSED = "out of reach in the middle of a resync"
    RESYNC_VERIFYING = "heard again in the middle of a paused resync"


class Cue(Enum):
    LOST = "silent past the liveness timeout, or the port gone"
    HEARD = "a well-formed message after it was out of reach"
    WENT_ON = "its counter (or its clock) went on from where it was"
    RESTARTED = "evidence of a restart"
    RESYNC = "the configuration is to be set again (asked for, or after a restart)"
    RESYNC_DONE = "every setting held was set again, or failed"


_P, _C = Phase, Cue
#: (phase, cue) → the next phase; every pair is here.
TRANSITIONS: dict[tuple[Phase, Cue], Phase] = {
    (_P.IN_STEP, _C.LOST): _P.OUT_OF_REACH,
    (_P.IN_STEP, _C.HEARD): _P.IN_STEP,
    (_P.IN_STEP, _C.WENT_ON): _P.IN_STEP,
    (_P.IN_STEP, _C.RESTARTED): _P.RESYNCING,
    (_P.IN_STEP, _C.RESYNC): _P.RESYNCING,
    (_P.IN_STEP, _C.RESYNC_DONE): _P.IN_STEP,
    (_P.OUT_OF_REACH, _C.LOST): _P.OUT_OF_REACH,
    (_P.OUT_OF_REACH, _C.HEARD): _P.VERIFYING,
    (_P.OUT_OF_REACH, _C.WENT_ON): _P.OUT_OF_REACH,
    (_P.OUT_OF_REACH, _C.RESTARTED): _P.RESYNCING,
    (_P.OUT_OF_REACH, _C.RESYNC): _P.RESYNC_PAUSED,
    (_P.OUT_OF_REACH, _C.RESYNC_DONE): _P.OUT_OF_REACH,
    (_P.VERIFYING, _C.LOST): _P.OUT_OF_REACH,
    (_P.VERIFYING, _C.HEARD): _P.VERIFYING,
    (_P.VERIFYING, _C.WENT_ON): _P.IN_STEP,
    (_P.VERIFYING, _C.RESTARTED): _P.RESYNCING,
    (_P.VERIFYING, _C.RESYNC): _P.RESYNC_VERIFYING,
    (_P.VERIFYING, _C.RESYNC_DONE): _P.VERIFYING,
    (_P.RESYNCING, _C.LOST): _P.RESYNC_PAUSED,
    (_P.RESYNCING, _C.HEARD): _P.RESYNCING,
    (_P.RESYNCING, _C.WENT_ON): _P.RESYNCING,
    (_P.RESYNCING, _C.RESTARTED): _P.RESYNCING,
    (_P.RESYNCING, _C.RESYNC): _P.RESYNCING,
    (_P.RESYNCING, _C.RESYNC_DONE): _P.IN_STEP,
    (_P.RESYNC_PAUSED, _C.LOST): _P.RESYNC_PAUSED,
    (_P.RESYNC_PAUSED, _C.HEARD): _P.RESYNC_VERIFYING,
    (_P.RESYNC_PAUSED, _C.WENT_ON): _P.RESYNC_PAUSED,
    (_P.RESYNC_PAUSED, _C.RESTARTED): _P.RESYNCING,
    (_P.RESYNC_PAUSED, _C.RESYNC): _P.RESYNC_PAUSED,
    (_P.RESYNC_PAUSED, _C.RESYNC_DONE): _P.OUT_OF_REACH,
    (_P.RESYNC_VERIFYING, _C.LOST): _P.RESYNC_PAUSED,
    (_P.RESYNC_VERIFYING, _C.HEARD): _P.RESYNC_VERIFYING,
    (_P.RESYNC_VERIFYING, _C.WENT_ON): _P.RESYNCING,
    (_P.RESYNC_VERIFYING, _C.RESTARTED): _P.RESYNCING,
    (_P.RESYNC_VERIFYING, _C.RESYNC): _P.RESYNC_VERIFYING,
    (_P.RESYNC_VERIFYING, _C.RESYNC_DONE): _P.VERIFYING,
}
_VERIFYING = frozenset({Phase.VERIFYING, Phase.RESYNC_VERIFYING})
_RESYNCING = frozenset({Phase.RESYNCING, Phase.RESYNC_PAUSED, Phase.RESYNC_VERIFYING})


def _question(crc_on: bool) -> Param:
    """What a board heard again, or whose telemetry stopped, is asked: a plain board its
    telemetry setting; on the CRC wire WireCrc, which a board restarted onto the plain wire
    understands in either form, and whose answer is taken in either form."""
    return _WIRE_CRC if crc_on else _GET_DATA


def _same(param: Param, a: int | float, b: int | float | None) -> bool:
    """Whether the board holding ``a`` holds ``b`` (a float parameter as float32)."""
    if b is None or param.type is not ParamType.FLOAT:
        return a == b
    return float32(float(a)) == float32(float(b))


class Configuration:
    """What this side set and the board confirmed, in the order first set (``held``: set
    again after a restart), and values sent in a set not confirmed since
    (``unconfirmed``: the board may hold any of them, so a probe reading one is no lost
    setting)."""

    __slots__ = ("held", "last_set", "unconfirmed")

    def __init__(self) -> None:
        self.held: dict[tuple[int, int], Setting] = {}
        self.unconfirmed: dict[tuple[int, int], set[int | float]] = {}
        self.last_set: dict[tuple[int, int], int] = {}  #: the newest set's request id

    def sent(self, param: Param, channel: int, value: int | float, request_id: int) -> None:
        self.unconfirmed.setdefault((param.id, channel), set()).add(
            float32(float(value)) if param.type is ParamType.FLOAT else value)
        self.last_set[(param.id, channel)] = request_id

    def confirmed(self, param: Param, channel: int, value: int | float) -> None:
        # Keys keep their first place: the order the configuration was built in.
        self.held[(param.id, channel)] = (param, channel, value)
        self.unconfirmed.pop((param.id, channel), None)

    def hold(self, param: Param, channel: int, value: int | float) -> None:
        self.held.setdefault((param.id, channel), (param, channel, value))

    def lost(self, param: Param, channel: int, value: int | float) -> int | float | None:
        """The value this side holds for ``param`` when the board, reading ``value``, lost
        it: another value, and none sent unconfirmed (a set of it left unconfirmed, asked
        again meanwhile or still waiting behind a slow host's telemetry, may have been
        applied)."""
        held = self.held.get((param.id, channel))
        if held is None or held[2] == value or value in self.unconfirmed.get(
                (param.id, channel), ()):
            return None
        return held[2]

    def in_resync_order(self) -> list[Setting]:
        """The wire CRC first (every later message then carries it, as before), telemetry
        last, so the stream comes back from a board configured as before."""
        return sorted(self.held.values(),
                      key=lambda held: (held[0] is _GET_DATA) - (held[0] is _WIRE_CRC))


class ClockCheck:
    """Heard again after it was out of reach: is the board's clock where one that ran on
    would have it? Its samples' board time since the last sample before (``baseline``)
    against this host's time over the same stretch: one that ran on counted about the
    host's time, one that restarted meanwhile only from its power-up (the slack covers a
    sample that waited in a buffer).

    What a sample's arrival time says depends on where the host was: reading all along
    (a silence), a sample was sent when it arrived. Back on a reconnected port, the first
    samples read may have waited in the port while the host was away (a pty queues what the
    board sent since it came back): their arrival is not their send time, and a clock that
    looks behind may be nothing but the queue. Such a sample is no verdict (``doubt``);
    samples read after the board's answer to a question asked since were sent after that
    question went out (``sent_after``), and decide."""

    __slots__ = ("baseline", "doubt", "sent_after", "trust_arrival")

    def __init__(self) -> None:
        self.baseline: tuple[int, float] | None = None  #: (t_us, arrival) before the loss
        self.trust_arrival = True
        self.sent_after: float | None = None
        self.doubt = False

    def start(self, last_t_us: int | None, last_at: float | None, queued: bool) -> None:
        self.baseline = None if last_t_us is None or last_at is None else (last_t_us, last_at)
        self.trust_arrival = not queued
        self.sent_after = None
        self.doubt = False

    def behind(self, t_us: int, now: float) -> str | None:
        """The restart's detail when the sample at ``t_us``, arrived at ``now``, shows the
        clock behind; ``None`` when it went on, or is no verdict (then ``doubt``)."""
        if self.baseline is None:
            return None
        base_t_us, base_at = self.baseline
        board_s = (t_us - base_t_us) % T_US_WRAP / 1e6
        host_s = now - base_at
        if not _behind(board_s, host_s):
            self.doubt = False  # a queue only makes a sample look later: it went on
            return None
        if not self.trust_arrival:
            if self.sent_after is None:
                self.doubt = True
                return None
            host_s = self.sent_after - base_at
            if not _behind(board_s, host_s):
                self.doubt = False
                return None
        self.doubt = False
        return f"{board_s:.3f} s of board time over {host_s:.3f} s of this host's"


def _behind(board_s: float, host_s: float) -> bool:
    return board_s < host_s - (_CLOCK_SLACK_S + _CLOCK_SLACK_SHARE * host_s)


class Continuity:
    """The board's phase, the question asked to settle it (``probe``) and the resync.
    ``restart`` is the connection's own reaction to a restart found here (a setting read
    back lost): it resets what a board's power-up resets, then calls :meth:`resync`."""

    def __init__(self, requests: Requests, stats: LinkStats, *, emit: Callable[[Event], None],
                 restart: Callable[[RestartEvidence, str, float], None]) -> None:
        self.phase = Phase.IN_STEP
        self.config = Configuration()
        self.probe: int | None = None  #: the request asking the board what it has
        self._away: tuple[str, float] | None = None  #: out of reach: (where, since)
        self._verify: str | None = None  #: heard again: how long it was away, for the verdict
        self._queued = False  #: out of reach with its port gone: frames may wait in the port
        self.clock = ClockCheck()
        self._queue: deque[Setting] = deque()  #: the resync: what is still to set
        self._in_flight: int | None = None  #: the resync's request
        self._applied = 0
        self._failed: list[tuple[str, FpgalinkError]] = []
        #: read-backs after a withdrawn set (request id → the set's), and sets back
        self._rereads: dict[int, Request] = {}
        self._restores: dict[tuple[int, int], int] = {}
        self._requests = requests
        self._stats = stats
        self._emit = emit
        self._restart = restart

    @property
    def verifying(self) -> bool:
        return self.phase in _VERIFYING

    @property
    def resyncing(self) -> bool:
        return self.phase in _RESYNCING

    @property
    def doubting(self) -> bool:
        """Verifying, and a sample's clock looked behind while it may have waited in the
        port: every sample is judged until one decides."""
        return self.verifying and self.clock.doubt

    def _cue(self, cue: Cue) -> None:
        self.phase = TRANSITIONS[(self.phase, cue)]

    # --- out of reach, heard again ----------------------------------------------------------

    def lost(self, where: str, since: float) -> None:
        """Out of reach since ``since``: silent (``where`` empty) or its port gone (``where``
        says so; an earlier silence still counts from its start)."""
        if where and self._away is not None:
            since = self._away[1]
        self._away = (where, since)
        self._queued = bool(where)
        self._verify = None
        self._cue(Cue.LOST)

    def heard(self, now: float, crc_on: bool, last_t_us: int | None,
              last_at: float | None, *, ask: bool = True) -> None:
        """Heard after it was out of reach: it may have restarted meanwhile, or not. What it
        sends next decides (its counter back at 00000, or going on; its clock, against the
        last sample before, ``last_t_us`` arrived at ``last_at``), and a question asked
        (:func:`_question`; unless not to ``ask``) makes sure something comes."""
        if self._away is None:
            return
        where, since = self._away
        self._away = None
        self._verify = f"heard again after {now - since:.3f} s of silence{where}"
        self.clock.start(last_t_us, last_at, self._queued)
        self._cue(Cue.HEARD)
        if self.probe is None and ask:
            self.probe = self._requests.start(_question(crc_on), 0, None, now, 0)

    def went_on(self, now: float) -> None:
        """Heard again, it went on counting: it did not restart (unless its clock, in
        doubt, says otherwise yet)."""
        if self._verify is None or self.doubting:
            return
        detail, self._verify = self._verify, None
        self._drop_probe()
        self._cue(Cue.WENT_ON)
        self._emit(BoardBack(detail, at=now))

    def judge_clock(self, t_us: int, last_t_us: int | None, now: float
                    ) -> tuple[RestartEvidence, str] | None:
        """What a sample's clock says, its counter out of sequence: gone back from the last
        sample's (``last_t_us``), a restarted board (a damaged t_us alone comes with the
        counter in order); heard again, behind this host's time (:class:`ClockCheck`), a
        board that restarted while it was out of reach."""
        if last_t_us is not None and 0 < (last_t_us - t_us) % T_US_WRAP < T_US_WRAP // 2:
            return RestartEvidence.CLOCK_BACKWARDS, f"t_us {t_us} after {last_t_us}"
        return self.judge_doubt(t_us, now) if self.verifying else None

    def judge_doubt(self, t_us: int, now: float) -> tuple[RestartEvidence, str] | None:
        """A sample's clock, heard again (every sample while :attr:`doubting`)."""
        behind = self.clock.behind(t_us, now)
        return None if behind is None else (RestartEvidence.CLOCK_BEHIND, behind)

    def ask(self, now: float, crc_on: bool) -> None:
        """Telemetry stopped: ask the board what it has (a restart shows as telemetry off,
        and as its counter back at 00000 on the answer)."""
        if self.probe is None and not self.resyncing:
            self.probe = self._requests.start(_question(crc_on), 0, None, now, 0)

    def _drop_probe(self) -> None:
        """The question the probe asked is answered otherwise: its request goes, unsaid."""
        if self.probe is not None:
            self._requests.withdraw(self.probe)
            self.probe = None

    # --- restarts and the resync --------------------------------------------------------------

    def restarted(self, evidence: RestartEvidence, detail: str, now: float) -> None:
        """Say so; what was sent unconfirmed is gone with the board's power-up. The caller
        resets the rest of the link, then calls :meth:`resync`."""
        if self._verify is not None:
            detail += f"; {self._verify}"
            self._verify = None
        self.clock.doubt = False
        self._emit(BoardRestarted(evidence, detail, at=now))
        self.config.unconfirmed.clear()
        self._drop_probe()
        self._cue(Cue.RESTARTED)

    def resync(self, now: float) -> None:
        """Set again, one at a time, every setting held (``BoardResynced`` says how it went)."""
        if self._in_flight is not None:
            self._requests.withdraw(self._in_flight)
        self._queue = deque(self.config.in_resync_order())
        self._in_flight = None
        self._applied = 0
        self._failed = []
        self._cue(Cue.RESYNC)
        self._next(now)

    def go_on(self, now: float) -> None:
        """The board is heard: a resync that was paused goes on from the setting it was at
        (whether that one took is not known)."""
        if self.phase is Phase.RESYNCING and self._in_flight is None:
            self._next(now)

    def _next(self, now: float) -> None:
        """Set the next held setting again (one at a time: the board's RX RAM holds two
        frames), or report the resync done."""
        if self.phase is not Phase.RESYNCING:
            return
        if self._queue:
            param, channel, value = self._queue.popleft()
            self._in_flight = self._set(param, channel, value, now)
            return
        self._in_flight = None
        failed = tuple(self._failed)
        self._stats.resync_failures += len(failed)
        self._cue(Cue.RESYNC_DONE)
        self._emit(BoardResynced(self._applied, failed, at=now))

    def _set(self, param: Param, channel: int, value: int | float, now: float) -> int:
        request_id = self._requests.start(param, channel, value, now, RESYNC_ROUNDS)
        self.config.sent(param, channel, value, request_id)
        return request_id

    # --- a withdrawn set --------------------------------------------------------------------

    def withdraw(self, request_id: int, now: float) -> None:
        """The caller gave up on a request of its own (the link's questions are not its to
        withdraw): never sent again. A set went out, so it may still land: say so and read
        the parameter back."""
        if (request_id in (self.probe, self._in_flight) or request_id in self._rereads
                or request_id in self._restores.values()):
            return
        request = self._requests.withdraw(request_id)
        if request is None or request.value is None:
            return
        self._emit(SetWithdrawn(request.request_id, request.param, request.channel,
                                request.value, at=now))
        reread = self._requests.start(request.param, request.channel, None, now, RESYNC_ROUNDS)
        self._rereads[reread] = request

    def superseded(self, param: Param, channel: int) -> None:
        """The caller sets ``param`` anew: that decides what the board holds, so a set back
        (never sent again after the caller's) is withdrawn."""
        restore = self._restores.pop((param.id, channel), None)
        if restore is not None:
            self._requests.withdraw(restore)

    def _read_back(self, withdrawn: Request, value: int | float, now: float) -> None:
        """A parameter read back after a withdrawn set: another value than the one last
        confirmed is set back, and said (unless a newer set decides)."""
        key = (withdrawn.param.id, withdrawn.channel)
        if self.config.last_set.get(key) != withdrawn.request_id:
            return
        held = self.config.held.get(key)
        if held is not None and held[2] == value:
            return
        if held is None and not _same(withdrawn.param, value, withdrawn.value):
            return  # nothing confirmed, and the withdrawn set did not land
        restored = None if held is None else held[2]
        self._emit(WithdrawnSetLanded(withdrawn.param, withdrawn.channel, value, restored,
                                      at=now))
        if restored is not None:
            self._restores[key] = self._set(withdrawn.param, withdrawn.channel, restored, now)

    def settled(self, request: Request, outcome: Outcome, result: RequestDone | RequestFailed,
                now: float) -> None:
        """A request ended: the probe's answer may be a lost setting; the resync goes on; a
        read-back after a withdrawn set may call for a set back."""
        withdrawn = self._rereads.pop(request.request_id, None)
        if withdrawn is not None:
            if isinstance(result, RequestDone):
                self._read_back(withdrawn, result.value, now)
            return
        key = (request.param.id, request.channel)
        if self._restores.get(key) == request.request_id:
            del self._restores[key]
            return
        if request.request_id == self.probe:
            self.probe = None
            if self.doubting and outcome is Outcome.FAIL_TIMEOUT:
                # Whatever waited in the port was read by now, or not: only an answer tells.
                self.probe = self._requests.start(request.param, 0, None, now, 0)
            elif (self.doubting and self.clock.sent_after is None
                  and outcome is not Outcome.FAIL_LINK):
                # What comes after this answer was sent after the question: the next
                # sample decides.
                self.clock.sent_after = request.sent_at
            elif isinstance(result, RequestDone):
                self.clock.doubt = False
                lost = self.config.lost(request.param, request.channel, result.value)
                if lost is not None:
                    self._restart(RestartEvidence.CONFIG_LOST,
                                  f"{request.param.full_name(request.channel)} reads "
                                  f"{result.value} on the board; this host set {lost}", now)
                else:
                    self.went_on(now)
        elif request.request_id == self._in_flight:
            self._in_flight = None
            if isinstance(result, RequestDone):
                self._applied += 1
            elif outcome is Outcome.FAIL_LINK:
                # The board went silent (or its port): paused, not given up. It goes on
                # when the board is heard going on (restarted again meanwhile, it starts
                # over), its rounds afresh: a silence is not an unanswered board.
                if request.value is not None:
                    self._queue.appendleft((request.param, request.channel, request.value))
                return
            else:
                self._failed.append((request.param.full_name(request.channel), result.error))
            self._next(now)
