"""Everything a :class:`~fpgalink.Connection` reports, as one hierarchy under
:class:`~fpgalink.protocol.Event`.

From the wire (defined in :mod:`fpgalink.protocol`): every received message (``Telemetry``,
``ParamAck`` … a generic ``CountedMessage``, the direct ``Alive``), ``Malformed`` content and
the framing errors ``NoiseDropped`` and ``FrameAborted``. From the connection itself (defined
here): counter gaps, duplicates and late arrivals, the board lost and found, a parameter
request's outcome, and events dropped because nobody drained them.

Order is stream order, with one rule: :class:`BoardFound` comes *before* the message that
revealed the board, so a consumer knows the board is there when it sees the message.
"""

from __future__ import annotations

from dataclasses import dataclass

from fpgalink.errors import FpgalinkError
from fpgalink.protocol import (
    Alive,
    CountedMessage,
    Event,
    FrameAborted,
    FramingError,
    Malformed,
    NoiseDropped,
    Param,
    ParamAck,
    ParamNack,
    Telemetry,
)

__all__ = [
    "Alive",
    "BoardFound",
    "BoardSilent",
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
    "RequestDone",
    "RequestFailed",
    "Telemetry",
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
class BoardSilent(Event):
    """Nothing well-formed heard for longer than the liveness timeout: the board is lost."""

    silent_for: float


@dataclass(frozen=True, slots=True)
class BoardFound(Event):
    """The board is heard for the first time, or again after it was lost."""


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
