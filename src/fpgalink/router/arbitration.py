"""Who drives a board among its clients (sans-I/O): the first client to send a frame is the
**controller** until it leaves; every other client is an **observer**, whose frames are
refused. A refused ``PS`` or ``PG`` is answered ``PN`` 5 (another client controls the
board) in the form it came in, so the client's link fails the request at once with the
reason instead of resending it to no one. An observer's ``IQ`` (who is the board?) is the
one frame passed on: it changes nothing on the board, and its ``IA`` reaches every client
as every frame does (another client's link reads past an answer to a nonce it did not
send)."""

from __future__ import annotations

from types import UnionType
from typing import Generic, TypeVar

from fpgalink.protocol.catalogue import (
    IdentityQuery,
    NackReason,
    ParamGet,
    ParamNack,
    ParamSet,
)
from fpgalink.protocol.codec import encode_message, parse_content
from fpgalink.protocol.counter import SendCounter
from fpgalink.protocol.crc import append_crc, strip_crc
from fpgalink.router.stats import Client

__all__ = ["Arbitration", "identity_query", "parameter_request"]

C = TypeVar("C", bound=Client)


class Arbitration(Generic[C]):
    """One board's controller, if any, and the router's own answers to its observers."""

    def __init__(self) -> None:
        self.controller: C | None = None
        #: the router's own counter toward each client it answers (PN 5), by client number
        self._answer_counters: dict[int, SendCounter] = {}

    def take(self, client: C) -> bool:
        """``client`` sent a frame: it becomes the controller if nobody is. Whether it just
        did."""
        if self.controller is not None:
            return False
        self.controller = client
        client.stats.role = "controller"
        return True

    def controls(self, client: C) -> bool:
        return client is self.controller

    def release(self, client: C | None = None) -> bool:
        """``client`` left (``None``: the router stops): whether it was the controller,
        whom nobody replaces until the next client sends."""
        if self.controller is None or (client is not None and client is not self.controller):
            return False
        self.controller = None
        return True

    def refusal(self, client: C, content: bytes) -> bytes | None:
        """The content that answers ``client``'s refused frame: ``PN`` 5 for a ``PS`` or
        ``PG`` (with the wire CRC when it carried one); ``None`` for any other frame, which
        the protocol does not answer."""
        request, with_crc = parameter_request(content)
        if request is None:
            return None
        counter = self._answer_counters.setdefault(client.stats.client, SendCounter())
        answer = encode_message(ParamNack(request.param_id, request.channel,
                                          NackReason.NOT_CONTROLLER), counter.take())
        return append_crc(answer) if with_crc else answer


def parameter_request(content: bytes) -> tuple[ParamSet | ParamGet | None, bool]:
    """A ``PS`` or ``PG`` in ``content``, plain or with a good wire CRC (and which)."""
    message, with_crc = _message(content, ParamSet | ParamGet)
    return (message if isinstance(message, ParamSet | ParamGet) else None), with_crc


def identity_query(content: bytes) -> bool:
    """An ``IQ`` (docs/protocol.md §8) in ``content``, plain or with a good wire CRC."""
    return _message(content, IdentityQuery)[0] is not None


def _message(content: bytes, wanted: type | UnionType) -> tuple[object | None, bool]:
    """The message of type ``wanted`` in ``content`` as it is, or with a good wire CRC
    stripped (and whether it had one); ``None`` when it is neither."""
    message = parse_content(content)
    if isinstance(message, wanted):
        return message, False
    body = strip_crc(content)
    if body is not None:
        message = parse_content(body)
        if isinstance(message, wanted):
            return message, True
    return None, False
