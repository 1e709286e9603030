"""A board behind a pseudo-terminal (``fpgaemu serve --pty``), and the pty set-up itself
(:func:`open_raw_pty`), which anything serving a device on a pty can share."""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from pathlib import Path
from typing import NamedTuple

from fpgaemu.serving.loop import Pacer, say
from fpgaemu.serving.pacing import TX_BACKLOG_S, PacedBoard, RxFlow, schedule_unplugs

__all__ = ["PtyEndpoint", "RawPty", "open_raw_pty"]


class RawPty(NamedTuple):
    """A pseudo-terminal: the side this process reads and writes (non-blocking), the side a
    host opens (raw: no echo, no line discipline), and that side's path."""

    master: int
    slave: int
    path: str


def open_raw_pty() -> RawPty:
    """A new pty in raw mode, its master non-blocking. Keeping the slave side open as well
    lets a host close and reopen the path without the pty going away."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return RawPty(master, slave, os.ttyname(slave))


class PtyEndpoint:
    """One board behind a pseudo-terminal. We keep the slave side open ourselves, so a host
    that closes and reopens the path finds the same board still running. Host bytes are read
    only as fast as the line carries them: while
    :data:`~fpgaemu.serving.pacing.RX_BACKLOG_BYTES` wait, the pty is not read and the
    host's ``write`` waits in the kernel's tty buffer."""

    def __init__(self, paced: PacedBoard) -> None:
        self.paced = paced
        self._open_pty()
        self.flow = RxFlow(paced, self._pause, self._resume)
        self.pacer = Pacer(self._tick, self.flow.next_wake)
        self._pending_out = bytearray()
        self._writing = False
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        #: TX bytes lost because nobody read the pty for longer than the backlog holds
        self.dropped_tx = 0
        #: a stable symlink to the pty (``--link``), pointed at the new pty on a replug
        self.link: Path | None = None
        self.unplugged = False
        self.unplugs = 0
        #: TX bytes the board sent while unplugged (gone, as on a pulled cable)
        self.unplugged_tx = 0

    def _open_pty(self) -> None:
        self._master, self._slave, self.path = open_raw_pty()

    def start(self) -> None:
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        self.pacer.start()
        schedule_unplugs(self.paced, self._unplug, self._replug)

    def remove_own_link(self) -> None:
        """Remove the ``--link`` if it points at the pty served now: another serve or router
        may have taken the name since. An unplugged pty's link went with it, and its freed
        number may be another's now."""
        if self.link is None or self.unplugged:
            return
        with contextlib.suppress(OSError):
            if os.readlink(self.link) == self.path:
                self.link.unlink()

    def _unplug(self) -> None:
        """The USB-UART is pulled out: the pty goes (the host's next read fails), what the
        host wrote that the line had not begun is gone, and the board runs on unheard. The
        ``--link`` goes with it, as udev's /dev/serial/by-id link goes with a pulled
        USB-UART: the freed pty's number may be given to another program meanwhile, and a
        host reopening the link must find nothing, not that program's pty."""
        if self.unplugged:
            return
        self.remove_own_link()
        self.unplugged = True
        self.unplugs += 1
        loop = asyncio.get_running_loop()
        with contextlib.suppress(Exception):
            loop.remove_reader(self._master)
        if self._writing:
            with contextlib.suppress(Exception):
                loop.remove_writer(self._master)
            self._writing = False
        self.unplugged_tx += len(self._pending_out)
        self._pending_out.clear()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.paced.host_gone()
        self.flow.reset()
        say(f"unplugged {self.path}")

    def _replug(self) -> None:
        """Plugged in again: a new pty (a new name, as a USB-UART may come back as another
        ttyUSB), the ``--link`` symlink made again, pointing at it."""
        if not self.unplugged:
            return
        self._open_pty()
        self.unplugged = False
        shown = self.path
        if self.link is not None:
            shown = f"{self.link} -> {self.path}"
            try:
                if self.link.is_symlink() and not self.link.exists():
                    self.link.unlink()  # a stale link (its pty gone): ours to replace
                self.link.symlink_to(self.path)
            except FileExistsError:
                # Taken while unplugged (another serve or router): theirs, left alone.
                shown = f"{self.path} (--link {self.link} is now another's, left alone)"
            except OSError as exc:
                shown = f"{self.path} (--link {self.link}: {exc.strerror or exc})"
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        say(f"plugged in again: {shown}")

    def _pause(self) -> None:
        if not self.unplugged:
            asyncio.get_running_loop().remove_reader(self._master)

    def _resume(self) -> None:
        if not self.unplugged:
            asyncio.get_running_loop().add_reader(self._master, self._readable)

    def _readable(self) -> None:
        room = self.paced.rx_room()
        if room <= 0:
            self.flow.took()
            return
        try:
            data = os.read(self._master, room)
        except BlockingIOError:
            return
        except OSError:
            return  # no reader on the slave side right now; the board keeps running
        self.paced.host_write(data)
        self.flow.took()
        self.pacer.poke()

    def _tick(self) -> None:
        out = self.paced.advance()
        self.flow.check()
        if self.unplugged:
            self.unplugged_tx += len(out)
            return
        if out:
            self._pending_out += out
        self._flush()

    def _flush(self) -> None:
        if self.unplugged:
            return
        if self._pending_out:
            try:
                written = os.write(self._master, self._pending_out)
                del self._pending_out[:written]
            except OSError:
                pass  # the pty is full (nobody reading just now): keep the bytes for later
            excess = len(self._pending_out) - self._backlog
            if excess > 0:
                # Nobody read for longer than the backlog: the oldest bytes are gone, counted
                # rather than blocking the board.
                del self._pending_out[:excess]
                self.dropped_tx += excess
        # Bytes left over go out when the pty has room, not on the next deadline.
        loop = asyncio.get_running_loop()
        if self._pending_out and not self._writing:
            loop.add_writer(self._master, self._flush)
            self._writing = True
        elif not self._pending_out and self._writing:
            loop.remove_writer(self._master)
            self._writing = False

    async def close(self) -> None:
        await self.pacer.stop()
        if self.unplugged:
            return
        if self._writing:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_writer(self._master)
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

