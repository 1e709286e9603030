"""The sans-I/O connection (:class:`Connection`): bytes in, events out, time passed in.

One module per concern under the :class:`Connection` facade (:mod:`.core`): :mod:`.settings`
(one frozen, checked value), :mod:`.stats`, :mod:`.frames` (bytes ↔ frames and the wire
CRC), :mod:`.requests` (parameter requests, every retry), :mod:`.liveness` (heartbeat,
silence, stale telemetry, watchdog lapses) and :mod:`.restart` (restarts, the resync).
"""

from fpgalink.connection.core import Connection
from fpgalink.connection.liveness import Liveness
from fpgalink.connection.requests import REQUEST_TABLE, Answer, Outcome
from fpgalink.connection.settings import WATCHDOG_S, LinkOptions, Options, Settings
from fpgalink.connection.stats import LinkStats

__all__ = [
    "REQUEST_TABLE",
    "WATCHDOG_S",
    "Answer",
    "Connection",
    "LinkOptions",
    "LinkStats",
    "Liveness",
    "Options",
    "Outcome",
    "Settings",
]
