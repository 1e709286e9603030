"""Telemetry as flat rows — one schema shared by ``monitor --format csv|jsonl``, ``record``
(MCAP and CSV) and ``step`` — plus the board clock and the streaming switch."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import Any

from fpgalink.aio.link import Link
from fpgalink.catalogue import Telemetry
from fpgalink.errors import FpgalinkError

__all__ = [
    "CHANNEL_FIELDS",
    "TELEMETRY_FIELDS",
    "BoardClock",
    "Streaming",
    "telemetry_row",
    "telemetry_schema",
]

#: Per channel, in TM wire order; ``ref`` is the reference the board is following.
CHANNEL_FIELDS = ("position", "speed", "current", "pwm", "ref", "flags")
TELEMETRY_FIELDS = (
    "timestamp", "t_us", "counter",
    *(f"{ch}_{name}" for ch in ("a", "b") for name in CHANNEL_FIELDS),
)
_UNITS = {"position": "encoder counts", "speed": "deg/s", "current": "A",
          "pwm": "duty, ±32760 = ±100 %", "ref": "reference (deg/s or N·m)",
          "flags": "bit0 enable, bit1 end-stop, bit2 saturated"}

_WRAP = 1 << 32  #: t_us is a u32 of microseconds: it wraps every ~71.6 minutes


@dataclass
class BoardClock:
    """Board time (``t_us``, wrapping) → host epoch seconds.

    Anchored to the host clock at the first sample, then advanced by board time, so samples
    that arrive in one burst still get their true spacing. A backward jump of less than half
    the counter is a board restart (re-anchor); more is a wrap."""

    anchor: float | None = None
    _origin_us: int = 0
    _last_us: int = 0
    _base_us: int = 0

    def seconds(self, t_us: int, host_now: float | None = None) -> float:
        if self.anchor is None or (t_us < self._last_us and self._last_us - t_us < _WRAP // 2):
            self.anchor = time.time() if host_now is None else host_now
            self._origin_us, self._base_us = t_us, 0
        elif t_us < self._last_us:
            self._base_us += _WRAP
        self._last_us = t_us
        return self.anchor + (self._base_us + t_us - self._origin_us) / 1e6


def telemetry_row(sample: Telemetry, timestamp: float) -> dict[str, Any]:
    row: dict[str, Any] = {"timestamp": timestamp, "t_us": sample.t_us,
                           "counter": sample.counter}
    for prefix, channel in (("a", sample.a), ("b", sample.b)):
        for name, value in zip(CHANNEL_FIELDS, channel, strict=True):
            row[f"{prefix}_{name}"] = value
    return row


def telemetry_schema() -> dict[str, Any]:
    """JSON Schema of a row: flat numeric fields, so Foxglove and PlotJuggler plot
    ``/board/<name>/telemetry.a_speed`` without configuration."""
    properties: dict[str, Any] = {
        "timestamp": {"type": "number", "description": "host epoch time of the sample, s"},
        "t_us": {"type": "integer", "description": "board time, µs (wraps at 2^32)"},
        "counter": {"type": "integer", "description": "the TM message counter"},
    }
    for prefix in ("a", "b"):
        for name in CHANNEL_FIELDS:
            kind = "integer" if name in ("position", "pwm", "flags") else "number"
            properties[f"{prefix}_{name}"] = {
                "type": kind, "description": f"channel {prefix.upper()} {_UNITS[name]}"
            }
    return {"title": "fpgalink.Telemetry", "type": "object", "properties": properties,
            "required": list(TELEMETRY_FIELDS)}


@dataclass
class Streaming:
    """Turns ``GetDataPeriodical`` on for the duration of a command and restores what was
    there before, so watching a board leaves it as it was found."""

    link: Link
    previous: int | float | None = None
    changed: bool = field(default=False)

    async def start(self) -> None:
        self.previous = await self.link.get_param("GetDataPeriodical")
        if self.previous != 1:
            await self.link.set_param("GetDataPeriodical", 1)
            self.changed = True

    async def restore(self) -> None:
        if self.changed and self.previous is not None and self.link.board_alive:
            # Best effort: the board may be gone, and we are on our way out anyway.
            with contextlib.suppress(FpgalinkError):
                await self.link.set_param("GetDataPeriodical", self.previous)
