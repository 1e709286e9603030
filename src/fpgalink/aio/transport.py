"""Opening a port: the URL scheme picks an opener from a registry, and every opener ends as
an ``asyncio.Transport`` feeding an ``asyncio.Protocol``, so the link above does not care
which one it got.

Built in:

* a device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/…``, a pty) → pyserial opens and
  configures it, :class:`~fpgalink.aio.serialport.SerialTransport` reads and writes it
  (O(1) a write, whatever is queued);
* ``socket://host:port`` → asyncio's own TCP. pyserial's ``socket://`` backend returns empty
  reads on a closed socket, so a vanished peer would never be noticed; asyncio's TCP
  reports it as ``connection_lost``.

Other schemes come from packages: an opener registered with :func:`register_scheme`, or
advertised under the ``fpgalink.transports`` entry-point group (the emulator registers
``emu://`` that way, so this package never imports it).
"""

from __future__ import annotations

import asyncio
import errno
import functools
import os
from collections.abc import Awaitable, Callable
from importlib.metadata import entry_points
from typing import Any
from urllib.parse import urlsplit

from fpgalink.aio.serialport import READ_CHUNK, SerialTransport
from fpgalink.errors import PortError
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

__all__ = [
    "ENTRY_POINT_GROUP",
    "FAR_END_LAG_EXTRA",
    "HOST_DUE_EXTRA",
    "READ_CHUNK",
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
#: the loop's clock at the loop time it is given. The link keeps its time that much behind:
#: a process starved as a whole starves its board too, and the samples the board had no
#: time to make are not a board that stopped, nor is a heartbeat the board had no time to
#: miss a lapse.
FAR_END_LAG_EXTRA = "fpgalink.far_end_lag"
#: Such an opener may also offer, under this name, a function the link calls once with its
#: own ``due()`` (when its connection next has work, on the far end's time, or ``None``):
#: the far end then does not run past a deadline of the link's that has come and not been
#: met, so after the process was not scheduled the link meets its deadlines (its heartbeat
#: first) at the time they fell, and the far end takes what it wrote then.
HOST_DUE_EXTRA = "fpgalink.host_due"

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
    except serial.SerialException as exc:
        raise PortError(f"cannot open serial port {url}: {_why_not(exc)}") from exc
    except ValueError as exc:
        raise PortError(f"cannot open serial port {url}: {exc}") from exc
    protocol = protocol_factory()
    return SerialTransport(loop, protocol, port), protocol


def _why_not(exc: OSError) -> str:
    """Why a serial port did not open, said once: pyserial's message repeats the path and
    the errno (``[Errno 11] Could not exclusively lock port P: [Errno 11] Resource
    temporarily unavailable``)."""
    code = exc.errno
    if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY):
        # pyserial's exclusive lock (flock) is held: another program has the port open.
        return "in use by another program; share it with `fpgalink-cli router`"
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return ("no such device (unplugged? `fpgalink-cli ports` lists the serial ports "
                "there are)")
    if code == errno.EACCES:
        return ("permission denied (is your user in the group that owns it, such as "
                "dialout?)")
    if code is not None:
        return os.strerror(code)
    return str(exc)


@functools.cache
def _loop_serial_class() -> Any:
    """pyserial's POSIX port with a read made for an event loop: ``Serial.read`` runs
    ``select`` before and after its ``read`` — three system calls where one does. The
    transport reads the descriptor itself; this read serves a link that collects a batch
    from a paused transport (``get_extra_info("serial").read(n)``)."""
    import serial

    if os.name != "posix":  # pragma: no cover - the project runs on POSIX
        return serial.Serial

    class LoopSerial(serial.Serial):  # type: ignore[misc]
        def read(self, size: int = 1) -> bytes:
            if not self.is_open:
                raise serial.PortNotOpenError()
            try:
                # Everything waiting, not just what is asked for: a link that batches
                # reads must find its whole batch in one call.
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
