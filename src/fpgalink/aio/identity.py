"""``await read_identity(link)``: which protocol declaration, firmware and board a link's
board is (its ``IA`` answer), or ``None`` for a seed board that does not know ``IQ``
(:data:`~fpgalink.protocol.identity.SEED_PROTOCOL`). The decision is
:class:`~fpgalink.protocol.identity.IdentityProbe`'s: each ``IQ`` is followed by a ``PG`` of
``TsTimerPeriod`` (every board answers it, in order), so a board that did not answer is
told from a lost answer by what arrives, not by a timeout — only a board that answers
nothing at all fails, as any request to it would. A refusal (``PN``) of that ``PG`` is an
answer in order too; one from ``fpgalink-cli router`` (``PN`` 5: this client is an
observer) is not the board's, and comes through as the error it is.

A part of the link (it stands below :mod:`fpgalink.aio.link`, on what any asker offers:
:class:`Asker`); :meth:`fpgalink.aio.link.Link.identify` runs it and keeps the answer."""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Protocol

from fpgalink.errors import ParameterRefused
from fpgalink.protocol import Event, IdentityQuery, NackReason
from fpgalink.protocol.identity import BoardIdentity, IdentityProbe

__all__ = ["FENCE_PARAMETER", "Asker", "read_identity"]

#: The request that follows each ``IQ``: a board-wide parameter every board has.
FENCE_PARAMETER = "TsTimerPeriod"


class Asker(Protocol):
    """What asking takes of a link: send a message, read a parameter, hear every event."""

    def send(self, message: IdentityQuery) -> bytes: ...

    async def get_param(self, name: str, channel: None = None) -> int | float: ...

    def add_listener(self, listener: Callable[[Event], None]) -> Callable[[], None]: ...


async def read_identity(link: Asker, *, rounds: int = 3) -> BoardIdentity | None:
    """The board's identity, or ``None`` when ``rounds`` queries in a row went unanswered
    while the board answered the request after each (a seed board). The link's request
    errors (:class:`~fpgalink.errors.RequestTimeout`, :class:`~fpgalink.errors.BoardLost`,
    :class:`~fpgalink.errors.LinkClosed`) come through: a board answering nothing is not a
    seed board."""
    probe = IdentityProbe(random.getrandbits(32), rounds)

    def observe(event: Event) -> None:
        probe.observe(event)

    remove = link.add_listener(observe)
    try:
        while True:
            link.send(probe.query())
            try:
                await link.get_param(FENCE_PARAMETER)
            except ParameterRefused as exc:
                if exc.code == NackReason.NOT_CONTROLLER:
                    raise
            if probe.fence_answered():
                return probe.identity
    finally:
        remove()
