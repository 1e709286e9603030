"""The optional wire CRC (an extension of SPEC §4, docs/protocol.md §7): declared once here,
generated for C by :mod:`fpgalink.codegen`, used by the host's connection and by both
emulated firmwares.

* **The check**: CRC-16/CCITT-FALSE — polynomial 0x1021, initial value 0xFFFF, no input or
  output reflection, no final XOR; ``crc("123456789") = 0x29B1``. It detects every error
  of 1, 2 or 3 bits, every odd number of bit errors and every burst up to 16 bits in a
  frame of up to 4,095 bytes.
* **Where**: once on, every *counted* message's content is ID + COUNTER + BODY + CRC, the CRC
  two bytes, little-endian (as every binary field), over everything before it. Direct
  commands (``RE``, ``RD``, ``E``) are matched by the logic on their exact content and stay
  as they are. Framing is unchanged: the CRC bytes are content, escaped like any other.
* **Switching**: off at power-up, so the seed's wire is byte-identical. The board parameter
  ``WireCrc`` (:data:`WIRE_CRC_PARAM`) switches it: the board validates the ``PS``, switches,
  and answers ``PA`` already in the new form. An older board does not know the parameter
  and answers ``PN`` 1: the host stays on the plain wire.
* **The handshake is understood in either form.** A ``PS`` or ``PG`` naming ``WireCrc`` is
  taken by the board plain or with a good CRC whatever its mode (a host that lost the ``PA``
  resends in its old form; a new host session finds a board left switched on), and while
  the host waits for the answer it takes frames in either form. Every other frame a side in
  CRC mode receives must pass the check: one that fails is dropped and counted, never
  delivered.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass
from typing import Any

from fpgalink.protocol.catalogue import ParamGet, ParamSet
from fpgalink.protocol.codec import parse_content
from fpgalink.protocol.framingerrors import CrcMismatch
from fpgalink.protocol.messages import DIRECT_BY_CONTENT, DirectCommand, Malformed
from fpgalink.protocol.params import lookup

__all__ = [
    "CRC16",
    "CRC_BYTES",
    "HANDSHAKE_WITH_CRC",
    "WIRE_CRC_PARAM",
    "BoardWireCrc",
    "CrcMismatch",
    "CrcSpec",
    "HostWireCrc",
    "append_crc",
    "carries_crc",
    "crc16",
    "handshake_request",
    "plain_counted",
    "strip_crc",
]

CRC_BYTES = 2  #: the CRC's size on the wire, after the body


@dataclass(frozen=True, slots=True)
class CrcSpec:
    """A CRC in the parameters of the usual catalogue of CRC algorithms (width, poly, init,
    refin, refout, xorout, check)."""

    name: str
    width: int
    poly: int
    init: int
    refin: bool
    refout: bool
    xorout: int
    check: int  #: the CRC of the nine ASCII bytes ``123456789``

    def compute(self, data: bytes) -> int:
        """Bit by bit, straight from the definition: the reference the table-driven code
        (here and in the generated C) is checked against."""
        top = 1 << (self.width - 1)
        mask = (1 << self.width) - 1
        crc = self.init
        for byte in data:
            if self.refin:
                byte = int(f"{byte:08b}"[::-1], 2)
            crc ^= byte << (self.width - 8)
            for _ in range(8):
                crc = ((crc << 1) ^ self.poly) & mask if crc & top else (crc << 1) & mask
        if self.refout:
            crc = int(f"{crc:0{self.width}b}"[::-1], 2)
        return crc ^ self.xorout

    def table(self) -> list[int]:
        """The 256-entry table of a byte-at-a-time, MSB-first implementation (no
        reflection), as the generated C uses."""
        if self.refin or self.refout:
            raise NotImplementedError("only a non-reflected CRC is tabulated")
        top = 1 << (self.width - 1)
        mask = (1 << self.width) - 1
        out = []
        for byte in range(256):
            crc = byte << (self.width - 8)
            for _ in range(8):
                crc = ((crc << 1) ^ self.poly) & mask if crc & top else (crc << 1) & mask
            out.append(crc)
        return out


#: The wire's CRC: the declaration both sides are generated from.
CRC16 = CrcSpec("CRC-16/CCITT-FALSE", width=16, poly=0x1021, init=0xFFFF, refin=False,
                refout=False, xorout=0x0000, check=0x29B1)

#: The board parameter that switches the CRC (the SPEC §5 table, extended in params.py).
WIRE_CRC_PARAM = lookup("WireCrc").id

_U16 = struct.Struct("<H")


def crc16(data: bytes | bytearray | memoryview) -> int:
    """:data:`CRC16` of ``data``. ``binascii.crc_hqx`` is this very CRC (MSB-first 0x1021,
    no final XOR) given the initial value, at C speed."""
    return binascii.crc_hqx(data, CRC16.init)


def append_crc(content: bytes) -> bytes:
    """``content`` with its CRC after it (little-endian)."""
    return content + _U16.pack(binascii.crc_hqx(content, 0xFFFF))


def strip_crc(content: bytes) -> bytes | None:
    """The content before a good CRC, or ``None`` when the last two bytes are not the CRC of
    what precedes them (or there are fewer than three bytes)."""
    if len(content) <= CRC_BYTES:
        return None
    body = content[:-CRC_BYTES]
    if binascii.crc_hqx(body, 0xFFFF) != _U16.unpack_from(content, len(body))[0]:
        return None
    return body


def plain_counted(content: bytes) -> bool:
    """Whether ``content`` is a counted message as it is (no CRC after it)."""
    return not isinstance(parse_content(content), Malformed | DirectCommand)


def carries_crc(content: bytes) -> bool:
    """Whether ``content`` is a counted message with a good CRC after it, which is no
    message without the CRC stripped: what a side whose CRC is off receives from one whose
    CRC is on."""
    body = strip_crc(content)
    return body is not None and plain_counted(body) and not plain_counted(content)


# The handshake's plain contents: "PS" or "PG", five digits, "{" LEN, then the parameter id
# first in the body. Only these lengths are looked at further.
_PS_LEN = 2 + 5 + 3 + 7
_PG_LEN = 2 + 5 + 3 + 2
_HANDSHAKE = {_PS_LEN: b"PS", _PG_LEN: b"PG"}
#: Content lengths at which a frame may be the handshake with a CRC after it.
HANDSHAKE_WITH_CRC = frozenset(n + CRC_BYTES for n in _HANDSHAKE)


def handshake_request(content: bytes) -> bool:
    """Whether plain ``content`` is a well-formed ``PS`` or ``PG`` naming ``WireCrc`` (any
    channel: a wrong one gets its ``PN`` as usual)."""
    msg_id = _HANDSHAKE.get(len(content))
    return (msg_id is not None and content[:2] == msg_id and content[2:7].isdigit()
            and content[7] == 0x7B and content[8] == len(content) - 10
            and content[-1] == 0x7D and content[9] == WIRE_CRC_PARAM)


class BoardWireCrc:
    """The board's side: what the firmware does with each received frame's content and with
    each counted message it sends."""

    __slots__ = ("failures", "on")

    def __init__(self) -> None:
        self.on = False
        self.failures = 0  #: frames dropped for a bad CRC

    def receive(self, content: bytes) -> bytes | None:
        """The content to parse, or ``None`` for a frame dropped (and counted)."""
        if self.on:
            body = strip_crc(content)
            if body is not None:
                return body
            if handshake_request(content):
                return content
            self.failures += 1
            return None
        if len(content) in HANDSHAKE_WITH_CRC:
            body = strip_crc(content)
            if body is not None and handshake_request(body):
                return body
        return content

    def send(self, content: bytes) -> bytes:
        return append_crc(content) if self.on else content


#: The requests that ask a parameter's value (a tuple, not a union a call would build anew:
#: :meth:`HostWireCrc.sent` runs for every counted message sent).
_ASKS_PARAM = (ParamSet, ParamGet)


class HostWireCrc:
    """The host's side (used by :class:`fpgalink.Connection`): the mode follows the board's
    ``PA`` for ``WireCrc``; while a ``PS``/``PG`` for it is unanswered, frames are taken in
    either form."""

    __slots__ = ("asking", "on")

    def __init__(self) -> None:
        self.on = False  #: counted messages sent carry the CRC; received ones must
        self.asking = False  #: a WireCrc request is out: frames taken in either form

    @property
    def checking(self) -> bool:
        """Received frames go through :meth:`filter`."""
        return self.on or self.asking

    def outgoing(self, content: bytes) -> bytes:
        return append_crc(content) if self.on else content

    def sent(self, message: Any) -> None:
        """Told of every counted message sent."""
        if isinstance(message, _ASKS_PARAM) and message.param_id == WIRE_CRC_PARAM:
            self.asking = True

    def answered(self, param_id: int, value: int | float | None) -> None:
        """A ``PA`` (``value``) or ``PN`` (``None``) about ``param_id`` arrived."""
        if param_id != WIRE_CRC_PARAM:
            return
        self.asking = False
        if value is not None:
            self.on = value == 1

    def filter(self, items: list[Any]) -> tuple[list[Any], int]:
        """Frames (``bytes``) with their CRC checked and removed (direct commands are never
        checked: the logic matches them on their exact content); a frame that fails becomes
        a :class:`CrcMismatch` (strict) or stays as it is (asking). Returns the items and how
        many frames failed."""
        out: list[Any] = []
        failed = 0
        strict = not self.asking
        for item in items:
            if type(item) is bytes and item not in DIRECT_BY_CONTENT:
                body = strip_crc(item)
                if body is not None:
                    item = body
                elif strict:
                    failed += 1
                    item = CrcMismatch(len(item), item)
            out.append(item)
        return out, failed
