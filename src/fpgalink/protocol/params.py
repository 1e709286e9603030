"""The parameter table of SPEC §5 as data, with lookup and host-side validation.

Everything the board checks (unknown id, bad channel, wrong type, out of range) is checked
here first, so a mistake becomes a clear :class:`~fpgalink.errors.ParameterError` before a
byte is sent. The board still checks, as it must for any host.

The table also holds each parameter's power-up value (``default``): the emulated firmware
starts from it, and ``docs/emulator.md`` explains each choice.
"""

from __future__ import annotations

import difflib
import math
import numbers
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal
from enum import IntEnum

from fpgalink.protocol.errors import ParameterError, UnknownParameter

__all__ = [
    "BOARD",
    "CHANNEL_A",
    "CHANNEL_B",
    "FLOAT32_MAX",
    "PARAMETERS",
    "Param",
    "ParamType",
    "Scope",
    "channel_code",
    "channel_name",
    "float32",
    "iter_addresses",
    "lookup",
    "resolve",
]

BOARD, CHANNEL_A, CHANNEL_B = 0, 1, 2


class Scope(IntEnum):
    BOARD = 0  #: one value for the board; addressed with channel 0
    CHANNEL = 1  #: one value per channel A (1) and B (2)


class ParamType(IntEnum):
    INT = 1  #: value travels as int32
    FLOAT = 2  #: value travels as IEEE-754 float32


_F32 = struct.Struct("<f")
#: The largest finite float32, (2 − 2⁻²³)·2¹²⁷: the bound for any float the wire carries.
FLOAT32_MAX = 3.4028234663852886e38


def float32(value: float) -> float:
    """``value`` as the board will store it (rounded to float32). Raises ``OverflowError``
    for a finite value too large for a float32."""
    return float(_F32.unpack(_F32.pack(value))[0])


def real_number(value: object) -> int | float | None:
    """Any real number (``int``, ``float``, numpy scalars, ``Fraction``, ``Decimal`` …) as an
    ``int`` when it is integral by type, else a ``float``; ``None`` for anything else
    (``bool`` included: ``True`` is not a parameter value)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real | Decimal):
        return None
    if isinstance(value, numbers.Integral):
        return int(value)
    return float(value)


@dataclass(frozen=True, slots=True)
class Param:
    id: int
    name: str  #: without the channel suffix: ``Kp_Wheel_Pid``
    scope: Scope
    type: ParamType
    minimum: float
    maximum: float
    min_exclusive: bool = False
    allowed: tuple[int, ...] | None = None  #: a discrete set instead of a range
    unit: str = ""
    description: str = ""
    #: the power-up value (the emulated firmware's; see docs/emulator.md)
    default: int | float = 0

    @property
    def range_text(self) -> str:
        if self.allowed is not None:
            return " or ".join(str(v) for v in self.allowed)
        lo = "" if self.minimum == -math.inf else f"{self.minimum:g}"
        hi = "" if self.maximum == math.inf else f"{self.maximum:g}"
        if hi and lo:
            return f"{lo}..{hi}"
        if lo:
            return f"{'>' if self.min_exclusive else '≥'} {lo}"
        return f"≤ {hi}"

    def full_name(self, channel: int) -> str:
        """The seed's name: ``Kp_Wheel_PidA`` for a channel parameter, plain for a board one."""
        if self.scope is Scope.BOARD:
            return self.name
        return self.name + channel_name(channel)

    def in_range(self, value: float) -> bool:
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.allowed is not None:
            return value in self.allowed
        if value > self.maximum:
            return False
        if self.min_exclusive:
            return value > self.minimum
        return value >= self.minimum

    def check_channel(self, channel: int) -> bool:
        if self.scope is Scope.BOARD:
            return channel == BOARD
        return channel in (CHANNEL_A, CHANNEL_B)

    def coerce(self, value: object) -> int | float:
        """The value as it will travel, or :class:`ParameterError` naming the valid range.
        Any real number type is accepted; a float parameter's value is rounded to float32
        (what the board stores), and one that does not fit a float32 is out of range."""
        number = real_number(value)
        if number is None:
            raise ParameterError(
                f"{self.name}: expected a number ({self.type.name.lower()}, {self.range_text}), "
                f"got {value!r}"
            )
        if self.type is ParamType.INT:
            if isinstance(number, float):
                if not number.is_integer():
                    raise ParameterError(
                        f"{self.name} is an integer parameter ({self.range_text}); got {value!r}"
                    )
                number = int(number)
            if not self.in_range(number):
                raise ParameterError(f"{self.name} must be {self.range_text}; got {number}")
            return number
        number = float(number)
        try:
            stored = float32(number) if math.isfinite(number) else number
        except OverflowError:
            stored = math.inf
        if not self.in_range(stored) or not self.in_range(number):
            raise ParameterError(
                f"{self.name} must be a float {self.range_text} (and fit a float32); "
                f"got {value!r}"
            )
        return stored


_INF = math.inf
PARAMETERS: tuple[Param, ...] = (
    Param(1, "TsTimerPeriod", Scope.BOARD, ParamType.INT, 1, 1000, unit="ms",
          description="controller and telemetry period", default=1),
    Param(2, "GetDataPeriodical", Scope.BOARD, ParamType.INT, 0, 1,
          description="1: send TM telemetry every period", default=0),
    Param(3, "TorqueCoef", Scope.CHANNEL, ParamType.FLOAT, 0, _INF, min_exclusive=True,
          unit="N·m/A", description="motor current to torque", default=0.2),
    Param(4, "ActiveController", Scope.CHANNEL, ParamType.INT, 0, 3,
          description="0 SW speed PID, 1 HW speed PID, 2 SW current PID, 3 HW current PID",
          default=0),
    Param(5, "MaxControlSignal", Scope.CHANNEL, ParamType.INT, 0, 32760,
          description="PWM clamp; 32760 = 100 %", default=32760),
    Param(6, "IncSenzRes", Scope.CHANNEL, ParamType.INT, 0, 65535, unit="pulses/turn",
          description="encoder pulses per wheel turn; counts per turn = 10 × this",
          default=500),
    Param(7, "IncSenzCountDirection", Scope.CHANNEL, ParamType.INT, -1, 1, allowed=(-1, 1),
          description="encoder counting direction", default=1),
    # The speed PID's power-up tuning: the integral time cancels the emulated high-gear
    # plant's dominant 0.24 s pole, Kp puts the crossover near 6 rad/s (docs/emulator.md).
    Param(8, "Kp_Wheel_Pid", Scope.CHANNEL, ParamType.FLOAT, 0, _INF,
          unit="PWM/(deg/s)", description="speed PID proportional gain", default=520.0),
    Param(9, "Ti_Wheel_Pid", Scope.CHANNEL, ParamType.FLOAT, 0, _INF, min_exclusive=True,
          unit="s", description="speed PID integral time", default=0.24),
    Param(10, "Td_Wheel_Pid", Scope.CHANNEL, ParamType.FLOAT, 0, _INF,
          unit="s", description="speed PID derivative time", default=0.0),
    # Not in the seed: the optional wire CRC (protocol/crc.py, docs/protocol.md §7). Off at
    # power-up, so the seed's wire is unchanged; a board without it answers PN 1.
    Param(11, "WireCrc", Scope.BOARD, ParamType.INT, 0, 1,
          description="1: every counted message carries a CRC-16/CCITT-FALSE", default=0),
)

_BY_ID = {p.id: p for p in PARAMETERS}
_BY_NAME = {p.name.lower(): p for p in PARAMETERS}


def channel_code(channel: int | str | None) -> int | None:
    """``'A'``/``'a'``/``1`` → 1, ``'B'``/``2`` → 2, ``0``/``'board'`` → 0, ``None`` → None."""
    if channel is None:
        return None
    if isinstance(channel, str):
        key = channel.strip().upper()
        codes = {"A": CHANNEL_A, "B": CHANNEL_B, "0": BOARD, "BOARD": BOARD, "1": 1, "2": 2}
        if key not in codes:
            raise ParameterError(f"unknown channel {channel!r}: use A or B")
        return codes[key]
    if isinstance(channel, bool) or channel not in (BOARD, CHANNEL_A, CHANNEL_B):
        raise ParameterError(f"unknown channel {channel!r}: use A (1) or B (2)")
    return int(channel)


def channel_name(channel: int) -> str:
    return {CHANNEL_A: "A", CHANNEL_B: "B"}.get(channel, "")


def lookup(name_or_id: str | int) -> Param:
    """A parameter by id or by name, case-insensitive, with or without the A/B suffix."""
    return _find(name_or_id)[0]


def _find(name: str | int) -> tuple[Param, int | None]:
    """The parameter and the channel its name's suffix names, if any."""
    if isinstance(name, int) and not isinstance(name, bool):
        try:
            return _BY_ID[name], None
        except KeyError:
            raise UnknownParameter(f"no parameter has id {name}") from None
    key = str(name).strip().lower()
    if key in _BY_NAME:
        return _BY_NAME[key], None
    if key[-1:] in ("a", "b") and key[:-1] in _BY_NAME:
        candidate = _BY_NAME[key[:-1]]
        if candidate.scope is Scope.CHANNEL:
            return candidate, CHANNEL_A if key[-1] == "a" else CHANNEL_B
    known = ", ".join(p.name + ("A/B" if p.scope is Scope.CHANNEL else "")
                      for p in PARAMETERS)
    guesses = suggest(str(name))
    guess = f"; did you mean {' or '.join(guesses)}?" if guesses else ""
    raise UnknownParameter(f"unknown parameter {name!r}{guess} (known: {known})")


def _spelling(name: str) -> str:
    """A name as people misspell it the least: no case, no underscores or dashes."""
    return "".join(c for c in name.lower() if c.isalnum())


def suggest(name: str, limit: int = 2) -> list[str]:
    """The parameter names (channel parameters with their A/B suffix) closest to ``name``:
    ``KpWheelPidA`` → ``Kp_Wheel_PidA``. Case, underscores and dashes do not count."""
    names = [p.name for p in PARAMETERS]
    names += [p.name + c for p in PARAMETERS if p.scope is Scope.CHANNEL for c in "AB"]
    by_spelling: dict[str, str] = {}
    for full in names:
        by_spelling.setdefault(_spelling(full), full)
    wanted = _spelling(name)
    if wanted in by_spelling:
        return [by_spelling[wanted]]
    close = difflib.get_close_matches(wanted, list(by_spelling), n=3 * limit, cutoff=0.75)
    found: dict[str, str] = {}  # one guess per parameter, the closest spelling of it
    for spelling in close:
        full = by_spelling[spelling]
        found.setdefault(_find(full)[0].name, full)
    return list(found.values())[:limit]


def resolve(name: str | int, channel: int | str | None = None) -> tuple[Param, int]:
    """``(param, channel code)`` for a name such as ``Kp_Wheel_Pid`` with ``channel='A'``, or
    the seed's suffixed form ``Kp_Wheel_PidA``. A channel parameter needs a channel; a board
    parameter takes none (or 0)."""
    code = channel_code(channel)
    param, suffix = _find(name)
    if suffix is not None:
        if code is not None and code != suffix:
            raise ParameterError(
                f"{name}: the name says channel {channel_name(suffix)} but channel "
                f"{channel_name(code) or code} was given"
            )
        code = suffix
    if param.scope is Scope.BOARD:
        if code not in (None, BOARD):
            raise ParameterError(f"{param.name} is board-wide; it takes no channel")
        return param, BOARD
    if code not in (CHANNEL_A, CHANNEL_B):
        raise ParameterError(f"{param.name} is per channel: give channel A or B")
    assert code is not None
    return param, code


def iter_addresses() -> Iterator[tuple[Param, int]]:
    """Every (parameter, channel) the board holds, in table order."""
    for p in PARAMETERS:
        if p.scope is Scope.BOARD:
            yield p, BOARD
        else:
            yield p, CHANNEL_A
            yield p, CHANNEL_B
