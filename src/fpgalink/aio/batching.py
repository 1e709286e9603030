"""Read batching: bytes gathered for up to a latency bound before the link handles them, for a
consumer that needs samples at 100 Hz or less (at 1 kHz telemetry a 10 ms bound turns a
thousand wake-ups a second into about a hundred, losing nothing).

While a batch gathers, the transport is paused (the loop stops watching the port) and one
timer reads what arrived, straight from the port's device or socket, when the bound is up.
A transport that offers neither (``get_extra_info("serial")`` or ``"socket"``) is never
paused."""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
from collections.abc import Callable

from fpgalink.aio.transport import READ_CHUNK

__all__ = ["ReadBatcher"]


class ReadBatcher:
    """``deliver(data)`` hands gathered bytes to the link; ``transport()`` is the port now;
    ``urgent()`` says a batch must not start (a request waits for its answer)."""

    def __init__(self, deliver: Callable[[bytes], None],
                 transport: Callable[[], asyncio.BaseTransport | None],
                 urgent: Callable[[], bool]) -> None:
        self.latency: float | None = None
        self._deliver = deliver
        self._transport = transport
        self._urgent = urgent
        self._timer: asyncio.TimerHandle | None = None

    def set_latency(self, seconds: float | None) -> None:
        if seconds is not None and not (math.isfinite(seconds) and 0 <= seconds <= 1.0):
            raise ValueError(f"read latency must be 0..1 s, got {seconds!r}")
        self.latency = seconds or None
        if self.latency is None:
            self.resume()

    def read(self) -> None:
        """The link handled a read: begin a batch, unless one is under way or urgent."""
        if self.latency and self._timer is None and not self._urgent():
            self._pause()

    def resume(self) -> None:
        """End the batch now: what arrived during it goes first, in order, then the
        transport reads again (a request's answer must not wait for a batch)."""
        handle, self._timer = self._timer, None
        if handle is None:
            return
        handle.cancel()
        data = _read_waiting(self._transport())
        if data:
            self._deliver(data)
            self.cancel()
        self._resume_transport()

    def read_now(self) -> None:
        """Hand the link what the port holds now, paused or not, without waiting for the
        loop to notice it. Before a timer's judgement (a silence, a stale stream, an overdue
        heartbeat): the loop looks at the port once per turn, before that turn's timers, so
        bytes that came while this host was not scheduled, after the look, would be judged
        missing by a timer in the same turn. A silence is the board's only when nothing waits."""
        data = _read_waiting(self._transport())
        if data:
            self._deliver(data)

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _pause(self) -> None:
        pause = getattr(self._transport(), "pause_reading", None)
        if pause is None or self.latency is None:
            return
        try:
            pause()
        except (RuntimeError, AttributeError):  # closing, or not a reading transport
            return
        self._timer = asyncio.get_running_loop().call_later(self.latency, self._collect)

    def _collect(self) -> None:
        self._timer = None
        data = _read_waiting(self._transport())
        if data is None:  # nothing to read it with, or the port has an error: let the
            self._resume_transport()  # transport read and report as usual
            return
        if data:
            self._deliver(data)  # may start the next batch
        elif self.latency and not self._urgent():
            self._timer = asyncio.get_running_loop().call_later(self.latency, self._collect)
            return
        if self._timer is None:
            self._resume_transport()

    def _resume_transport(self) -> None:
        resume = getattr(self._transport(), "resume_reading", None)
        if resume is not None:
            with contextlib.suppress(RuntimeError, AttributeError):
                resume()


def _read_waiting(transport: asyncio.BaseTransport | None) -> bytes | None:
    """What a paused transport's port holds now, without blocking: a serial port's device
    or a socket, read directly; ``None`` when there is no such thing to read or reading it
    failed (the transport, resumed, then sees and reports the problem itself)."""
    if transport is None:
        return None
    port = transport.get_extra_info("serial")
    if port is not None:
        try:
            data: bytes = port.read(READ_CHUNK)
        except Exception:  # pyserial raises its own kinds: the port is in trouble
            return None
        return data
    sock = transport.get_extra_info("socket")
    if sock is not None:
        try:
            data = os.read(sock.fileno(), READ_CHUNK)  # asyncio's sockets are non-blocking
        except BlockingIOError:
            return b""
        except (OSError, ValueError):
            return None
        return data if data else None  # b"": the peer closed
    return None
