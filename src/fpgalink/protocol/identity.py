"""Board identity: which protocol declaration, firmware and board a host is talking to.

"The host library broke when the firmware changed" is the complaint this answers. The
protocol is declared once (:mod:`.catalogue`, :mod:`.params`, :mod:`.framing`,
:mod:`.crc`); :func:`declarations_hash` is a 64-bit hash of every part of that
declaration — each message's layout, the parameter table, the framing bytes, the CRC,
the codes — and the board's C is generated from the same declaration with the same hash in
it (``FL_DECLARATIONS_HASH``, :mod:`fpgalink.codegen`). Equal hashes, equal wire.

A host asks with ``IQ`` (a nonce); a board that knows the pair answers ``IA`` with the
nonce, the hash its firmware was built from, the firmware's version and build, and its
serial. A seed board does not know ``IQ``: it counts it as an unknown message and answers
nothing, and keeps working — :data:`SEED_PROTOCOL`. To tell "no answer" from "answer
lost" without a timeout guess, the asker follows each ``IQ`` with a request every board
answers (a ``PG``): a board handles its frames in order and answers in order, so the
``PG``'s answer arriving with no ``IA`` before it means the board did not answer the
``IQ`` (:class:`IdentityProbe`; the asyncio call is :func:`fpgalink.aio.identity.read_identity`).

Sans-I/O: no clock, no I/O.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol.catalogue import (
    BODIES,
    IdentityAnswer,
    IdentityQuery,
    NackReason,
    TelemetryFlags,
)
from fpgalink.protocol.crc import CRC16, WIRE_CRC_PARAM
from fpgalink.protocol.errors import FpgalinkError
from fpgalink.protocol.framing import DEFAULT_FRAMING
from fpgalink.protocol.messages import COUNTER_MODULUS, MalformedReason, MessageId
from fpgalink.protocol.params import PARAMETERS

__all__ = [
    "NOT_ASKED",
    "SEED_PROTOCOL",
    "BoardIdentity",
    "IdentityMatch",
    "IdentityMismatch",
    "IdentityProbe",
    "compare_identity",
    "declarations_digest",
    "declarations_hash",
    "describe_identity",
    "identity_metadata",
    "require_identity",
]

#: What a board that does not answer ``IQ`` is shown as: it speaks the seed's protocol.
SEED_PROTOCOL = "seed protocol, identity unknown"
#: What a board that was not asked is shown as (a passive watcher sends nothing).
NOT_ASKED = "identity not asked"
#: A nonce is a u32.
NONCE_MODULUS = 1 << 32


@functools.cache
def declarations_digest() -> str:
    """The declaration's hash as 16 hex digits: every message's layout (``IQ``/``IA``
    included), ID and sender, the parameter table (id, name, scope, type, range, allowed
    values, power-up value, unit), the framing bytes and limit, the CRC and its parameter,
    the counter's modulus and every code (malformed reasons, ``PN`` codes, ``TM`` flags).
    Anything that changes the wire changes it."""
    parts = [
        repr(sorted((bytes(k), v) for k, v in BODIES.items())),
        repr([(p.id, p.name, int(p.scope), int(p.type), p.minimum, p.maximum,
               p.min_exclusive, p.allowed, p.default, p.unit) for p in PARAMETERS]),
        repr([(m.name, bytes(m), m.sender.value) for m in MessageId]),
        repr(DEFAULT_FRAMING), repr(CRC16), repr(COUNTER_MODULUS),
        repr([r.name for r in MalformedReason]), repr([(r.name, int(r)) for r in NackReason]),
        repr([(f.name, int(f)) for f in TelemetryFlags]), repr(WIRE_CRC_PARAM),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def declarations_hash() -> int:
    """:func:`declarations_digest` as the u64 ``IA`` carries."""
    return int(declarations_digest(), 16)


@dataclass(frozen=True, slots=True)
class BoardIdentity:
    """What a board said of itself in ``IA``."""

    declarations: int  #: the hash of the declaration its firmware was built from
    firmware: tuple[int, int, int]  #: major, minor, patch
    build: int  #: 0: not set
    serial: int

    @classmethod
    def from_answer(cls, answer: IdentityAnswer) -> BoardIdentity:
        return cls(answer.declarations,
                   (answer.firmware_major, answer.firmware_minor, answer.firmware_patch),
                   answer.build, answer.serial)

    @property
    def digest(self) -> str:
        """The declaration hash as :func:`declarations_digest` writes it."""
        return f"{self.declarations:016x}"

    @property
    def version(self) -> str:
        return ".".join(str(v) for v in self.firmware)

    def describe(self) -> str:
        """One line: ``protocol 3f1c…, firmware 1.1.0 (build 0), serial 0x…``."""
        build = f"build {self.build:08x}" if self.build else "build not set"
        return (f"protocol {self.digest}, firmware {self.version} ({build}), "
                f"serial 0x{self.serial:x}")


class IdentityMatch(Enum):
    """How a board's identity compares with this host's declaration."""

    MATCH = "match"  #: same declaration hash: the same wire
    MISMATCH = "mismatch"  #: built from another declaration
    UNKNOWN = "unknown"  #: no answer: a seed board (:data:`SEED_PROTOCOL`)


def compare_identity(identity: BoardIdentity | None, host: int | None = None
                     ) -> IdentityMatch:
    """``identity`` (``None``: the board did not answer) against ``host`` (default: this
    library's :func:`declarations_hash`)."""
    if identity is None:
        return IdentityMatch.UNKNOWN
    expected = declarations_hash() if host is None else host
    return IdentityMatch.MATCH if identity.declarations == expected else IdentityMatch.MISMATCH


class IdentityMismatch(FpgalinkError):
    """The board's firmware was built from another protocol declaration than this host's.
    The message is one line naming both hashes."""

    def __init__(self, where: str, board: int, host: int) -> None:
        self.board = board
        self.host = host
        prefix = f"{where}: " if where else ""
        super().__init__(f"{prefix}the board's protocol declaration is {board:016x}, this "
                         f"host's is {host:016x}: its firmware was built from another "
                         "protocol")


def require_identity(identity: BoardIdentity | None, where: str = "",
                     host: int | None = None) -> IdentityMatch:
    """:func:`compare_identity`, raising :class:`IdentityMismatch` on a mismatch (a seed
    board, which cannot say, passes as :attr:`IdentityMatch.UNKNOWN`)."""
    match = compare_identity(identity, host)
    if match is IdentityMatch.MISMATCH:
        assert identity is not None
        raise IdentityMismatch(where, identity.declarations,
                               declarations_hash() if host is None else host)
    return match


def describe_identity(identity: BoardIdentity | None, known: bool = True,
                      host: int | None = None) -> str:
    """One line for people: the board's :meth:`BoardIdentity.describe`, marked when its
    declaration is not this host's; :data:`SEED_PROTOCOL`; or :data:`NOT_ASKED` (``known``
    false: the board was not asked, or not since it restarted)."""
    if not known:
        return NOT_ASKED
    if identity is None:
        return SEED_PROTOCOL
    if compare_identity(identity, host) is IdentityMatch.MISMATCH:
        expected = declarations_hash() if host is None else host
        return f"{identity.describe()} — NOT this host's protocol {expected:016x}"
    return identity.describe()


def identity_metadata(boards: dict[str, tuple[BoardIdentity | None, bool]]
                      ) -> dict[str, str]:
    """What a recording's metadata says of who made it: this host's declaration hash
    (``host_protocol``) and, per board name, ``board.NAME.identity`` (one line:
    :func:`describe_identity`), ``.protocol`` (its hash, or empty), ``.firmware``,
    ``.build``, ``.serial`` and ``.match`` (``match``, ``mismatch``, ``unknown`` for a seed
    board, ``not asked``). ``boards``: name → (identity, known)."""
    out = {"host_protocol": declarations_digest()}
    for name, (identity, known) in boards.items():
        prefix = f"board.{name}."
        out[prefix + "identity"] = describe_identity(identity, known)
        out[prefix + "match"] = compare_identity(identity).value if known else "not asked"
        out[prefix + "protocol"] = identity.digest if identity is not None else ""
        out[prefix + "firmware"] = identity.version if identity is not None else ""
        out[prefix + "build"] = f"{identity.build:08x}" if identity is not None else ""
        out[prefix + "serial"] = f"0x{identity.serial:x}" if identity is not None else ""
    return out


class IdentityProbe:
    """The asking side of ``IQ``, sans-I/O. Per round: send :meth:`query`, then a request
    every board answers (the fence); feed every received message to :meth:`observe`; when
    the fence is answered, :meth:`fence_answered` says whether the round is decided. An
    ``IA`` with any nonce this probe sent counts (a late answer to an earlier round too)."""

    def __init__(self, first_nonce: int = 0, rounds: int = 3) -> None:
        if rounds < 1:
            raise ValueError(f"rounds must be at least 1, got {rounds}")
        self.rounds = rounds
        self._next = first_nonce % NONCE_MODULUS
        self._sent: set[int] = set()
        self.answer: IdentityAnswer | None = None
        self.rounds_done = 0

    def query(self) -> IdentityQuery:
        """The next round's ``IQ``."""
        nonce = self._next
        self._next = (nonce + 1) % NONCE_MODULUS
        self._sent.add(nonce)
        return IdentityQuery(nonce)

    def observe(self, message: object) -> bool:
        """A received message; True when it is the answer."""
        if (type(message) is IdentityAnswer and self.answer is None
                and message.nonce in self._sent):
            self.answer = message
            return True
        return False

    def fence_answered(self) -> bool:
        """The round's fence was answered: True when the probe is done (answered, or every
        round went unanswered: a seed board), False to ask again."""
        self.rounds_done += 1
        return self.answer is not None or self.rounds_done >= self.rounds

    @property
    def identity(self) -> BoardIdentity | None:
        """The board's identity, or ``None`` (:data:`SEED_PROTOCOL`) once done unanswered."""
        return None if self.answer is None else BoardIdentity.from_answer(self.answer)
