"""Fault injection beyond single bit flips: the ``--fault`` grammar, and a babbling host.

Line faults (bit errors, dropped, duplicated and noise bytes, stuck and cut windows) live in
:class:`~fpgaemu.uart.LineFaults`, one per direction. This module adds what is not a property
of one line: a host that babbles random bytes at full line rate (:class:`Babbler`, a board
peripheral), and the parser that turns ``--fault SPEC`` strings into a :class:`FaultSet`.

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

if TYPE_CHECKING:
    from fpgaemu.board import Board

__all__ = ["FAULT_HELP", "Babbler", "BoardFaults", "FaultSet", "parse_fault_spec", "parse_faults"]

#: The grammar, for ``--help`` and error messages (docs/reliability.md has the long form).
FAULT_HELP = """\
rx-* = host->board line, tx-* = board->host line; RATE is a probability in [0, 1],
START_S:DURATION_S are seconds of emulated time from power-up. Repeatable.
  rx-ber=RATE / tx-ber=RATE        each bit slot inverted with probability RATE
  rx-drop=RATE / tx-drop=RATE      each byte lost with probability RATE
  rx-dup=RATE / tx-dup=RATE        each byte sent twice with probability RATE
  rx-noise=RATE:LEN / tx-noise=..  LEN random bytes inserted before a byte, probability RATE
  rx-stuck=START_S:DURATION_S      line held low (break): bytes become framing errors
  tx-stuck=..., stuck=...          (stuck = both lines)
  rx-cut=START_S:DURATION_S        line cut: nothing sent in the window arrives
  tx-cut=..., disconnect=...       (disconnect = both lines)
  stall=START_S:DURATION_S         the host stalls: the board hears nothing (= rx-cut)
  babble=START_S:DURATION_S        the host sends random bytes at full line rate
  drop-frames=ID:N                 lose the first N host->board frames with message ID
  wheel-stuck=A|B[:START_S:DUR_S]  that channel's wheel is blocked (from power-up, for ever)
  restart=T_S (or restart@T_S)     the board power-cycles at T_S: registers, RAM, counter,
                                   clock and parameters back to power-up; the wheels go on
  tm-loss=START_S:DURATION_S       the board's TM frames are lost on the way to the host
                                   (E, PA, PN pass): a telemetry-only loss
  unplug=START_S:DURATION_S        fpgaemu serve: the board's pty or TCP connection goes
                                   away (the host's port is lost) and comes back"""

FAULT_KEYS = ("rx-ber", "tx-ber", "rx-drop", "tx-drop", "rx-dup", "tx-dup", "rx-noise",
              "tx-noise", "rx-stuck", "tx-stuck", "stuck", "rx-cut", "tx-cut", "disconnect",
              "stall", "babble", "drop-frames", "wheel-stuck", "restart", "tm-loss", "unplug")

#: The babbler refills the line this often; short enough that the line never goes idle
#: between refills for longer than a few bytes, long enough to cost one call per refill.
BABBLE_CHUNK_S = 0.001
#: Times in a spec are below this (a year of emulated time): anything later is a typo.
_LONGEST_S = 365 * 86400.0


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
    """``--fault`` specs → everything they ask for; ``ValueError`` naming the grammar."""
    wanted = FaultSet()
    for spec in specs:
        parse_fault_spec(spec, wanted)
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


def _rate(text: str) -> float:
    rate = float(text)
    if not 0.0 <= rate <= 1.0:
        raise ValueError
    return rate


def _window(text: str) -> tuple[int, int]:
    start_s, sep, duration_s = text.partition(":")
    if not sep:
        raise ValueError
    start, duration = float(start_s), float(duration_s)
    if not (0 <= start < _LONGEST_S and 0 <= duration < _LONGEST_S):  # NaN fails too
        raise ValueError
    first = seconds_to_cycles(start)
    return first, first + seconds_to_cycles(duration)


def parse_fault_spec(spec: str, into: FaultSet) -> None:
    """Add one ``KEY=VALUE`` spec to ``into``; ``ValueError`` naming the grammar if bad."""
    key, _, value = spec.partition("=")
    try:
        direction, _, kind = key.partition("-")
        lines = {"rx": [into.rx], "tx": [into.tx]}.get(direction)
        if key == "drop-frames":
            msg_id, _, count = value.partition(":")
            if len(msg_id) not in (1, 2) or not count.isdigit():
                raise ValueError
            into.drop_frames[msg_id.encode()] = int(count)
        elif key in ("stuck", "disconnect", "stall"):
            window = _window(value)
            targets = [into.rx] if key == "stall" else [into.rx, into.tx]
            for line in targets:
                (line.stuck if key == "stuck" else line.cut).append(window)
        elif key == "babble":
            start, end = _window(value)
            into.babble.append((start, end))
        elif key == "restart" or key.startswith("restart@"):
            at = key.partition("@")[2] if key != "restart" else value
            if key != "restart" and value:
                raise ValueError
            restart_s = float(at)
            if not 0 <= restart_s < _LONGEST_S:  # NaN fails too
                raise ValueError
            into.restarts.append(seconds_to_cycles(restart_s))
        elif key == "tm-loss":
            into.tm_loss.append(_window(value))
        elif key == "unplug":
            into.unplugs.append(_window(value))
        elif key == "wheel-stuck":
            channel, _, when = value.partition(":")
            if channel not in ("A", "B"):
                raise ValueError
            first, last = _window(when) if when else (0, None)
            into.stuck_wheels.append((1 if channel == "A" else 2, first, last))
        elif lines is not None and kind == "ber":
            for line in lines:
                line.bit_error_rate = _rate(value)
        elif lines is not None and kind == "drop":
            for line in lines:
                line.drop_rate = _rate(value)
        elif lines is not None and kind == "dup":
            for line in lines:
                line.dup_rate = _rate(value)
        elif lines is not None and kind == "noise":
            rate, _, length = value.partition(":")
            for line in lines:
                line.noise_rate = _rate(rate)
                line.noise_len = int(length) if length else 1
                if line.noise_len < 1:
                    raise ValueError
        elif lines is not None and kind in ("stuck", "cut"):
            for line in lines:
                (line.stuck if kind == "stuck" else line.cut).append(_window(value))
        else:
            raise ValueError
    except ValueError:
        raise ValueError(f"bad fault spec {spec!r}: expected KEY=VALUE with KEY one of "
                         f"{', '.join(FAULT_KEYS)} (the grammar: fpgaemu serve --help, "
                         "docs/reliability.md)") from None


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
