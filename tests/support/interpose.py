"""Stand between a link and its port: what the board sends arrives late, or is held back,
as from a starved emulator's or node's process, or a slow line."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, TypeVar

from fpgalink.aio import Link

_P = TypeVar("_P", bound=asyncio.Protocol)


class LateReads(asyncio.Protocol):
    """Everything the board sends reaches the link ``delay`` late."""

    def __init__(self, inner: asyncio.Protocol, delay: float) -> None:
        self.inner, self.delay = inner, delay
        self.loop = asyncio.get_running_loop()

    def data_received(self, data: bytes) -> None:
        self.loop.call_later(self.delay, self.inner.data_received, data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class HeldReads(asyncio.Protocol):
    """While ``held``, what the board sends waits, as in a host that stopped reading that
    port (or a starved emulator's pty); released, it all arrives at once, late."""

    def __init__(self, inner: asyncio.Protocol) -> None:
        self.inner, self.held, self.waiting = inner, False, bytearray()

    def data_received(self, data: bytes) -> None:
        if self.held:
            self.waiting += data
        else:
            self.inner.data_received(data)

    def release(self) -> None:
        self.held = False
        data, self.waiting = bytes(self.waiting), bytearray()
        if data:
            self.inner.data_received(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class SlowReader(asyncio.Protocol):
    """A host that reads ``rate`` bytes a second (every 10 ms or so, in a chunk), slower than the
    board sends: what waits beyond ``backlog`` bytes is lost, the oldest first, as serve's
    pty loses what nobody read in time (a loaded node against a 1 kHz stream)."""

    def __init__(self, inner: asyncio.Protocol, rate: float, backlog: int = 4096) -> None:
        self.inner, self.rate, self.backlog = inner, rate, backlog
        self.waiting = bytearray()
        self.loop = asyncio.get_running_loop()
        self._last_read = self.loop.time()
        self._owed = 0.0  #: bytes the rate allows that a whole byte has not yet used
        self._reading = self.loop.call_later(0.01, self._read)

    def data_received(self, data: bytes) -> None:
        self.waiting += data
        del self.waiting[:len(self.waiting) - self.backlog]  # the oldest beyond the backlog

    def _read(self) -> None:
        # By the time that passed, not per call: a loaded loop calls late, and the host
        # still reads at its rate (the boards' time is kept the same way).
        now = self.loop.time()
        self._owed += self.rate * (now - self._last_read)
        self._last_read = now
        allowed = int(self._owed)
        self._owed -= allowed
        chunk = bytes(self.waiting[:allowed])
        if len(chunk) < allowed:
            self._owed = 0.0  # a host with nothing to read saves up no reading
        del self.waiting[:len(chunk)]
        if chunk:
            self.inner.data_received(chunk)
        self._reading = self.loop.call_later(0.01, self._read)

    def stop(self) -> None:
        self._reading.cancel()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def interpose(link: Link, make: Callable[[asyncio.Protocol], _P]) -> _P:
    """Put ``make(its protocol)`` between ``link``'s open port and the link; returned."""
    transport = link._transport  # the port's far end is here
    assert transport is not None
    between = make(transport._protocol)  # type: ignore[attr-defined]
    transport._protocol = between  # type: ignore[attr-defined]
    return between
