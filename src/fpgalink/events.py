"""Everything a :class:`~fpgalink.Connection` reports, as one hierarchy under
:class:`~fpgalink.protocol.Event`.

From the wire (defined in :mod:`fpgalink.protocol`): every received message (``Telemetry``,
``ParamAck`` … a generic ``CountedMessage``, the direct ``Alive``), ``Malformed`` content and
the framing errors ``NoiseDropped`` and ``FrameAborted``. From the connection itself (defined
here): counter gaps, duplicates and late arrivals, the board lost and found, a parameter
request's outcome, and events dropped because nobody drained them.

Order is stream order, with one rule: :class:`BoardFound` comes *before* the message that
revealed the board, so a consumer knows the board is there when it sees the message.

The board's real life, each reported, never silent: :class:`BoardRestarted` (its counter
back to ``00000``, its clock going backwards, a parameter the host set found at another
value) and then :class:`BoardResynced` once the configuration the host holds is applied
again; a board heard again after a silence or on a reconnected port is asked, and its
answer's counter says whether it restarted or is :class:`BoardBack`;
:class:`WatchdogLapsed` (the board's 300 ms watchdog disabled it while the host meant it
enabled); :class:`TelemetryStale` and :class:`TelemetryResumed` (telemetry configured on
and none arriving); :class:`WireCrcMismatch` (its frames in the other wire-CRC mode);
:class:`BoardIdentified` (what it said of itself when asked: its protocol declaration,
firmware and serial, docs/protocol.md §8).

**Status events** (:class:`StatusEvent`) are what a link's watchers get
(``Link.watch()``, ``Link.on_event()``): the board lost, found, back, restarted,
resynced, its faults, a withdrawn set, and its port lost, restored and the link closed.
Each has a stable :attr:`~StatusEvent.name` (``board_lost``, ``port_restored`` …: what the
CLI prints, ROS diagnostics and recordings log), the time it happened on the connection's
clock (``at``: the ``now`` the connection was told) and one line, :meth:`~StatusEvent.describe`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

from fpgalink.errors import FpgalinkError
from fpgalink.protocol import (
    SEED_PROTOCOL,
    Alive,
    BoardIdentity,
    CountedMessage,
    Event,
    FrameAborted,
    FramingError,
    IdentityMatch,
    IdentityMismatch,
    Malformed,
    NoiseDropped,
    Param,
    ParamAck,
    ParamNack,
    Telemetry,
)

__all__ = [
    "Alive",
    "BoardBack",
    "BoardFault",
    "BoardFound",
    "BoardIdentified",
    "BoardRestarted",
    "BoardResynced",
    "BoardSilent",
    "Closed",
    "CountedMessage",
    "CounterDuplicate",
    "CounterGap",
    "CounterLate",
    "Event",
    "EventsDropped",
    "FrameAborted",
    "FramingError",
    "Malformed",
    "NoiseDropped",
    "ParamAck",
    "ParamNack",
    "PortLost",
    "PortRestored",
    "RequestAskedAgain",
    "RequestDone",
    "RequestFailed",
    "RestartEvidence",
    "SetWithdrawn",
    "StatusEvent",
    "Telemetry",
    "TelemetryResumed",
    "TelemetryStale",
    "WatchdogLapsed",
    "WireCrcMismatch",
    "WithdrawnSetLanded",
]


@dataclass(frozen=True, slots=True)
class CounterGap(Event):
    """Counters were skipped before ``counter``: ``lost`` messages never arrived (so far)."""

    lost: int
    counter: int


@dataclass(frozen=True, slots=True)
class CounterDuplicate(Event):
    counter: int


@dataclass(frozen=True, slots=True)
class CounterLate(Event):
    """A message reported missing arrived after all (reordered on the way)."""

    counter: int


@dataclass(frozen=True, slots=True)
class StatusEvent(Event):
    """The base of what a link's watchers get: ``name`` (stable, for logs and lines), ``at``
    (when, on the connection's clock; not compared) and :meth:`describe` (one line)."""

    name: ClassVar[str] = "status"
    at: float = field(default=math.nan, compare=False, kw_only=True)

    def describe(self) -> str:
        return ""


@dataclass(frozen=True, slots=True)
class BoardSilent(StatusEvent):
    """Nothing well-formed heard for longer than the liveness timeout: the board is lost."""

    name: ClassVar[str] = "board_lost"
    silent_for: float

    def describe(self) -> str:
        return f"silent for {self.silent_for:.3f} s"


@dataclass(frozen=True, slots=True)
class BoardFound(StatusEvent):
    """The board is heard for the first time, or again after it was lost."""

    name: ClassVar[str] = "board_found"


@dataclass(frozen=True, slots=True)
class PortLost(StatusEvent):
    """The device or socket went away (``reason``); the link reopens it if it may."""

    name: ClassVar[str] = "port_lost"
    reason: str

    def describe(self) -> str:
        return self.reason


@dataclass(frozen=True, slots=True)
class PortRestored(StatusEvent):
    """A new port to the board: liveness judged anew; the board, heard, is judged too."""

    name: ClassVar[str] = "port_restored"


@dataclass(frozen=True, slots=True)
class Closed(StatusEvent):
    """The link closed (``reason``: why, when not asked to): the last status event."""

    name: ClassVar[str] = "closed"
    reason: str = ""

    def describe(self) -> str:
        return self.reason


@dataclass(frozen=True, slots=True)
class EventsDropped(Event):
    """The caller did not drain events and the queue hit its cap; the oldest were dropped."""

    count: int


@dataclass(frozen=True, slots=True)
class RequestDone(Event):
    """A parameter request was confirmed: ``value`` is what the board says is in force."""

    request_id: int
    param: Param
    channel: int
    value: int | float
    tries: int


@dataclass(frozen=True, slots=True)
class RequestFailed(Event):
    """A parameter request ended without confirmation; ``error`` says why
    (:class:`~fpgalink.errors.ParameterRefused`, :class:`~fpgalink.errors.ValueMismatch`,
    :class:`~fpgalink.errors.RequestTimeout`, :class:`~fpgalink.errors.BoardLost` …)."""

    request_id: int
    param: Param
    channel: int
    error: FpgalinkError
    tries: int


@dataclass(frozen=True, slots=True)
class RequestAskedAgain(Event):
    """A parameter request went unanswered through a round of tries while the board was
    heard: it is asked again at once (its ``round``, from 2), so an answer that comes later
    than the tries (a loaded machine, a slow line) confirms it."""

    request_id: int
    param: Param
    channel: int
    round: int


@dataclass(frozen=True, slots=True)
class BoardFault(StatusEvent):
    """The base of the status events about the board's real life."""


class RestartEvidence(Enum):
    """What showed that the board restarted."""

    COUNTER_RESET = "its message counter went back"
    CLOCK_BACKWARDS = "its clock (t_us) went backwards"
    #: heard again after a silence, its clock ran much less than this host's meanwhile
    CLOCK_BEHIND = "its clock (t_us) ran behind this host's over a silence"
    CONFIG_LOST = "a parameter this host set reads back at another value"


@dataclass(frozen=True, slots=True)
class BoardRestarted(BoardFault):
    """The board restarted (power-up state: disabled, telemetry off, parameters at their
    power-up values, counters from 0). The connection has stopped its heartbeat (and sent
    ``RD``): enable again when ready. It applies the configuration it holds again;
    :class:`BoardResynced` follows."""

    name: ClassVar[str] = "board_restarted"

    evidence: RestartEvidence
    detail: str

    def describe(self) -> str:
        return f"restarted: {self.evidence.value} ({self.detail})"


@dataclass(frozen=True, slots=True)
class BoardBack(BoardFault):
    """The board, heard again after a silence or on a reconnected port, did not restart:
    its message counter went on from where it was (its configuration is as it was)."""

    name: ClassVar[str] = "board_back"

    detail: str

    def describe(self) -> str:
        return f"back, not restarted: {self.detail}"


@dataclass(frozen=True, slots=True)
class BoardResynced(BoardFault):
    """After a restart, every parameter this host had set on the board (confirmed) was
    set again: ``applied`` of them confirmed; ``failed`` names the others with the reason.
    Until this event the board runs its power-up configuration."""

    name: ClassVar[str] = "board_resynced"

    applied: int
    failed: tuple[tuple[str, FpgalinkError], ...] = ()

    @property
    def ok(self) -> bool:
        return not self.failed

    def describe(self) -> str:
        if self.ok:
            return f"reconfigured: {self.applied} parameter(s) set again and confirmed"
        what = "; ".join(f"{name}: {error}" for name, error in self.failed)
        return f"reconfiguring failed: {what}"


@dataclass(frozen=True, slots=True)
class BoardIdentified(BoardFault):
    """The board was asked who it is (``IQ``, docs/protocol.md §8): at connect, when the
    caller asks, and after each restart (a re-flash changes it). ``identity`` is its
    answer, ``None`` for a seed board that does not know ``IQ``; ``match`` compares its
    declaration hash with this host's (``host``). A mismatch is the caller's to refuse (the
    robot stops and keeps the board not ready; the CLI ends)."""

    name: ClassVar[str] = "board_identified"

    identity: BoardIdentity | None
    match: IdentityMatch
    host: int

    @property
    def mismatch(self) -> IdentityMismatch | None:
        """The error a refusal raises, for a board built from another declaration."""
        if self.match is not IdentityMatch.MISMATCH or self.identity is None:
            return None
        return IdentityMismatch("", self.identity.declarations, self.host)

    def describe(self) -> str:
        if self.identity is None:
            return SEED_PROTOCOL
        mismatch = self.mismatch
        if mismatch is not None:
            return f"{mismatch} ({self.identity.describe()})"
        return self.identity.describe()


@dataclass(frozen=True, slots=True)
class WatchdogLapsed(BoardFault):
    """The board's watchdog disabled it (its references cleared to 0) while this host
    meant it enabled, so the connection stopped its heartbeat and sent ``RD``: enable again
    to go on. Either the host's own heartbeat was overdue (``host_silent_for``: seconds
    since its last ``RE``, e.g. a stalled process), or the board's telemetry showed it
    disabled after it had shown it enabled: then ``host_silent_for`` is the longest gap
    between this host's ``RE`` in the last second when that was twice the heartbeat interval
    or more (the host late, though not past giving up), else ``None``."""

    name: ClassVar[str] = "watchdog_lapsed"

    host_silent_for: float | None
    detail: str

    def describe(self) -> str:
        if self.host_silent_for is not None:
            return (f"disabled itself (watchdog: host silent "
                    f"{self.host_silent_for * 1000:.0f} ms)")
        return f"disabled itself ({self.detail})"


@dataclass(frozen=True, slots=True)
class TelemetryStale(BoardFault):
    """Telemetry is configured on (``GetDataPeriodical`` = 1, confirmed), and none has come
    for ``silent_for`` seconds: more than the connection's limit of periods of
    ``period`` seconds."""

    name: ClassVar[str] = "telemetry_stale"

    silent_for: float
    period: float

    def describe(self) -> str:
        return (f"telemetry stopped: none for {self.silent_for * 1000:.0f} ms "
                f"({self.silent_for / self.period:.0f} periods of {self.period * 1000:g} ms)")


@dataclass(frozen=True, slots=True)
class WireCrcMismatch(BoardFault):
    """The board's frames arrive in the other wire-CRC mode than this host's
    (docs/protocol.md §7): carrying the CRC while this host's is off (``board_crc``), or
    without it while this host's is on. They are dropped, never messages, and counted
    (:attr:`~fpgalink.connection.LinkStats.crc_mode_mismatches`); a request then unanswered
    fails with :class:`~fpgalink.errors.WireCrcMismatchError`. Connect in the board's mode
    (``open_link(…, wire_crc=True)``, ``fpgalink-cli --wire-crc``). Said once, until this
    host's mode is settled again (the board's answer about ``WireCrc``, its restart)."""

    name: ClassVar[str] = "wire_crc_mismatch"

    board_crc: bool

    def describe(self) -> str:
        if self.board_crc:
            return ("the board sends CRC-16 frames and this host has the wire CRC off: they "
                    "are dropped; connect with the CRC on")
        return ("the board sends frames without the wire CRC and this host has it on: they "
                "are dropped; connect with the CRC off")


@dataclass(frozen=True, slots=True)
class TelemetryResumed(BoardFault):
    """Telemetry came again after :class:`TelemetryStale`, ``gap`` seconds after the last
    sample before it."""

    name: ClassVar[str] = "telemetry_resumed"

    gap: float

    def describe(self) -> str:
        return f"telemetry resumed ({self.gap * 1000:.0f} ms after the last sample)"


@dataclass(frozen=True, slots=True)
class SetWithdrawn(StatusEvent):
    """The caller gave up on a set (cancelled it) after it went out: it is never sent again,
    but the board may have taken it. The parameter is read back:
    :class:`WithdrawnSetLanded` follows when the board holds another value than the one last
    confirmed."""

    name: ClassVar[str] = "set_withdrawn"

    request_id: int
    param: Param
    channel: int
    value: int | float

    def describe(self) -> str:
        return (f"set {self.param.full_name(self.channel)} = {self.value} withdrawn after it "
                f"went out: it may still land; reading it back")


@dataclass(frozen=True, slots=True)
class WithdrawnSetLanded(StatusEvent):
    """A parameter read back after a withdrawn set holds ``found``, not the value last
    confirmed to the caller: ``restored`` is that value, set again (``None``: none was
    confirmed on this link, so nothing is set back)."""

    name: ClassVar[str] = "withdrawn_set_landed"

    param: Param
    channel: int
    found: int | float
    restored: int | float | None

    def describe(self) -> str:
        name = self.param.full_name(self.channel)
        if self.restored is None:
            return (f"{name} reads {self.found} after a withdrawn set; no value was "
                    f"confirmed on this link to set back")
        return (f"{name} reads {self.found} after a withdrawn set: set back to "
                f"{self.restored}, the value last confirmed")
