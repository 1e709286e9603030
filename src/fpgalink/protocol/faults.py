"""The ``--fault`` grammar: what a fault spec asks for, parsed and bounded, as data.

One grammar for both sides. The emulator (``fpgaemu serve --fault``, ``emu://…?fault=``)
builds its fault models from what :func:`parse_fault` returns; a campaign
(:mod:`fpgalink.campaign`) checks its files' ``faults`` with the same function before any
scenario runs. Pure parsing of text: no clock, no emulator. Times stay in seconds here (the
emulator turns them into its cycles).

Every number is bounded where it is parsed, and a spec outside a bound is one
:class:`FaultSpecError` line naming the bound: a rate is a probability, a time or a
duration at most a year of emulated time, a noise burst at most :data:`MAX_NOISE_LEN`
bytes (the emulator lays every noise byte out bit by bit, so the burst is what its memory
per line burst scales with), a frame count at most :data:`MAX_FRAME_COUNT`, a spec at most
:data:`MAX_SPEC_CHARS` characters, and a board at most :data:`MAX_FAULTS` specs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

from fpgalink.protocol.errors import FpgalinkError

__all__ = [
    "FAULT_HELP",
    "FAULT_KEYS",
    "LONGEST_S",
    "MAX_FAULTS",
    "MAX_FRAME_COUNT",
    "MAX_NOISE_LEN",
    "MAX_SPEC_CHARS",
    "Babble",
    "DropFrames",
    "Fault",
    "FaultSpecError",
    "LineNoise",
    "LineRate",
    "LineWindow",
    "Restart",
    "TelemetryLoss",
    "Unplug",
    "WheelStuck",
    "WindowFault",
    "parse_fault",
    "parse_faults",
]

#: Times and durations in a spec: at most a year of emulated time (later is a typo).
LONGEST_S = 365 * 86400.0
#: Random bytes in one noise burst. Each noise byte goes onto the emulated line bit by bit
#: (about 200 bytes of memory while its burst is laid out), so a host burst of 4 KiB at
#: rate 1 takes 17 times that at most.
MAX_NOISE_LEN = 16
#: ``drop-frames=ID:N``: N at most this.
MAX_FRAME_COUNT = 1_000_000_000
#: A spec longer than this is not one (and an error quoting it stays one short line).
MAX_SPEC_CHARS = 100
#: Specs for one board: each window is looked at for every burst on its line.
MAX_FAULTS = 100

FAULT_KEYS = ("rx-ber", "tx-ber", "rx-drop", "tx-drop", "rx-dup", "tx-dup", "rx-noise",
              "tx-noise", "rx-stuck", "tx-stuck", "stuck", "rx-cut", "tx-cut", "disconnect",
              "stall", "babble", "drop-frames", "wheel-stuck", "restart", "tm-loss", "unplug")

#: The grammar, for ``--help`` and error messages (docs/reliability.md has the long form).
FAULT_HELP = f"""\
rx-* = host->board line, tx-* = board->host line; RATE is a probability in [0, 1],
START_S:DURATION_S are seconds of emulated time from power-up (each at most a year),
LEN is 1..{MAX_NOISE_LEN}, N at most 1e9. Repeatable, at most {MAX_FAULTS} specs per board.
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

Line = Literal["rx", "tx"]
_RX: tuple[Line, ...] = ("rx",)
_TX: tuple[Line, ...] = ("tx",)
_BOTH: tuple[Line, ...] = ("rx", "tx")
#: A message ID as SPEC §4 writes them (two of ``[A-Z0-9]``), or its first letter (every ID
#: that starts with it).
_MESSAGE_ID = re.compile(r"[A-Z0-9]{1,2}")


class FaultSpecError(FpgalinkError, ValueError):
    """A fault spec the grammar does not take; the message is one line naming what is
    wrong (the bound, for a number outside one)."""


@dataclass(frozen=True, slots=True)
class Fault:
    """One parsed spec; ``text`` is the spec as written."""

    text: str


@dataclass(frozen=True, slots=True)
class LineRate(Fault):
    """``rx-ber``/``tx-ber`` (``kind`` ``ber``), ``-drop``, ``-dup``: each bit slot (or byte)
    with probability ``rate``."""

    lines: tuple[Line, ...]
    kind: Literal["ber", "drop", "dup"]
    rate: float


@dataclass(frozen=True, slots=True)
class LineNoise(Fault):
    """``rx-noise``/``tx-noise``: ``length`` random bytes before a byte, with probability
    ``rate``."""

    lines: tuple[Line, ...]
    rate: float
    length: int


@dataclass(frozen=True, slots=True)
class WindowFault(Fault):
    """A fault from ``start_s`` for ``duration_s`` seconds of emulated time."""

    start_s: float
    duration_s: float


@dataclass(frozen=True, slots=True)
class LineWindow(WindowFault):
    """``rx-stuck``, ``stuck`` … (``kind`` ``stuck``: held low) and ``rx-cut``,
    ``disconnect``, ``stall`` … (``cut``: nothing arrives) on ``lines``."""

    lines: tuple[Line, ...]
    kind: Literal["stuck", "cut"]


@dataclass(frozen=True, slots=True)
class Babble(WindowFault):
    """The host writes random bytes filling its line."""


@dataclass(frozen=True, slots=True)
class TelemetryLoss(WindowFault):
    """``tm-loss``: the board's ``TM`` frames are lost on the way to the host."""


@dataclass(frozen=True, slots=True)
class Unplug(WindowFault):
    """``unplug``: ``fpgaemu serve``'s pty or TCP connection goes away and comes back. Only
    a served board has one (not a board in the host's process, ``emu://``)."""


@dataclass(frozen=True, slots=True)
class DropFrames(Fault):
    """Lose the first ``count`` host→board frames whose content starts with
    ``message_id``."""

    message_id: str
    count: int


@dataclass(frozen=True, slots=True)
class WheelStuck(Fault):
    """That channel's wheel is blocked from ``start_s`` for ``duration_s`` (``None``: for
    ever)."""

    channel: Literal["A", "B"]
    start_s: float = 0.0
    duration_s: float | None = None


@dataclass(frozen=True, slots=True)
class Restart(Fault):
    """The board power-cycles at ``at_s``."""

    at_s: float


def parse_faults(specs: Iterable[str]) -> list[Fault]:
    """The specs for one board, each parsed; :class:`FaultSpecError` for the first bad one,
    or for more than :data:`MAX_FAULTS`."""
    parsed: list[Fault] = []
    for spec in specs:
        if len(parsed) == MAX_FAULTS:
            raise FaultSpecError(f"more than {MAX_FAULTS} fault specs for one board; at "
                                 f"most {MAX_FAULTS}")
        parsed.append(parse_fault(spec))
    return parsed


def parse_fault(spec: str) -> Fault:
    """One ``KEY=VALUE`` spec; :class:`FaultSpecError` naming the grammar, or the bound a
    number is outside."""
    if not isinstance(spec, str):
        raise FaultSpecError(f"a fault spec is text (KEY=VALUE), got {type(spec).__name__}")
    if len(spec) > MAX_SPEC_CHARS:
        raise FaultSpecError(f"bad fault spec {spec[:40]!r}…: longer than {MAX_SPEC_CHARS} "
                             "characters")
    key, _, value = spec.partition("=")
    try:
        return _parse(spec, key, value)
    except _Bound as bound:
        raise FaultSpecError(f"bad fault spec {spec!r}: {bound}") from None
    except ValueError:
        raise FaultSpecError(f"bad fault spec {spec!r}: expected KEY=VALUE with KEY one of "
                             f"{', '.join(FAULT_KEYS)} (the grammar: fpgaemu serve --help, "
                             "docs/reliability.md)") from None


class _Bound(ValueError):
    """A value of the right shape outside its bound: said as it is."""


def _parse(spec: str, key: str, value: str) -> Fault:
    direction, _, kind = key.partition("-")
    lines: tuple[Line, ...] | None = {"rx": _RX, "tx": _TX}.get(direction)
    if key == "drop-frames":
        message_id, sep, count = value.partition(":")
        if not sep or not _MESSAGE_ID.fullmatch(message_id):
            raise _Bound("write drop-frames=ID:N, ID a message ID (two of A-Z 0-9, or "
                         "the first of them)")
        return DropFrames(spec, message_id, _whole(count, "N", 0, MAX_FRAME_COUNT))
    if key in ("stuck", "disconnect", "stall"):
        start_s, duration_s = _window(value)
        return LineWindow(spec, start_s, duration_s, _RX if key == "stall" else _BOTH,
                          "stuck" if key == "stuck" else "cut")
    if key == "babble":
        return Babble(spec, *_window(value))
    if key == "tm-loss":
        return TelemetryLoss(spec, *_window(value))
    if key == "unplug":
        return Unplug(spec, *_window(value))
    if key == "restart" or key.startswith("restart@"):
        if key != "restart" and value:
            raise ValueError
        at = key.partition("@")[2] if key != "restart" else value
        return Restart(spec, _seconds(at, "T_S"))
    if key == "wheel-stuck":
        channel, _, when = value.partition(":")
        if channel not in ("A", "B"):
            raise _Bound("the wheel is A or B (wheel-stuck=A or wheel-stuck=A:START_S:DUR_S)")
        if not when:
            return WheelStuck(spec, "A" if channel == "A" else "B")
        start_s, duration_s = _window(when)
        return WheelStuck(spec, "A" if channel == "A" else "B", start_s, duration_s)
    if lines is None:
        raise ValueError
    if kind in ("ber", "drop", "dup"):
        return LineRate(spec, lines, "ber" if kind == "ber" else "drop" if kind == "drop"
                        else "dup", _rate(value))
    if kind == "noise":
        rate, sep, length = value.partition(":")
        return LineNoise(spec, lines, _rate(rate),
                         _whole(length, "LEN", 1, MAX_NOISE_LEN) if sep else 1)
    if kind in ("stuck", "cut"):
        start_s, duration_s = _window(value)
        return LineWindow(spec, start_s, duration_s, lines,
                          "stuck" if kind == "stuck" else "cut")
    raise ValueError


def _number(text: str, what: str, low: float, high: float, bound: str) -> float:
    """``text`` as a number in ``low..high``, else ``_Bound``: ``WHAT must be BOUND, got
    TEXT``."""
    try:
        number = float(text)
    except ValueError:
        number = math.nan
    if not low <= number <= high:  # NaN fails too
        raise _Bound(f"{what} must be {bound}, got {text!r}")
    return number


def _rate(text: str) -> float:
    return _number(text, "RATE", 0.0, 1.0, "a probability in [0, 1]")


def _seconds(text: str, what: str) -> float:
    return _number(text, what, 0.0, LONGEST_S, f"seconds from 0 to {LONGEST_S:,.0f} (a year)")


def _window(text: str) -> tuple[float, float]:
    start, sep, duration = text.partition(":")
    if not sep:
        raise _Bound("write START_S:DURATION_S (seconds of emulated time)")
    return _seconds(start, "START_S"), _seconds(duration, "DURATION_S")


def _whole(text: str, what: str, low: int, high: int) -> int:
    if not text.isascii() or not text.isdigit() or len(text) > len(str(high)) \
            or not low <= int(text) <= high:
        raise _Bound(f"{what} must be a whole number from {low:,} to {high:,}, got {text!r}")
    return int(text)
