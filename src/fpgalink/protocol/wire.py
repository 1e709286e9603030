"""Wire-time arithmetic for an 8N1 UART (SPEC §2, §7), shared by ``fpgalink-cli budget``, the
connection's reference pacing and the emulator's timing report. Pure functions, no I/O.

One byte is 10 bit times (start, 8 data, stop), so at 1,000,000 baud a direction carries
100,000 bytes/s and a 1 ms period holds 100 wire bytes. The seed's "131,072 byte/s" and its
200-byte messages every 1 ms are arithmetic slips: a 200-byte frame needs at least 2.02 ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fpgalink.protocol.catalogue import content_length
from fpgalink.protocol.framing import DEFAULT_FRAMING, Framing
from fpgalink.protocol.messages import MessageId

__all__ = [
    "BITS_PER_BYTE",
    "MAX_BAUD",
    "MIN_BAUD",
    "TM_CONTENT_BYTES",
    "TM_TYPICAL_WIRE_BYTES",
    "BudgetReport",
    "DirectionLoad",
    "Flow",
    "byte_time_s",
    "bytes_per_second",
    "frame_wire_bytes",
    "largest_frame_wire_bytes",
    "plan",
    "wire_bytes",
    "worst_case_wire_bytes",
]

BITS_PER_BYTE = 10  #: 8N1: start bit, 8 data bits, stop bit
#: The line rates this project handles: a 100 MHz clock divides down to 20 MBd at 5 cycles a
#: bit; below 50 Bd nothing is a UART any more.
MIN_BAUD, MAX_BAUD = 50, 20_000_000
#: ID 2 + counter 5 + ``{`` + LEN + 42 data + ``}`` = 52
TM_CONTENT_BYTES = content_length(MessageId.TM)
#: START + 52 + STOP + about 1 escape on average for realistic values (the codec benchmark
#: measures 54.4 on random telemetry); a worst case is 2 × 52 + 2 = 106.
TM_TYPICAL_WIRE_BYTES = 55
#: the direct commands: ``SREP``, ``SRDP``, ``SEP``
RE_WIRE_BYTES = RD_WIRE_BYTES = 4
E_WIRE_BYTES = 3


def bytes_per_second(baud: int) -> float:
    """Bytes one direction of an 8N1 line carries per second."""
    if baud <= 0:
        raise ValueError(f"baud must be positive, got {baud}")
    return baud / BITS_PER_BYTE


def byte_time_s(baud: int) -> float:
    return 1.0 / bytes_per_second(baud)


def frame_wire_bytes(content_length: int, escapes: int = 0) -> int:
    """Wire bytes of a frame: START + content + ``escapes`` SKIP bytes + STOP."""
    if content_length < 0 or escapes < 0 or escapes > content_length:
        raise ValueError("need 0 <= escapes <= content_length")
    return content_length + escapes + 2


def worst_case_wire_bytes(content_length: int) -> int:
    """Every content byte a special one, each escaped."""
    return frame_wire_bytes(content_length, content_length)


def wire_bytes(content: bytes, framing: Framing = DEFAULT_FRAMING) -> int:
    """Exact wire bytes for this content."""
    specials = framing.specials
    return frame_wire_bytes(len(content), sum(content.count(bytes((b,))) for b in specials))


def largest_frame_wire_bytes(baud: int, period_s: float) -> int:
    """The longest frame (wire bytes) that fits one period in one direction."""
    return math.floor(bytes_per_second(baud) * period_s + 1e-9)


@dataclass(frozen=True, slots=True)
class Flow:
    """``per_period`` frames of ``content_length`` bytes each, in one direction."""

    name: str
    content_length: int
    per_period: float = 1.0
    to_board: bool = False  #: host → board (else board → host)
    escapes: int | None = None  #: typical escapes per frame; ``None``: none assumed

    @property
    def typical_wire(self) -> int:
        return frame_wire_bytes(self.content_length, self.escapes or 0)

    @property
    def worst_wire(self) -> int:
        return worst_case_wire_bytes(self.content_length)


@dataclass(slots=True)
class DirectionLoad:
    name: str
    capacity: float  #: wire bytes per period
    typical: float = 0.0  #: wire bytes per period, typical escaping
    worst: float = 0.0  #: wire bytes per period, every content byte escaped
    flows: list[Flow] = field(default_factory=list)

    @property
    def utilisation(self) -> float:
        return self.typical / self.capacity

    @property
    def worst_utilisation(self) -> float:
        return self.worst / self.capacity

    @property
    def fits(self) -> bool:
        return self.typical <= self.capacity

    @property
    def fits_worst_case(self) -> bool:
        return self.worst <= self.capacity

    @property
    def slack_bytes(self) -> float:
        return self.capacity - self.typical


@dataclass(slots=True)
class BudgetReport:
    baud: int
    period_s: float
    to_board: DirectionLoad
    to_host: DirectionLoad

    @property
    def fits(self) -> bool:
        return self.to_board.fits and self.to_host.fits

    @property
    def fits_worst_case(self) -> bool:
        return self.to_board.fits_worst_case and self.to_host.fits_worst_case

    def explain(self) -> list[str]:
        """Plain sentences, one per direction, plus the limits that matter."""
        period_ms = self.period_s * 1000
        lines = [
            f"At {self.baud:,} baud 8N1 one byte takes {byte_time_s(self.baud) * 1e6:g} µs; "
            f"a {period_ms:g} ms period holds {self.to_host.capacity:g} wire bytes per "
            f"direction, so the largest frame that fits one period is "
            f"{largest_frame_wire_bytes(self.baud, self.period_s)} wire bytes."
        ]
        for load in (self.to_board, self.to_host):
            verdict = "fits" if load.fits else "DOES NOT FIT"
            worst = "fits" if load.fits_worst_case else "does not fit"
            lines.append(
                f"{load.name}: {load.typical:g} wire bytes per period "
                f"({load.utilisation:.1%}) — {verdict}; worst-case escaping "
                f"{load.worst:g} ({load.worst_utilisation:.1%}) {worst}."
            )
            for flow in load.flows:
                need = flow.typical_wire * byte_time_s(self.baud)
                if need > self.period_s:
                    lines.append(
                        f"  {flow.name}: one {flow.content_length}-byte frame alone needs "
                        f"{need * 1000:g} ms of wire time, more than the {period_ms:g} ms period."
                    )
        return lines


def plan(baud: int, period_s: float, flows: list[Flow]) -> BudgetReport:
    """Add up the flows per direction against the line's capacity per period."""
    if period_s <= 0:
        raise ValueError(f"period must be positive, got {period_s}")
    capacity = bytes_per_second(baud) * period_s
    report = BudgetReport(
        baud, period_s, DirectionLoad("host→board", capacity), DirectionLoad("board→host", capacity)
    )
    for flow in flows:
        load = report.to_board if flow.to_board else report.to_host
        load.flows.append(flow)
        load.typical += flow.typical_wire * flow.per_period
        load.worst += flow.worst_wire * flow.per_period
    return report
