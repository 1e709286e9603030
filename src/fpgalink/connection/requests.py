"""Parameter requests: the table of those pending, the board's answers, and every retry.

A request is sent, and settled by :data:`REQUEST_TABLE` (the board's answer × another try
allowed?) and nothing else: confirmed, sent again, or failed. ``request_tries`` tries of
``request_timeout`` each make a round; a round that ends unanswered while the board is heard
is followed by another (as many as the request was given), so an answer later than the tries
(a loaded machine, a slow line) confirms the request asked again
(:class:`~fpgalink.events.RequestAskedAgain`); a board not heard fails it at once. This is
the link's one retry layer: the caller's requests, a restarted board's resync and the
questions the connection asks on its own all go through it. A request the caller gives up
on is withdrawn (:meth:`Requests.withdraw`): never sent again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from fpgalink.connection.settings import Settings
from fpgalink.connection.stats import LinkStats
from fpgalink.errors import (
    FpgalinkError,
    ParameterRefused,
    RequestTimeout,
    ValueMismatch,
    WireCrcMismatchError,
)
from fpgalink.events import RequestAskedAgain, RequestDone, RequestFailed
from fpgalink.protocol import (
    Event,
    Param,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    ParamType,
    float32,
)

__all__ = ["REQUEST_TABLE", "Answer", "Outcome", "Request", "Requests", "Settled"]


class Answer(Enum):
    """What the board did about a pending parameter request: the table's input."""

    ECHO = "a PA with the same id, channel, type code and value (any value for a get)"
    OTHER_VALUE = "a PA for the same parameter with another value or type code"
    REFUSED = "a PN for the same parameter"
    NO_ANSWER = "the try's timeout passed without either"
    LINK_DOWN = "the board was lost, the port vanished or the link closed"


class Outcome(Enum):
    DONE = "confirmed: the value is in force"
    RESEND = "send the request again (the next try)"
    FAIL_REFUSED = "failed: the board refused (final)"
    FAIL_MISMATCH = "failed: the board answered with another value"
    FAIL_TIMEOUT = "failed: no answer (a new round first, while any is left and the board heard)"
    FAIL_LINK = "failed: the link went down"


#: (answer, another try allowed?) → what happens to the request. Every pending request is
#: settled by this table and nothing else.
REQUEST_TABLE: dict[tuple[Answer, bool], Outcome] = {
    (Answer.ECHO, True): Outcome.DONE,
    (Answer.ECHO, False): Outcome.DONE,
    (Answer.OTHER_VALUE, True): Outcome.RESEND,
    (Answer.OTHER_VALUE, False): Outcome.FAIL_MISMATCH,
    (Answer.REFUSED, True): Outcome.FAIL_REFUSED,
    (Answer.REFUSED, False): Outcome.FAIL_REFUSED,
    (Answer.NO_ANSWER, True): Outcome.RESEND,
    (Answer.NO_ANSWER, False): Outcome.FAIL_TIMEOUT,
    (Answer.LINK_DOWN, True): Outcome.FAIL_LINK,
    (Answer.LINK_DOWN, False): Outcome.FAIL_LINK,
}


@dataclass(slots=True)
class Request:
    request_id: int
    param: Param
    channel: int
    value: int | float | None  #: None for a get
    message: ParamSet | ParamGet
    sent_at: float  #: when it was first sent: an answer to it was sent by the board later
    deadline: float
    rounds: int  #: rounds left after this one
    tries: int = 1  #: tries in this round
    round: int = 1
    last_answer: ParamAck | None = None  #: the last PA that did not match

    @property
    def what(self) -> str:
        verb = "set" if self.value is not None else "get"
        return f"{verb} {self.param.full_name(self.channel)}"

    def answer_to(self, ack: ParamAck) -> Answer:
        """Whether ``ack`` confirms this request: same type code, and for a set exactly the
        value sent (float32-exact for floats; never raises on any value the board sends)."""
        if ack.value_type != self.param.type:
            return Answer.OTHER_VALUE
        if self.value is None:
            return Answer.ECHO
        if self.param.type is ParamType.FLOAT:
            same = float32(float(self.value)) == ack.value
        else:
            same = isinstance(ack.value, int) and ack.value == self.value
        return Answer.ECHO if same else Answer.OTHER_VALUE


#: Told of every request settled: the request, its outcome, the event that says so and
#: ``now``.
Settled = Callable[[Request, Outcome, RequestDone | RequestFailed, float], None]


class Requests:
    """The pending requests of one link. ``send`` puts a message on the wire, ``emit`` an
    event in the connection's queue; ``heard`` says whether the board is heard (a new round
    only then); ``crc_mismatch`` whether its frames came in the other wire-CRC mode (with
    the CRC: True), which an unanswered request's error says; ``settled`` is told of every
    outcome."""

    def __init__(self, settings: Settings, stats: LinkStats, *,
                 send: Callable[[ParamSet | ParamGet, float], None],
                 emit: Callable[[Event], None], heard: Callable[[], bool],
                 crc_mismatch: Callable[[], bool | None], settled: Settled) -> None:
        self.settings = settings
        self.pending: dict[int, Request] = {}
        self._stats = stats
        self._send = send
        self._emit = emit
        self._heard = heard
        self._crc_mismatch = crc_mismatch
        self._settled = settled
        self._next_id = 1

    def start(self, param: Param, channel: int, value: int | float | None, now: float,
              rounds: int) -> int:
        """Send ``PS`` (``value``) or ``PG`` (``None``); returns the request's id, which its
        :class:`~fpgalink.events.RequestDone` or :class:`~fpgalink.events.RequestFailed`
        will carry."""
        request_id = self._next_id
        self._next_id += 1
        message: ParamSet | ParamGet = (ParamGet(param.id, channel) if value is None else
                                        ParamSet(param.id, channel, int(param.type), value))
        self.pending[request_id] = Request(request_id, param, channel, value, message, now,
                                           now + self.settings.request_timeout, rounds)
        self._send(message, now)
        return request_id

    def answer(self, msg: ParamAck | ParamNack, now: float) -> None:
        """Settle the pending requests for the parameter ``msg`` is about."""
        waiting = [r for r in self.pending.values()
                   if r.param.id == msg.param_id and r.channel == msg.channel]
        if not waiting:
            return
        if isinstance(msg, ParamNack):
            for request in waiting:
                self._settle(request, Answer.REFUSED, now, msg)
            return
        # The first request this echo confirms takes it; for every other, it is another value.
        for request in waiting:
            if request.answer_to(msg) is Answer.ECHO:
                self._settle(request, Answer.ECHO, now, msg)
                return
        for request in waiting:
            self._stats.echo_mismatches += 1
            request.last_answer = msg
            self._settle(request, Answer.OTHER_VALUE, now, msg)

    def expire(self, now: float) -> None:
        """Every request whose try went unanswered by ``now``."""
        for request in list(self.pending.values()):
            if now >= request.deadline and request.request_id in self.pending:
                self._settle(request, Answer.NO_ANSWER, now)

    def fail_all(self, error: FpgalinkError, now: float) -> None:
        """The link went down: every pending request fails with ``error``."""
        for request in list(self.pending.values()):
            if request.request_id in self.pending:
                self._settle(request, Answer.LINK_DOWN, now, error=error)

    def withdraw(self, request_id: int) -> Request | None:
        """Take a request out unsettled: never sent again, nothing said about it."""
        return self.pending.pop(request_id, None)

    def deadline(self) -> float | None:
        return min((r.deadline for r in self.pending.values()), default=None)

    def _settle(self, request: Request, answer: Answer, now: float,
                msg: ParamAck | ParamNack | None = None,
                error: FpgalinkError | None = None) -> None:
        outcome = REQUEST_TABLE[(answer, request.tries < self.settings.request_tries)]
        if outcome is Outcome.RESEND:
            request.tries += 1
            self._resend(request, now)
            return
        if outcome is Outcome.FAIL_TIMEOUT and request.rounds > 0 and self._heard():
            # Unanswered is not refused: asked again at once, so an answer that comes late
            # (a loaded machine, a slow line) confirms the request asked again.
            request.rounds -= 1
            request.round += 1
            request.tries = 1
            request.last_answer = None  # a round is judged by its own answers
            self._emit(RequestAskedAgain(request.request_id, request.param, request.channel,
                                         request.round))
            self._resend(request, now)
            return
        del self.pending[request.request_id]
        result: RequestDone | RequestFailed
        if outcome is Outcome.DONE:
            assert isinstance(msg, ParamAck)
            result = RequestDone(request.request_id, request.param, request.channel, msg.value,
                                 request.tries)
        else:
            result = RequestFailed(request.request_id, request.param, request.channel,
                                   error or self._error(request, outcome, msg), request.tries)
        self._emit(result)
        self._settled(request, outcome, result, now)

    def _resend(self, request: Request, now: float) -> None:
        request.deadline = now + self.settings.request_timeout
        self._stats.retries += 1
        self._send(request.message, now)

    def _error(self, request: Request, outcome: Outcome,
               msg: ParamAck | ParamNack | None) -> FpgalinkError:
        if outcome is Outcome.FAIL_REFUSED:
            assert isinstance(msg, ParamNack)
            return ParameterRefused(request.param.full_name(request.channel), msg.channel,
                                    msg.reason, msg.error)
        if outcome is Outcome.FAIL_MISMATCH:
            assert isinstance(msg, ParamAck)
            return ValueMismatch(request.what, request.tries, request.value, msg.value,
                                 msg.value_type)
        last = request.last_answer
        if last is not None:
            return ValueMismatch(request.what, request.tries, request.value, last.value,
                                 last.value_type)
        mismatch = self._crc_mismatch()
        if mismatch is not None:
            return WireCrcMismatchError(request.what, request.tries,
                                        self.settings.request_timeout, mismatch)
        return RequestTimeout(request.what, request.tries, self.settings.request_timeout)
