"""The base of everything a :class:`~fpgalink.Connection` reports.

Received messages, framing errors, malformed content and the connection's own events
(counter gaps, liveness, request outcomes) all derive from :class:`Event`, so
``next_event() -> Event | None`` says what it returns and ``match`` statements can be
checked. Events are frozen and slotted: cheap to make at 1 kHz and safe to hand around.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Event"]


@dataclass(frozen=True, slots=True)
class Event:
    """Something the protocol reports. Subclasses carry the data."""
