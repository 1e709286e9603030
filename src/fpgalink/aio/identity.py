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
:class:`Asker`): :class:`Identification` asks at open, when asked, and after each restart;
the link keeps it as ``link.identification``."""

from __future__ import annotations

import asyncio
import random
from collections.abc import Callable
from typing import Protocol

from fpgalink.aio.tasks import cancel_and_wait
from fpgalink.connection.identity import KnownIdentity
from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    ParameterRefused,
    RequestTimeout,
    WireCrcMismatchError,
)
from fpgalink.protocol import Event, IdentityQuery, NackReason, require_identity
from fpgalink.protocol.identity import BoardIdentity, IdentityProbe

__all__ = ["FENCE_PARAMETER", "RETRY_S", "Asker", "Identification", "Identifying",
           "read_identity"]

#: The request that follows each ``IQ``: the wire CRC's handshake (docs/protocol.md §7),
#: which a board answers whichever mode it and this host are in, so asking also settles the
#: link in the board's mode (a board left with its CRC on drops a plain ``PG`` of anything
#: else, and would look like one that answers nothing); a board without the parameter (the
#: seed's) answers ``PN`` 1, an answer all the same.
FENCE_PARAMETER = "WireCrc"
#: How often a restarted board's identity is asked again while it does not answer (s).
RETRY_S = 0.1


class Asker(Protocol):
    """What asking takes of a link: send a message, read a parameter, hear every event."""

    def send(self, message: IdentityQuery) -> bytes: ...

    async def get_param(self, name: str, channel: None = None) -> int | float: ...

    def add_listener(self, listener: Callable[[Event], None]) -> Callable[[], None]: ...


async def read_identity(link: Asker, *, rounds: int = 3, nonces: random.Random | None = None
                        ) -> BoardIdentity | None:
    """The board's identity, or ``None`` when ``rounds`` queries in a row went unanswered
    while the board answered the request after each (a seed board). The link's request
    errors (:class:`~fpgalink.errors.RequestTimeout`, :class:`~fpgalink.errors.BoardLost`,
    :class:`~fpgalink.errors.LinkClosed`) come through: a board answering nothing is not a
    seed board. The first nonce is drawn from ``nonces`` (default: the ``random`` module's),
    so that askers sharing a board (through the router) tell their answers apart."""
    probe = IdentityProbe((nonces or random).getrandbits(32), rounds)

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


class Identifying(Asker, Protocol):
    """What :class:`Identification` takes of its link, beside asking."""

    @property
    def board_alive(self) -> bool: ...

    async def close(self) -> None: ...


class Identification:
    """A link's part for who its board is (docs/protocol.md §8): asks (:meth:`identify`), at
    open when ``at_open``, and again after each restart once it has asked (a re-flash changes
    it). What it decides goes to ``settle`` (the link keeps it in its connection's
    :class:`~fpgalink.connection.identity.KnownIdentity`, ``known``, and says it as a
    :class:`~fpgalink.events.BoardIdentified`); a board of another declaration is refused
    with :class:`~fpgalink.protocol.IdentityMismatch` unless ``allow_mismatch``."""

    def __init__(self, link: Identifying, known: KnownIdentity,
                 settle: Callable[[BoardIdentity | None], None], *, where: str,
                 at_open: bool = False, allow_mismatch: bool = False) -> None:
        self._link, self._known, self._settle = link, known, settle
        self.where = where  #: how a refusal names the board
        self.at_open = at_open
        self.allow_mismatch = allow_mismatch
        self._asked = False
        self._again: asyncio.Task[None] | None = None
        #: where the queries' nonces come from: seeded from the system unless seeded again
        #: (a campaign's scenario seeds it, so that a scenario's run is the same wherever it
        #: runs: a nonce changes the bytes on the line, hence the timing)
        self.nonces = random.Random()

    @property
    def identity(self) -> BoardIdentity | None:
        """What the board said when last asked (``None``: a seed board, or not asked since
        it was found or restarted: :attr:`known` tells which)."""
        return self._known.identity

    @property
    def known(self) -> bool:
        return self._known.known

    async def identify(self, *, allow_mismatch: bool | None = None, rounds: int = 3
                       ) -> BoardIdentity | None:
        """Ask: one ``IQ`` and a ``PG`` a round, one round for a board that answers,
        ``rounds`` for a seed board (``None``). A board that answers nothing fails as any
        request to it does (``asking who the board is (…): no answer after N tries``)."""
        try:
            identity = await read_identity(self._link, rounds=rounds, nonces=self.nonces)
        except WireCrcMismatchError:
            raise  # its own advice: connect in the board's mode
        except RequestTimeout as exc:
            raise RequestTimeout(f"asking who the board is ({exc.what})", exc.tries,
                                 exc.timeout_s) from exc
        self._asked = True
        self._settle(identity)
        if not (self.allow_mismatch if allow_mismatch is None else allow_mismatch):
            require_identity(identity, self.where)
        return identity

    async def opened(self) -> None:
        """The link opened: ask, if asked to (a failure closes the link and comes through;
        an observer behind ``fpgalink-cli router`` may not read the board: it opens without
        knowing, and its own first request says why, as it did before it asked)."""
        if not self.at_open:
            return
        try:
            await self.identify()
        except ParameterRefused as exc:
            if exc.code != NackReason.NOT_CONTROLLER:
                await self._link.close()
                raise
        except BaseException:
            await self._link.close()
            raise

    def restarted(self) -> None:
        """The board restarted: asked again (by a task) if it was ever asked."""
        if self._asked and (self._again is None or self._again.done()):
            self._again = asyncio.ensure_future(self._ask_again())

    async def _ask_again(self) -> None:
        while not self._known.known:
            if not self._link.board_alive:
                await asyncio.sleep(RETRY_S)
                continue
            try:
                await self.identify(allow_mismatch=True)
            except (RequestTimeout, BoardLost):
                await asyncio.sleep(RETRY_S)
            except FpgalinkError:
                return  # closed, or refused (a router's observer): nothing more to ask

    async def close(self) -> None:
        if self._again is not None:
            await cancel_and_wait(self._again)  # its failure: nothing more is asked anyway
