"""SPEC §4 message layer: the wire IDs, direct commands, counted messages and their body
items.

``parse_content(content)`` (in :mod:`.catalogue`) turns one frame's content into a message or
a :class:`Malformed` event; it never raises. ``encode_counted`` is its inverse.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Final

from fpgalink.protocol.errors import LocalProtocolError
from fpgalink.protocol.event import Event

__all__ = [
    "COUNTER_MODULUS",
    "Alive",
    "Binary",
    "BodyItem",
    "CountedMessage",
    "DirectCommand",
    "Disable",
    "Enable",
    "Malformed",
    "MalformedReason",
    "MessageId",
    "Role",
    "Text",
    "encode_body",
    "encode_counted",
    "parse_body",
    "validate_id",
]

COUNTER_MODULUS: Final = 100_000  #: five decimal digits, 99999 wraps to 00000
SECTION_OPEN = 0x7B  #: ``{``
SECTION_CLOSE = 0x7D  #: ``}``
LEN_RESERVED = 255  #: a section length the spec keeps for later
MAX_SECTION = LEN_RESERVED - 1  #: the longest binary section DATA

_ID_BYTES = frozenset(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789")


class Role(Enum):
    """Which end of the cable: each message ID is sent by one of them."""

    HOST = "host"
    BOARD = "board"


class MessageId(bytes, Enum):
    """Every ID SPEC §4 defines. Members are the ID's bytes, so they compare and hash as
    ``b"PS"`` does."""

    RE = b"RE"  #: host → board, direct: enable; (re)starts the 300 ms watchdog
    RD = b"RD"  #: host → board, direct: disable at once
    E = b"E"  #: board → host, direct: alive, every 300 ms
    PS = b"PS"  #: host → board: set a parameter
    PG = b"PG"  #: host → board: read a parameter
    PA = b"PA"  #: board → host: the value now in force (answers PS and PG)
    PN = b"PN"  #: board → host: a parameter request refused, with a reason
    RV = b"RV"  #: host → board: controller references
    TM = b"TM"  #: board → host: telemetry, one per timer period
    #: host → board: which protocol, firmware and board are you? (optional: a seed board
    #: does not know it and answers nothing; :mod:`fpgalink.protocol.identity`)
    IQ = b"IQ"
    #: board → host: the answer to ``IQ``: the declaration hash, firmware version, serial
    IA = b"IA"

    @property
    def sender(self) -> Role:
        return _SENDERS[self]

    @property
    def direct(self) -> bool:
        """Recognised by the communication hardware by exact content; carries no counter."""
        return self in (MessageId.RE, MessageId.RD, MessageId.E)

    @classmethod
    def lookup(cls, text: str) -> MessageId | None:
        """The catalogued ID spelled ``text`` (any case), or ``None`` for any other ID."""
        try:
            return cls(text.strip().upper().encode("ascii", "replace"))
        except ValueError:
            return None


_SENDERS = {
    MessageId.RE: Role.HOST, MessageId.RD: Role.HOST, MessageId.PS: Role.HOST,
    MessageId.PG: Role.HOST, MessageId.RV: Role.HOST, MessageId.IQ: Role.HOST,
    MessageId.E: Role.BOARD, MessageId.PA: Role.BOARD, MessageId.PN: Role.BOARD,
    MessageId.TM: Role.BOARD, MessageId.IA: Role.BOARD,
}


# --- direct (hardware) commands: exact content, no counter ------------------------------------


@dataclass(frozen=True, slots=True)
class DirectCommand(Event):
    """A command the communication hardware recognises by exact content match."""

    @property
    def content(self) -> bytes:
        raise NotImplementedError

    @property
    def msg_id(self) -> MessageId:
        return MessageId(self.content)


@dataclass(frozen=True, slots=True)
class Enable(DirectCommand):
    """``RE``: host → board; enable, (re)start the 300 ms watchdog."""

    @property
    def content(self) -> bytes:
        return b"RE"


@dataclass(frozen=True, slots=True)
class Disable(DirectCommand):
    """``RD``: host → board; disable at once."""

    @property
    def content(self) -> bytes:
        return b"RD"


@dataclass(frozen=True, slots=True)
class Alive(DirectCommand):
    """``E``: board → host; the board is alive (every 300 ms)."""

    @property
    def content(self) -> bytes:
        return b"E"


ENABLE, DISABLE, ALIVE = Enable(), Disable(), Alive()
DIRECT_BY_CONTENT: dict[bytes, DirectCommand] = {b"RE": ENABLE, b"RD": DISABLE, b"E": ALIVE}


# --- counted messages -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Text:
    """A text item: any bytes but ``{`` and ``}``."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Binary:
    """A binary section ``{`` LEN DATA ``}``; DATA is 0..254 bytes of any value."""

    data: bytes


BodyItem = Text | Binary


@dataclass(frozen=True, slots=True)
class CountedMessage(Event):
    """A well-formed counted message whose ID is not in the catalogue (or not yet decoded)."""

    msg_id: str
    items: tuple[BodyItem, ...] = ()
    counter: int | None = None


class MalformedReason(Enum):
    EMPTY = "empty content"
    TOO_SHORT = "shorter than ID + counter"
    BAD_ID = "ID is not two characters from A-Z0-9"
    RESERVED_ID = "ID is reserved (RE, RD, E…)"
    BAD_COUNTER = "counter is not five decimal digits"
    STRAY_CLOSE = "'}' outside a binary section"
    TRUNCATED_SECTION = "binary section shorter than its LEN"
    UNCLOSED_SECTION = "binary section not closed where LEN says"
    RESERVED_LEN = "binary section LEN 255 is reserved"
    BAD_LAYOUT = "body does not match the catalogued layout"


@dataclass(frozen=True, slots=True)
class Malformed(Event):
    """A frame whose content is not a valid message. Reported, counted, never raised."""

    reason: MalformedReason
    content: bytes
    detail: str = ""


# --- encoding ---------------------------------------------------------------------------------


def validate_id(msg_id: str) -> bytes:
    raw = msg_id.encode("ascii", "replace")
    if len(raw) != 2 or not set(raw) <= _ID_BYTES:
        raise LocalProtocolError(f"message ID {msg_id!r} is not two characters from A-Z0-9")
    if raw in (b"RE", b"RD") or raw[:1] == b"E":
        raise LocalProtocolError(f"message ID {msg_id!r} is reserved")
    return raw


def encode_body(items: tuple[BodyItem, ...] | list[BodyItem]) -> bytes:
    out = bytearray()
    for item in items:
        if isinstance(item, Binary):
            if len(item.data) > MAX_SECTION:
                raise LocalProtocolError(
                    f"binary section of {len(item.data)} bytes; at most {MAX_SECTION} fit one "
                    "section"
                )
            out.append(SECTION_OPEN)
            out.append(len(item.data))
            out += item.data
            out.append(SECTION_CLOSE)
        else:
            if SECTION_OPEN in item.data or SECTION_CLOSE in item.data:
                raise LocalProtocolError("text items cannot contain '{' or '}'")
            out += item.data
    return bytes(out)


def encode_counted(msg_id: bytes, counter: int, body: bytes) -> bytes:
    """Content of a counted message: ID, five-digit counter, body."""
    return msg_id + b"%05d" % (counter % COUNTER_MODULUS) + body


# --- parsing ----------------------------------------------------------------------------------


def parse_header(content: bytes) -> tuple[bytes, int] | Malformed:
    if len(content) < 7:
        reason = MalformedReason.EMPTY if not content else MalformedReason.TOO_SHORT
        return Malformed(reason, content)
    raw_id = content[:2]
    if not set(raw_id) <= _ID_BYTES:
        return Malformed(MalformedReason.BAD_ID, content, repr(raw_id))
    if raw_id in (b"RE", b"RD") or raw_id[:1] == b"E":
        return Malformed(MalformedReason.RESERVED_ID, content, raw_id.decode())
    digits = content[2:7]
    if not (digits.isdigit()):
        return Malformed(MalformedReason.BAD_COUNTER, content, repr(digits))
    return raw_id, int(digits)


def parse_body(content: bytes, start: int = 7) -> tuple[BodyItem, ...] | Malformed:
    items: list[BodyItem] = []
    i, n = start, len(content)
    while i < n:
        open_at = content.find(b"{", i)
        close_at = content.find(b"}", i)
        if close_at != -1 and (open_at == -1 or close_at < open_at):
            return Malformed(MalformedReason.STRAY_CLOSE, content, f"at byte {close_at}")
        if open_at == -1:
            items.append(Text(content[i:]))
            break
        if open_at > i:
            items.append(Text(content[i:open_at]))
        if open_at + 1 >= n:
            return Malformed(MalformedReason.TRUNCATED_SECTION, content, "no LEN byte")
        length = content[open_at + 1]
        if length == LEN_RESERVED:
            return Malformed(MalformedReason.RESERVED_LEN, content, f"at byte {open_at + 1}")
        data_end = open_at + 2 + length
        if data_end >= n:
            return Malformed(
                MalformedReason.TRUNCATED_SECTION,
                content,
                f"LEN {length} at byte {open_at + 1}, {max(0, n - open_at - 2)} bytes follow",
            )
        if content[data_end] != SECTION_CLOSE:
            return Malformed(
                MalformedReason.UNCLOSED_SECTION,
                content,
                f"LEN {length} at byte {open_at + 1}; byte {data_end} is {content[data_end]:#04x}",
            )
        items.append(Binary(content[open_at + 2 : data_end]))
        i = data_end + 1
    return tuple(items)
