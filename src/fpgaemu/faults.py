"""Fault injection beyond single bit flips: the ``--fault`` grammar, and a babbling host.

Line faults (bit errors, dropped, duplicated and noise bytes, stuck and cut windows) live in
:class:`~fpgaemu.uart.LineFaults`, one per direction. This module adds what is not a property
of one line: a host that babbles random bytes at full line rate (:class:`Babbler`, a board
peripheral), and :func:`parse_faults`, which turns ``--fault SPEC`` strings into a
:class:`FaultSet`: the grammar itself (and its bounds) is :mod:`fpgalink.protocol.faults`,
shared with the host, which checks a campaign's faults with it before anything runs.

Everything random draws from ``Timeline.rng(name)``, so a seed fixes every fault exactly.
Times in specs are seconds of emulated time from power-up (for ``fpgaemu serve``, from when
the board started serving).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from fpgaemu.timeline import seconds_to_cycles
from fpgaemu.uart import LineFaults
from fpgalink.protocol.faults import (
    FAULT_HELP,
    FAULT_KEYS,
    Babble,
    DropFrames,
    Fault,
    FaultSpecError,
    LineNoise,
    LineRate,
    LineWindow,
    Restart,
    TelemetryLoss,
    Unplug,
    WheelStuck,
    WindowFault,
    parse_fault,
)
from fpgalink.protocol.faults import parse_faults as parse_fault_list

if TYPE_CHECKING:
    from fpgaemu.board import Board

__all__ = ["FAULT_HELP", "FAULT_KEYS", "Babbler", "BoardFaults", "FaultSet", "FaultSpecError",
           "parse_fault_spec", "parse_faults"]

#: The babbler refills the line this often; short enough that the line never goes idle
#: between refills for longer than a few bytes, long enough to cost one call per refill.
BABBLE_CHUNK_S = 0.001


@dataclass
class FaultSet:
    """Everything a list of ``--fault`` specs asks for."""

    rx: LineFaults = field(default_factory=LineFaults)
    tx: LineFaults = field(default_factory=LineFaults)
    drop_frames: dict[bytes, int] = field(default_factory=dict)
    #: ``(start, end)`` cycle windows of host babble
    babble: list[tuple[int, int]] = field(default_factory=list)
    #: ``(channel code, start, end)``: a blocked wheel (``end`` None: for ever)
    stuck_wheels: list[tuple[int, int, int | None]] = field(default_factory=list)
    #: cycles at which the board power-cycles
    restarts: list[int] = field(default_factory=list)
    #: ``(start, end)`` cycle windows in which the board's TM frames are lost
    tm_loss: list[tuple[int, int]] = field(default_factory=list)
    #: ``(start, end)`` cycle windows in which serve's connection to the host is gone
    unplugs: list[tuple[int, int]] = field(default_factory=list)

    def line(self, which: str) -> LineFaults | None:
        """The line faults for ``"rx"`` or ``"tx"``, or ``None`` when that line is clean
        (keeps the board on its fast path and its generators untouched)."""
        faults = self.rx if which == "rx" else self.tx
        return faults if faults != LineFaults() else None

    def board_faults(self) -> BoardFaults:
        """The faults that attach to a board rather than to one line."""
        return BoardFaults(drop_frames=dict(self.drop_frames), babble=list(self.babble),
                           stuck_wheels=list(self.stuck_wheels),
                           restarts=sorted(self.restarts), tm_loss=list(self.tm_loss),
                           unplugs=sorted(self.unplugs))


def parse_faults(specs: list[str]) -> FaultSet:
    """One board's ``--fault`` specs → everything they ask for; :class:`FaultSpecError` (a
    ``ValueError``) naming the grammar, or the bound a number is outside."""
    wanted = FaultSet()
    for fault in parse_fault_list(specs):
        _add(fault, wanted)
    return wanted


@dataclass
class BoardFaults:
    """Faults that are not a property of one line: frame drops applied at ``uartcommand``
    (as if the line had eaten the frame), a babbling host (``(start, end)`` cycles),
    blocked wheels, the board's power cycles, and its TM frames lost on the way out. A
    board peripheral, carried over a power cycle (the faults are the world's, not the
    board's): attached again, it re-wires what it had wired into the new blocks."""

    drop_frames: dict[bytes, int] = field(default_factory=dict)
    dropped: int = 0
    babble: list[tuple[int, int]] = field(default_factory=list)
    babbler: Babbler | None = None
    stuck_wheels: list[tuple[int, int, int | None]] = field(default_factory=list)
    restarts: list[int] = field(default_factory=list)
    tm_loss: list[tuple[int, int]] = field(default_factory=list)
    tm_lost: int = 0  #: TM frames the tm-loss windows lost
    #: ``(start, end)`` cycles: serve's endpoint drops the host's connection (a USB-UART
    #: pulled out, a TCP link gone) and offers it again; the board itself runs on
    unplugs: list[tuple[int, int]] = field(default_factory=list)
    _attached: bool = False

    def attach(self, board: Board) -> None:
        first = not self._attached
        self._attached = True
        if self.drop_frames:
            board.uartcommand.frame_filter = self._keep
        if self.tm_loss:
            board.uartsend.frame_filter = self._keep_outgoing
        if self.babble:
            self.babbler = Babbler(self.babble)
            self.babbler.attach(board)
        for channel, start, end in self.stuck_wheels:
            if first or end is None or end > board.now:
                self._block(board, channel, start, end)
        if first:  # the board keeps the pending ones through its own power cycles
            for cycle in self.restarts:
                board.schedule_power_cycle(max(cycle, board.now))

    def _keep_outgoing(self, content: bytes, cycle: int) -> bool:
        if content[:2] == b"TM" and any(s <= cycle < e for s, e in self.tm_loss):
            self.tm_lost += 1
            return False
        return True

    @staticmethod
    def _block(board: Board, channel: int, start: int, end: int | None) -> None:
        motors: Any = board.peripherals.get("motors")
        if motors is None:
            raise ValueError("wheel-stuck needs the board's motors (attach them first)")

        def stall(on: bool) -> Callable[[int], None]:
            def apply(cycle: int) -> None:
                motors.advance_to(cycle)  # the wheel turns freely up to this moment
                motors.wheels[channel].stall(on)
            return apply

        if start <= board.now:
            stall(True)(board.now)
        else:
            board.schedule(start, stall(True))
        if end is not None:
            board.schedule(max(end, board.now), stall(False))

    def _keep(self, content: bytes, cycle: int) -> bool:
        for msg_id, left in self.drop_frames.items():
            if left > 0 and content.startswith(msg_id):
                self.drop_frames[msg_id] = left - 1
                self.dropped += 1
                return False
        return True


def parse_fault_spec(spec: str, into: FaultSet) -> None:
    """Add one ``KEY=VALUE`` spec to ``into``; :class:`FaultSpecError` (a ``ValueError``)
    naming the grammar, or the bound a number is outside, if bad."""
    _add(parse_fault(spec), into)


def _cycles(fault: WindowFault) -> tuple[int, int]:
    first = seconds_to_cycles(fault.start_s)
    return first, first + seconds_to_cycles(fault.duration_s)


def _lines(into: FaultSet, which: tuple[str, ...]) -> list[LineFaults]:
    return [into.rx if line == "rx" else into.tx for line in which]


def _add(fault: Fault, into: FaultSet) -> None:
    if isinstance(fault, LineRate):
        for line in _lines(into, fault.lines):
            setattr(line, _RATES[fault.kind], fault.rate)
    elif isinstance(fault, LineNoise):
        for line in _lines(into, fault.lines):
            line.noise_rate, line.noise_len = fault.rate, fault.length
    elif isinstance(fault, LineWindow):
        for line in _lines(into, fault.lines):
            (line.stuck if fault.kind == "stuck" else line.cut).append(_cycles(fault))
    elif isinstance(fault, Babble):
        into.babble.append(_cycles(fault))
    elif isinstance(fault, TelemetryLoss):
        into.tm_loss.append(_cycles(fault))
    elif isinstance(fault, Unplug):
        into.unplugs.append(_cycles(fault))
    elif isinstance(fault, DropFrames):
        into.drop_frames[fault.message_id.encode()] = fault.count
    elif isinstance(fault, Restart):
        into.restarts.append(seconds_to_cycles(fault.at_s))
    elif isinstance(fault, WheelStuck):
        first = seconds_to_cycles(fault.start_s)
        last = None if fault.duration_s is None else first + seconds_to_cycles(
            fault.duration_s)
        into.stuck_wheels.append((1 if fault.channel == "A" else 2, first, last))
    else:  # a kind the grammar gained and this model not yet
        raise FaultSpecError(f"fault spec {fault.text!r}: not modelled by the emulator")


#: ``LineRate.kind`` → the :class:`~fpgaemu.uart.LineFaults` field it sets
_RATES = {"ber": "bit_error_rate", "drop": "drop_rate", "dup": "dup_rate"}


class Babbler:
    """A babbling host: from each window's start to its end, random bytes fill every idle
    moment of the host→board line (full line rate). The host's real bytes still get onto
    the line, queued between refills, as they would from a host whose driver interleaves
    its writes with a runaway writer. Windows are ``(start, end)`` cycles."""

    def __init__(self, windows: list[tuple[int, int]]) -> None:
        self.windows = sorted(windows)
        self.bytes_sent = 0
        self._board: Board | None = None

    def attach(self, board: Board) -> None:
        self._board = board
        self._rng = board.timeline.rng("babble")
        self._chunk = seconds_to_cycles(BABBLE_CHUNK_S)
        for start, end in self.windows:
            if end > start:
                self._schedule(max(start, board.now), end)

    def _schedule(self, cycle: int, end: int) -> None:
        assert self._board is not None
        self._board.schedule(cycle, lambda at: self._refill(at, end))

    def _refill(self, cycle: int, end: int) -> None:
        board = self._board
        assert board is not None
        line = board.uartread
        until = min(end, cycle + self._chunk)
        # Fill the line from where it next goes idle up to the next refill, no further,
        # so the babble never builds a backlog ahead of the host's own bytes.
        count = (until - max(cycle, line.line_free_at)) // line.cycles_per_byte
        if count > 0:
            data = self._rng.integers(0, 256, count, "uint8").tobytes()
            line.transmit(data, cycle)
            self.bytes_sent += count
        if until < end:
            self._schedule(until, end)
