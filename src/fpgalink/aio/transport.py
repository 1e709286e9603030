"""Opening a port: the URL scheme picks an opener from a registry, and every opener ends as
an ``asyncio.Transport`` feeding an ``asyncio.Protocol``, so the link above does not care
which one it got.

Built in:

* a device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/…``, a pty) → pyserial-asyncio;
* ``socket://host:port`` → asyncio's own TCP. pyserial's ``socket://`` backend returns empty
  reads on a closed socket, which pyserial-asyncio ignores, so a vanished peer would never
  be noticed; asyncio's TCP reports it as ``connection_lost``.

Other schemes come from packages: an opener registered with :func:`register_scheme`, or
advertised under the ``fpgalink.transports`` entry-point group (the emulator registers
``emu://`` that way, so this package never imports it).
"""

from __future__ import annotations

import asyncio
import functools
import os
from collections.abc import Awaitable, Callable
from importlib.metadata import entry_points
from typing import Any
from urllib.parse import urlsplit

from fpgalink.errors import PortError
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

__all__ = [
    "ENTRY_POINT_GROUP",
    "FAR_END_LAG_EXTRA",
    "Opener",
    "ProtocolFactory",
    "describe_url",
    "open_transport",
    "register_scheme",
    "scheme_of",
]

ENTRY_POINT_GROUP = "fpgalink.transports"

#: An opener whose far end runs in this process (an emulated board) offers, under this
#: ``get_extra_info`` name, a function giving how many seconds that far end's time trails
#: the loop's clock. The link keeps its time that much behind: a process starved as a whole
#: starves its board too, and the samples the board had no time to make are not a board
#: that stopped, nor is a heartbeat the board had no time to miss a lapse.
FAR_END_LAG_EXTRA = "fpgalink.far_end_lag"

ProtocolFactory = Callable[[], asyncio.Protocol]
#: ``await opener(url, baud, protocol_factory)`` → the transport and its protocol.
Opener = Callable[
    [str, int, ProtocolFactory], Awaitable[tuple[asyncio.BaseTransport, asyncio.Protocol]]
]

_registry: dict[str, Opener] = {}


def register_scheme(scheme: str, opener: Opener) -> None:
    """Open ``scheme://…`` URLs with ``opener`` (replacing any earlier one)."""
    _registry[scheme.lower()] = opener


def scheme_of(url: str) -> str:
    """``"socket"`` for ``socket://h:p``, ``""`` for a device path."""
    head, sep, _ = url.partition("://")
    return head.lower() if sep else ""


def describe_url(url: str) -> str:
    kinds = {"": "serial port", "socket": "TCP", "emu": "emulated board"}
    return f"{kinds.get(scheme_of(url), scheme_of(url) + ' port')} {url}"


def _opener(scheme: str) -> Opener | None:
    opener = _registry.get(scheme)
    if opener is None:
        for entry in entry_points(group=ENTRY_POINT_GROUP, name=scheme):
            opener = entry.load()
            _registry[scheme] = opener
            break
    return opener


def known_schemes() -> list[str]:
    names = set(_registry) | {e.name for e in entry_points(group=ENTRY_POINT_GROUP)}
    return sorted(names)


async def open_transport(
    url: str, baud: int, protocol_factory: ProtocolFactory
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    """Open ``url`` and attach a protocol; :class:`PortError` (naming the port) on any
    failure, whatever the opener raised."""
    if isinstance(baud, bool) or not isinstance(baud, int) or not MIN_BAUD <= baud <= MAX_BAUD:
        raise PortError(f"{url}: baud must be a whole number from {MIN_BAUD:,} to "
                        f"{MAX_BAUD:,}, got {baud!r}")
    scheme = scheme_of(url)
    try:
        opener = _opener(scheme)
    except Exception as exc:  # a broken plug-in must not take the caller down with a trace
        raise PortError(f"{url}: the {scheme}:// opener could not be loaded: {exc}") from exc
    if opener is None:
        known = ", ".join(f"{s}://" for s in known_schemes() if s)  # "" is the device path
        raise PortError(f"{url}: unsupported port; use a device path, {known}")
    try:
        return await opener(url, baud, protocol_factory)
    except PortError:
        raise
    except OSError as exc:
        raise PortError(f"cannot open {url}: {exc.strerror or exc}") from exc
    except (ValueError, TypeError) as exc:
        raise PortError(f"{url}: {exc}") from exc


async def _open_socket(
    url: str, baud: int, protocol_factory: ProtocolFactory
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port
    except ValueError as exc:  # a port out of 0..65535
        raise PortError(f"{url}: {exc}; expected socket://HOST:PORT") from None
    if not host or port is None:
        raise PortError(f"{url}: expected socket://HOST:PORT")
    loop = asyncio.get_running_loop()
    return await loop.create_connection(protocol_factory, host, port)


async def _open_serial(
    url: str, baud: int, protocol_factory: ProtocolFactory
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    import serial

    loop = asyncio.get_running_loop()
    try:
        port = _loop_serial_class()(url, baudrate=baud, exclusive=True)
    except (serial.SerialException, ValueError) as exc:
        raise PortError(f"cannot open serial port {url}: {exc}") from exc
    # serial_asyncio.connection_for_serial, with the transport below.
    protocol = protocol_factory()
    transport = _serial_transport_class()(loop, protocol, port)
    return transport, protocol


@functools.cache
def _serial_transport_class() -> Any:
    """pyserial-asyncio's transport, closing on a failed write as it does on a failed read.
    Its write path hands the error to the loop's exception handler first, which prints a
    traceback for what is only a port that went away (a board unplugged, a pty whose server
    was killed); the protocol learns it from ``connection_lost(exc)`` either way."""
    import serial_asyncio

    class QuietSerialTransport(serial_asyncio.SerialTransport):  # type: ignore[misc]
        def _fatal_error(self, exc: Exception, message: str = "") -> None:
            self._abort(exc)

    return QuietSerialTransport


#: Bytes one read may take from a serial port (a pty holds up to 64 KiB).
READ_CHUNK = 65536


@functools.cache
def _loop_serial_class() -> Any:
    """pyserial's POSIX port with a read made for an event loop. The transport reads only
    when the loop has seen the port readable, yet ``Serial.read`` still runs ``select``
    before and after its ``read`` — three system calls where one does, at 1,000 reads a
    second per board."""
    import serial

    if os.name != "posix":  # pragma: no cover - the project runs on POSIX
        return serial.Serial

    class LoopSerial(serial.Serial):  # type: ignore[misc]
        def read(self, size: int = 1) -> bytes:
            if not self.is_open:
                raise serial.PortNotOpenError()
            try:
                # Everything waiting, not just what the transport asks for (1,024 bytes):
                # a link that batches reads must find its whole batch in one call.
                data = os.read(self.fd, max(size, READ_CHUNK))
            except BlockingIOError:
                return b""
            except OSError as exc:
                raise serial.SerialException(f"read failed: {exc}") from exc
            if not data:
                # A vanished device stays "readable" and returns nothing, as pyserial notes.
                raise serial.SerialException(
                    "device reports readiness to read but returned no data "
                    "(device disconnected?)"
                )
            return data

    return LoopSerial


register_scheme("", _open_serial)
register_scheme("socket", _open_socket)
