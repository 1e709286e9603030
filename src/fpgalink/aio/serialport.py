"""A serial port as an ``asyncio.Transport``: the port opened and configured by pyserial
(exclusive lock, baud, raw mode), then read and written straight on its file descriptor
with non-blocking ``os.read``/``os.write`` and the loop's reader and writer callbacks.

Why not pyserial-asyncio's ``SerialTransport``: its ``write`` sums the whole write buffer
(a list of chunks) on every call, so queuing n frames costs O(n²) — 20,000 frames froze a
router for 8 s, 100,000 for minutes, deaf to SIGTERM (issue 37). Here the write queue is
a deque of chunks with a running byte count: a write costs O(1), and the bytes of a write
are copied at most once more, when they go out in a batch. Closing writes out what is
queued (what the port's driver takes) and never waits on the line itself (no ``tcdrain``
inside the loop).

The transport queues whatever it is given, as asyncio's transports do (pausing its
protocol above the high-water mark); bounding what waits for the line is the writer's
business: the link refuses a request while the line is backed up beyond its bound
(:data:`fpgalink.aio.link.MAX_LINE_BACKLOG_S`), the router paces by line time and refuses
what does not fit.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections import deque
from typing import Any

__all__ = ["READ_CHUNK", "WRITE_BATCH", "SerialTransport"]

#: At most this many bytes are joined into one ``os.write`` (a pty takes 16 KiB at a time,
#: a USB-UART's driver a few KiB).
WRITE_BATCH = 65536
#: Bytes one read may take: everything waiting, so a link that batches reads finds its whole
#: batch in one call (a pty holds up to 64 KiB).
READ_CHUNK = 65536


class SerialTransport(asyncio.Transport):
    """``port`` is an open pyserial ``Serial`` (its ``fileno()`` is read and written
    directly). ``protocol.connection_made`` runs on the loop's next turn, then reading
    starts. A failed read or write (a USB-UART pulled out, a pty whose other side is gone)
    closes the transport: ``connection_lost(exc)``."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.BaseProtocol,
                 port: Any) -> None:
        super().__init__(extra={"serial": port})
        self._loop = loop
        self._protocol = protocol
        self._port = port
        self._fd: int = port.fileno()
        os.set_blocking(self._fd, False)
        self._queue: deque[bytes] = deque()
        self._queued = 0  #: bytes in the queue, kept as it changes: never summed
        self._reading = False
        self._writing = False
        self._closing = False
        self._gone = False  #: connection_lost is scheduled or done
        self._paused_protocol = False
        self._high = 64 * 1024
        self._low = 16 * 1024
        loop.call_soon(protocol.connection_made, self)
        loop.call_soon(self._start_reading)

    # --- reading ------------------------------------------------------------------------

    def _start_reading(self) -> None:
        if not self._closing and not self._reading:
            self._loop.add_reader(self._fd, self._read_ready)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading:
            self._loop.remove_reader(self._fd)
            self._reading = False

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._fatal(_port_failed("read failed", exc))
            return
        if not data:
            # A vanished device stays "readable" and reads nothing (as pyserial notes).
            self._fatal(_port_failed("device reports readiness to read but returned no "
                                     "data (device disconnected?)"))
            return
        self._protocol.data_received(data)  # type: ignore[attr-defined]

    def pause_reading(self) -> None:
        self._stop_reading()

    def resume_reading(self) -> None:
        self._start_reading()

    def is_reading(self) -> bool:
        return self._reading

    # --- writing ------------------------------------------------------------------------

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Queue ``data`` (O(1)); written at once if nothing is waiting and the port takes
        it. Ignored once the transport is closing, as asyncio's transports do."""
        if self._closing or not data:
            return
        chunk = bytes(data)
        if not self._queue:
            try:
                written = os.write(self._fd, chunk)
            except (BlockingIOError, InterruptedError):
                written = 0
            except OSError as exc:
                self._fatal(_port_failed("write failed", exc))
                return
            if written == len(chunk):
                return
            chunk = chunk[written:]
            self._loop.add_writer(self._fd, self._write_ready)
            self._writing = True
        self._queue.append(chunk)
        self._queued += len(chunk)
        if not self._paused_protocol and self._queued > self._high:
            self._paused_protocol = True
            self._protocol.pause_writing()

    def _write_ready(self) -> None:
        queue = self._queue
        if len(queue) == 1 or len(queue[0]) >= WRITE_BATCH:
            batch = queue.popleft()
        else:
            parts = [queue.popleft()]
            size = len(parts[0])
            while queue and size + len(queue[0]) <= WRITE_BATCH:
                size += len(queue[0])
                parts.append(queue.popleft())
            batch = b"".join(parts)
        try:
            written = os.write(self._fd, batch)
        except (BlockingIOError, InterruptedError):
            written = 0
        except OSError as exc:
            queue.appendleft(batch)
            self._fatal(_port_failed("write failed", exc))
            return
        if written < len(batch):
            queue.appendleft(batch[written:])
        self._queued -= written
        if self._paused_protocol and self._queued <= self._low:
            self._paused_protocol = False
            self._protocol.resume_writing()
        if not queue:
            self._loop.remove_writer(self._fd)
            self._writing = False
            if self._closing:
                self._lose(None)

    def get_write_buffer_size(self) -> int:
        """Bytes queued and not yet taken by the port's driver (O(1))."""
        return self._queued

    def get_write_buffer_limits(self) -> tuple[int, int]:
        return (self._low, self._high)

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        if high is None:
            high = 4 * low if low is not None else 64 * 1024
        if low is None:
            low = high // 4
        if not high >= low >= 0:
            raise ValueError(f"high ({high!r}) must be >= low ({low!r}) must be >= 0")
        self._high, self._low = high, low

    def can_write_eof(self) -> bool:
        return False

    def write_eof(self) -> None:
        raise NotImplementedError("a serial port has no end of file")

    # --- the rest of the transport ------------------------------------------------------

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = protocol

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        """Stop reading; write out what is queued (what the port's driver takes: the line
        itself is not waited for), then close the port and call ``connection_lost(None)``."""
        if self._closing:
            return
        self._closing = True
        self._stop_reading()
        if not self._queue:
            self._lose(None)

    def abort(self) -> None:
        """Close at once: what is queued is not written."""
        self._closing = True
        self._lose(None)

    def _fatal(self, exc: Exception) -> None:
        self._closing = True
        self._lose(exc)

    def _lose(self, exc: Exception | None) -> None:
        if self._gone:
            return
        self._gone = True
        self._stop_reading()
        if self._writing:
            self._loop.remove_writer(self._fd)
            self._writing = False
        self._queue.clear()
        self._queued = 0
        self._loop.call_soon(self._call_connection_lost, exc)

    def _call_connection_lost(self, exc: Exception | None) -> None:
        try:
            self._protocol.connection_lost(exc)
        finally:
            with contextlib.suppress(Exception):  # a port already gone closes as it can
                self._port.close()

    def __repr__(self) -> str:
        return f"<SerialTransport fd={self._fd} queued={self._queued}>"


def _port_failed(what: str, exc: OSError | None = None) -> Exception:
    """pyserial's own exception type for a port that failed, as its transport reported it."""
    import serial

    failed: Exception = serial.SerialException(f"{what}: {exc}" if exc is not None else what)
    return failed
