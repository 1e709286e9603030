"""A pseudo-terminal a host opens as a device: its set-up (:func:`open_raw_pty`) and the
writes to its master side that never block (:class:`PtyOutput`)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from typing import NamedTuple

__all__ = ["PtyOutput", "RawPty", "open_raw_pty"]


class RawPty(NamedTuple):
    """A pseudo-terminal: the side this process reads and writes (non-blocking), the side a
    host opens (raw: no echo, no line discipline), and that side's path."""

    master: int
    slave: int
    path: str


def open_raw_pty() -> RawPty:
    """A new pty in raw mode, its master non-blocking. Keeping the slave side open as well
    lets a host close and reopen the path without the pty going away; closing it lets this
    process see a host's close as a hang-up on the master."""
    master, slave = os.openpty()
    try:
        tty.setraw(slave)  # kept by the pty: nothing echoes before the host sets it up
        os.set_blocking(master, False)
        path = os.ttyname(slave)
    except BaseException:
        os.close(master)
        os.close(slave)
        raise
    return RawPty(master, slave, path)


class PtyOutput:
    """Bytes for a pty's master side, written as far as the pty takes them now; the rest
    waits here (:attr:`pending`) and goes when the event loop says the master is writable,
    so a host that does not read never blocks this process. What waits is bounded by the
    owner (:meth:`trim`): a pty has no backpressure a writer could wait on."""

    def __init__(self, master: int) -> None:
        self.master = master
        self.pending = bytearray()
        self._watching = False

    def write(self, data: bytes) -> None:
        self.pending += data
        self.flush()

    def flush(self) -> None:
        """Write what waits as far as the pty takes it; watch the master while some is
        left."""
        if self.pending:
            try:
                written = os.write(self.master, self.pending)
                del self.pending[:written]
            except OSError:
                pass  # full (nobody reading just now) or nobody on the slave side: kept
        self._watch(bool(self.pending))

    def trim(self, keep: int) -> int:
        """Drop the oldest waiting bytes beyond ``keep``; how many were dropped."""
        excess = len(self.pending) - keep
        if excess <= 0:
            return 0
        del self.pending[:excess]
        return excess

    def discard(self) -> int:
        """Drop everything waiting and stop watching the master (a host gone, the pty
        closing); how many bytes were dropped."""
        dropped = len(self.pending)
        self.pending.clear()
        self._watch(False)
        return dropped

    def _watch(self, on: bool) -> None:
        if on == self._watching:
            return
        loop = asyncio.get_running_loop()
        if on:
            loop.add_writer(self.master, self.flush)
        else:
            with contextlib.suppress(Exception):  # the master may be closed already
                loop.remove_writer(self.master)
        self._watching = on
