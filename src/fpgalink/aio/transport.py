"""Byte-stream adapters: every backend ends as an ``asyncio.Transport`` feeding an
``asyncio.Protocol``, so the link above does not care which one it got.

* a device path (``/dev/ttyUSB0``, a pty) → pyserial-asyncio;
* ``socket://host:port`` → asyncio's own TCP. pyserial's ``socket://`` backend returns
  empty reads on a closed socket, which pyserial-asyncio ignores, so a vanished peer would
  never be noticed; asyncio's TCP reports it as ``connection_lost``;
* ``emu://`` → an emulated board in this process (:mod:`fpgaemu.serve`).
"""

from __future__ import annotations

import asyncio
import functools
import os
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs, urlsplit

from fpgalink.errors import PortError

__all__ = ["connect", "describe_url"]


def describe_url(url: str) -> str:
    kind = "emulated board" if url.startswith("emu://") else (
        "TCP" if url.startswith("socket://") else "serial port"
    )
    return f"{kind} {url}"


async def connect(
    url: str, baud: int, protocol_factory: Callable[[], asyncio.Protocol]
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    """Open ``url`` and attach a protocol; :class:`PortError` (naming the port) on failure."""
    loop = asyncio.get_running_loop()
    try:
        if url.startswith("emu://"):
            return await _connect_emulator(url, baud, protocol_factory)
        if url.startswith("socket://"):
            parts = urlsplit(url)
            if parts.hostname is None or parts.port is None:
                raise PortError(f"{url}: expected socket://HOST:PORT")
            return await loop.create_connection(protocol_factory, parts.hostname, parts.port)
        import serial
        import serial_asyncio

        try:
            if "://" in url or os.name != "posix":
                port = serial.serial_for_url(url, baudrate=baud, exclusive=True)
            else:
                port = _loop_serial_class()(url, baudrate=baud, exclusive=True)
            return await serial_asyncio.connection_for_serial(  # type: ignore[no-any-return]
                loop, protocol_factory, port
            )
        except (serial.SerialException, ValueError) as exc:
            raise PortError(f"cannot open serial port {url}: {exc}") from exc
    except PortError:
        raise
    except OSError as exc:
        raise PortError(f"cannot open {url}: {exc.strerror or exc}") from exc


@functools.cache
def _loop_serial_class() -> Any:
    """pyserial's POSIX port with a read made for an event loop. The transport reads only
    when the loop has seen the port readable, yet ``Serial.read`` still runs ``select``
    before and after its ``read`` — three system calls where one does, at 1,000 reads a
    second per board."""
    import serial

    class LoopSerial(serial.Serial):  # type: ignore[misc]
        def read(self, size: int = 1) -> bytes:
            if not self.is_open:
                raise serial.PortNotOpenError()
            try:
                data = os.read(self.fd, size)
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


async def _connect_emulator(
    url: str, baud: int, protocol_factory: Callable[[], asyncio.Protocol]
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    try:
        from fpgaemu.serve import open_emulated_transport
    except ImportError as exc:  # pragma: no cover - both ship in one distribution
        raise PortError(f"{url}: the emulator is not available ({exc})") from exc
    options = {k: v[-1] for k, v in parse_qs(urlsplit(url).query).items()}
    return await open_emulated_transport(protocol_factory, baud=baud, options=options)
