"""A connection's settings: one frozen value, checked once where it is made.

``Connection(baud=None, request_tries=3)`` builds one from keywords (:class:`Options` names
them for the type checker); ``Connection(settings=…)`` takes one whole, and
``connection.settings = dataclasses.replace(connection.settings, stale_periods=20)`` changes
one on a running connection (checked again, as every new value is).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypedDict

from fpgalink.protocol import DEFAULT_FRAMING, Framing
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

__all__ = ["WATCHDOG_S", "LinkOptions", "Options", "Settings"]

#: The board's watchdog (SPEC §6): enable falls this long after the last ``RE`` arrived.
WATCHDOG_S = 0.3


@dataclass(frozen=True, slots=True)
class Settings:
    """How one connection behaves. Times are seconds.

    ``baud`` lets the connection know how fast the line drains, so references never queue
    behind more than ``max_reference_delay`` of earlier bytes (``None``: not known, every
    ``RV`` goes at once). ``heartbeat_give_up``: a heartbeat due when the last ``RE`` went
    out this long ago (the caller's loop stalled) is not sent: ``RD`` instead, and
    :class:`~fpgalink.events.WatchdogLapsed`. ``stale_periods``: telemetry configured on and
    none for this many timer periods is :class:`~fpgalink.events.TelemetryStale`.
    ``request_tries`` tries of ``request_timeout`` each make one round of a parameter
    request; ``unanswered_rounds`` more rounds follow while the board is heard (a late
    answer then confirms the request asked again: a loaded machine, a slow line).
    ``max_events``: the event queue's cap (the oldest dropped beyond it, and said).
    ``wire_crc``: the link starts with the wire CRC on (a board left with ``WireCrc`` = 1;
    docs/protocol.md §7); either way the board's answer about ``WireCrc`` sets it.
    ``listen_only``: this side sends nothing of its own — no question to a board heard again
    after a silence or whose telemetry stopped (a watcher beside another host, as
    ``monitor --passive``: through the router its question would be refused, and on a
    shared line it would be another host's traffic); a restart is then judged by what the
    board sends alone.
    """

    framing: Framing = DEFAULT_FRAMING
    baud: int | None = 1_000_000
    heartbeat_interval: float = 0.1
    liveness_timeout: float = 0.7
    request_timeout: float = 0.05
    request_tries: int = 8
    unanswered_rounds: int = 0
    max_reference_delay: float = 0.005
    max_events: int = 65536
    heartbeat_give_up: float = 0.28
    stale_periods: int = 50
    wire_crc: bool = False
    listen_only: bool = False

    def __post_init__(self) -> None:
        if not 0 < self.heartbeat_interval < WATCHDOG_S:
            raise ValueError(
                f"heartbeat_interval must be below the board's 300 ms watchdog, got "
                f"{self.heartbeat_interval!r} s"
            )
        if not self.heartbeat_interval < self.heartbeat_give_up <= WATCHDOG_S:
            raise ValueError(
                f"heartbeat_give_up must be above the heartbeat interval and at most the "
                f"board's 300 ms watchdog, got {self.heartbeat_give_up!r} s"
            )
        if not (isinstance(self.stale_periods, int) and self.stale_periods >= 2):
            raise ValueError(f"stale_periods must be a whole number ≥ 2, got "
                             f"{self.stale_periods!r}")
        for name in ("request_timeout", "liveness_timeout", "max_reference_delay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number of seconds, "
                                 f"got {value!r}")
        if self.request_tries < 1 or self.max_events < 1:
            raise ValueError("request_tries and max_events must be at least 1")
        if not (isinstance(self.unanswered_rounds, int) and self.unanswered_rounds >= 0):
            raise ValueError(f"unanswered_rounds must be a whole number ≥ 0, got "
                             f"{self.unanswered_rounds!r}")
        baud = self.baud
        if baud is not None and not (isinstance(baud, int) and MIN_BAUD <= baud <= MAX_BAUD):
            raise ValueError(f"baud must be a whole number from {MIN_BAUD:,} to {MAX_BAUD:,}, "
                             f"got {baud!r}")


class LinkOptions(TypedDict, total=False):
    """:class:`Settings` but the baud, as keyword arguments (``open_link(url, baud, …)``,
    which opens its port at that baud)."""

    framing: Framing
    heartbeat_interval: float
    liveness_timeout: float
    request_timeout: float
    request_tries: int
    unanswered_rounds: int
    max_reference_delay: float
    max_events: int
    heartbeat_give_up: float
    stale_periods: int
    wire_crc: bool
    listen_only: bool


class Options(LinkOptions, total=False):
    """:class:`Settings` as keyword arguments (``Connection(**options)``)."""

    baud: int | None
