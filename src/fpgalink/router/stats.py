"""A client as its board's route sees it (:class:`Client`), each client's exact accounting
(:class:`ClientStats`), and how a frame is counted by its message ID (:func:`message_id`)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["Client", "ClientStats", "message_id"]


@dataclass
class ClientStats:
    """One client's exact accounting."""

    client: int  #: the client's number on this board, from 1
    peer: str
    role: str = "observer"
    frames_to_client: int = 0  #: the board's frames delivered to it
    bytes_to_client: int = 0
    dropped_frames: int = 0  #: the board's frames not delivered: its buffer was full
    frames_to_board: int = 0  #: its frames passed to the board (as the controller)
    to_board_by_id: Counter[str] = field(default_factory=Counter)
    refused_frames: int = 0  #: its frames not passed on (an observer's writes)
    refused_by_id: Counter[str] = field(default_factory=Counter)
    #: its frames as the controller while the board's port was gone: not sent, nowhere to
    unsent_frames: int = 0
    #: its frames as the controller refused because BOARD_QUEUE_S of line time already
    #: waited for the board (it wrote faster than the line carries)
    line_full_frames: int = 0
    #: its frames still waiting for the line when an RD went ahead of them (its own, or the
    #: router's when it left): dropped, never sent
    overtaken_frames: int = 0
    noise_bytes: int = 0  #: bytes it sent that were not part of a whole frame
    connected: bool = True
    connected_s: float = 0.0  #: how long it was connected (once it has left), s


def message_id(content: bytes) -> str:
    """The frame's message ID as it is counted: the first two bytes (``E``, a heartbeat, is
    one letter and its counter)."""
    return content[:1].decode("ascii", "replace") if content[:1] == b"E" else \
        content[:2].decode("ascii", "replace")


class Client(Protocol):
    """What the route and the arbitration know of a client, over TCP or a pty: its
    accounting, what waits unread for it, and a way to hand it bytes."""

    stats: ClientStats

    def backlog(self) -> int | None:
        """Bytes handed to it and not yet taken; ``None`` when it cannot take any."""

    def send(self, wire: bytes) -> None:
        """Hand it ``wire`` (whole frames)."""
