"""The sans-I/O connection as a codec for tests: what a message looks like on the wire, and
what a connection makes of bytes."""

from __future__ import annotations

from fpgalink import Connection, Role
from fpgalink.events import BoardFound
from fpgalink.protocol import CountedMessage, DirectCommand, Event, Message

__all__ = ["received", "sent"]


def sent(message: Message | CountedMessage | DirectCommand, conn: Connection | None = None,
         role: Role = Role.HOST, now: float = 0.0) -> bytes:
    """The bytes ``conn`` (a fresh connection of ``role`` by default) puts on the wire."""
    conn = conn if conn is not None else Connection(role=role, baud=None)
    conn.send(message, now)
    return conn.data_to_send()


def received(wire: bytes, conn: Connection | None = None, now: float = 0.0) -> list[Event]:
    """Every event ``conn`` (a fresh host connection by default) reports for ``wire``, but
    the liveness news (:class:`BoardFound`) that the first message brings."""
    conn = conn if conn is not None else Connection(baud=None)
    conn.receive_data(wire, now)
    return [e for e in conn.events() if not isinstance(e, BoardFound)]
