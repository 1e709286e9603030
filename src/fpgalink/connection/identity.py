"""Who the board said it is (docs/protocol.md §8), as the connection keeps it: the asker (the
link's :class:`~fpgalink.aio.identity.Identification`, on the protocol's
:class:`~fpgalink.protocol.IdentityProbe`) decides, this part keeps the answer, says it
(:class:`~fpgalink.events.BoardIdentified`) and forgets it when the board restarts."""

from __future__ import annotations

from collections.abc import Callable

from fpgalink.events import BoardIdentified
from fpgalink.protocol import BoardIdentity, Event, compare_identity, declarations_hash

__all__ = ["KnownIdentity"]


class KnownIdentity:
    """``identity``: what the board said (``None``: a seed board, or not asked: ``known``
    tells which); ``known``: asked and decided since it was found or last restarted."""

    def __init__(self, emit: Callable[[Event], None]) -> None:
        self._emit = emit
        self.identity: BoardIdentity | None = None
        self.known = False

    def identified(self, identity: BoardIdentity | None, now: float) -> BoardIdentified:
        """The asker decided: kept, and said (the event is returned too)."""
        self.identity, self.known = identity, True
        event = BoardIdentified(identity, compare_identity(identity), declarations_hash(),
                                at=now)
        self._emit(event)
        return event

    def forget(self) -> None:
        """The board restarted: a re-flash changes who it is."""
        self.identity, self.known = None, False
