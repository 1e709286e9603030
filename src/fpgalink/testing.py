"""Test doubles that tests, benchmarks and user code share.

:class:`MemoryTransport` is an ``asyncio.Transport`` with the test's hand on the far end:
what the link writes collects in :attr:`MemoryTransport.written` (and goes to ``on_write``
if set, so a scripted peer can answer), :meth:`feed` delivers bytes as if they had arrived,
:meth:`lose` pulls the cable. With it a :class:`~fpgalink.Link` runs without a port::

    transport = MemoryTransport()
    async with Link(Connection(), transport) as link:
        transport.feed(b"SEP")          # the board's heartbeat arrives
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

__all__ = ["MemoryTransport"]


class MemoryTransport(asyncio.Transport):
    def __init__(self, on_write: Callable[[bytes], None] | None = None) -> None:
        super().__init__()
        self.written = bytearray()
        self.on_write = on_write
        self._protocol: asyncio.BaseProtocol | None = None
        self._closing = False

    # --- the link's side ------------------------------------------------------------------

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = protocol

    def get_protocol(self) -> asyncio.BaseProtocol:
        assert self._protocol is not None
        return self._protocol

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        chunk = bytes(data)
        self.written += chunk
        if self.on_write is not None:
            self.on_write(chunk)

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        if self._protocol is not None:
            asyncio.get_running_loop().call_soon(self._protocol.connection_lost, None)

    def abort(self) -> None:
        self.close()

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return default

    # --- the far end ----------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Bytes arrive from the far end."""
        if not self._closing and self._protocol is not None:
            self._protocol.data_received(data)  # type: ignore[attr-defined]

    def lose(self, exc: Exception | None = None) -> None:
        """The far end vanished (cable pulled, device gone)."""
        if self._closing:
            return
        self._closing = True
        if self._protocol is not None:
            self._protocol.connection_lost(exc)

    def take_written(self) -> bytes:
        """Everything written since the last call."""
        data = bytes(self.written)
        self.written.clear()
        return data
