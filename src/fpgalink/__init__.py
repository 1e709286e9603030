"""fpgalink: host library for the FPGA motor-controller UART protocol.

Layers, each importing only the ones below it:

* :mod:`fpgalink.protocol` — the wire (framing, messages, parameters, counters, budgets);
* :class:`Connection` — the sans-I/O link: bytes in, :mod:`events <fpgalink.events>` out,
  time passed in;
* :func:`open_link` / :class:`Link` (:mod:`fpgalink.aio`) — asyncio on top: heartbeat,
  retries, reconnects, telemetry subscriptions;
* the robot, the CLI and the ROS 2 node above that.

Importing ``fpgalink`` does not import asyncio: the asyncio names load on first use.
"""

from typing import TYPE_CHECKING

from fpgalink.connection import Connection, LinkStats
from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    LinkClosed,
    LocalProtocolError,
    ParameterError,
    ParameterRefused,
    PortError,
    RequestTimeout,
    UnknownParameter,
    ValueMismatch,
)
from fpgalink.protocol import Role, Telemetry

__version__ = "0.2.0"

if TYPE_CHECKING:
    from fpgalink.aio.link import Link, LinkEvent, LinkEventKind, open_link

_AIO_NAMES = ("Link", "LinkEvent", "LinkEventKind", "open_link")


def __getattr__(name: str) -> object:
    if name in _AIO_NAMES:
        from fpgalink.aio import link

        return getattr(link, name)
    raise AttributeError(f"module 'fpgalink' has no attribute {name!r}")


__all__ = [
    "BoardLost",
    "Connection",
    "FpgalinkError",
    "Link",
    "LinkClosed",
    "LinkEvent",
    "LinkEventKind",
    "LinkStats",
    "LocalProtocolError",
    "ParameterError",
    "ParameterRefused",
    "PortError",
    "RequestTimeout",
    "Role",
    "Telemetry",
    "UnknownParameter",
    "ValueMismatch",
    "__version__",
    "open_link",
]
