"""fpgalink: host library for the FPGA motor-controller UART protocol.

Layers, each importing only the ones below it:

* :mod:`fpgalink.protocol` — the wire (framing, messages, parameters, counters, budgets);
* :class:`Connection` — the sans-I/O link: bytes in, :mod:`events <fpgalink.events>` out,
  time passed in;
* :func:`open_link` / :class:`Link` (:mod:`fpgalink.aio`) — asyncio on top: heartbeat,
  retries, reconnects, telemetry subscriptions;
* the robot, the CLI and the ROS 2 node above that.

The names below load on first use, so ``import fpgalink`` costs nothing a program does not
use (the asyncio layer, in particular, is not imported by the sans-I/O core).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# Before any module that may be compiled: which build runs (compiled or pure Python).
import fpgalink.buildinfo  # noqa: F401
from fpgalink.protocol.exports import lazy_exports

__version__ = "0.2.0"

#: public name → the module that defines it
_HOMES = {
    "Connection": "fpgalink.connection",
    "LinkStats": "fpgalink.connection",
    "BoardLost": "fpgalink.errors",
    "FpgalinkError": "fpgalink.errors",
    "LineBusy": "fpgalink.errors",
    "LinkClosed": "fpgalink.errors",
    "LocalProtocolError": "fpgalink.errors",
    "ParameterError": "fpgalink.errors",
    "ParameterRefused": "fpgalink.errors",
    "PortError": "fpgalink.errors",
    "RequestTimeout": "fpgalink.errors",
    "UnknownParameter": "fpgalink.errors",
    "ValueMismatch": "fpgalink.errors",
    "WireCrcMismatchError": "fpgalink.errors",
    "Role": "fpgalink.protocol",
    "Telemetry": "fpgalink.protocol",
    "Link": "fpgalink.aio.link",
    "StatusEvent": "fpgalink.events",
    "open_link": "fpgalink.aio.link",
}

if TYPE_CHECKING:
    from fpgalink.aio.link import Link, open_link
    from fpgalink.connection import Connection, LinkStats
    from fpgalink.errors import (
        BoardLost,
        FpgalinkError,
        LineBusy,
        LinkClosed,
        LocalProtocolError,
        ParameterError,
        ParameterRefused,
        PortError,
        RequestTimeout,
        UnknownParameter,
        ValueMismatch,
        WireCrcMismatchError,
    )
    from fpgalink.events import StatusEvent
    from fpgalink.protocol import Role, Telemetry


__getattr__ = lazy_exports(__name__, _HOMES)

__all__ = [
    "BoardLost",
    "Connection",
    "FpgalinkError",
    "LineBusy",
    "Link",
    "LinkClosed",
    "LinkStats",
    "LocalProtocolError",
    "ParameterError",
    "ParameterRefused",
    "PortError",
    "RequestTimeout",
    "Role",
    "StatusEvent",
    "Telemetry",
    "UnknownParameter",
    "ValueMismatch",
    "WireCrcMismatchError",
    "__version__",
    "open_link",
]
