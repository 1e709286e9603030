"""A board behind a pseudo-terminal (``fpgaemu serve --pty``). The pty itself, the writes to
it and its ``--link`` are :mod:`fpgalink.ports`', which ``fpgalink-cli router`` shares."""

from __future__ import annotations

import asyncio
import contextlib
import os
from pathlib import Path

from fpgaemu.serving.bridge import TxBridge
from fpgaemu.serving.loop import Pacer, say
from fpgaemu.serving.pacing import TX_BACKLOG_S, PacedBoard, RxFlow, earliest, schedule_unplugs
from fpgalink.ports import LinkError, LinkTaken, PtyOutput, make_link, open_raw_pty, pty_where
from fpgalink.ports import remove_own_link as remove_link

__all__ = ["PtyEndpoint"]


class PtyEndpoint:
    """One board behind a pseudo-terminal. We keep the slave side open ourselves, so a host
    that closes and reopens the path finds the same board still running. Host bytes are read
    only as fast as the line carries them: while
    :data:`~fpgaemu.serving.pacing.RX_BACKLOG_BYTES` wait, the pty is not read and the
    host's ``write`` waits in the kernel's tty buffer. The board's bytes reach the pty as a
    USB-UART bridge hands them over (:class:`~fpgaemu.serving.bridge.TxBridge`): a frame
    whole, as it ends."""

    def __init__(self, paced: PacedBoard) -> None:
        self.paced = paced
        self._open_pty()
        self.flow = RxFlow(paced, self._pause, self._resume)
        self.bridge = TxBridge(paced)
        self.pacer = Pacer(self._tick, self._next_wake)
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
        self._output = PtyOutput(self._master)

    def start(self) -> None:
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        self.pacer.start()
        schedule_unplugs(self.paced, self._unplug, self._replug)

    def remove_own_link(self) -> None:
        """Remove the ``--link`` if it points at the pty served now: another serve or router
        may have taken the name since. An unplugged pty's link went with it, and its freed
        number may be another's now."""
        if self.link is not None and not self.unplugged:
            remove_link(self.link, self.path)

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
        self.unplugged_tx += self._output.discard()
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
        shown = pty_where(self.path, self.link)
        if self.link is not None:
            try:
                make_link(self.link, self.path)  # a stale link (its pty gone) is replaced
            except LinkTaken:
                # Taken while unplugged (another serve or router): theirs, left alone.
                shown = f"{self.path} (--link {self.link} is now another's, left alone)"
            except LinkError as exc:
                shown = f"{self.path} ({exc})"
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

    def _next_wake(self) -> float | None:
        return earliest(self.flow.next_wake(), self.bridge.next_wake())

    def _tick(self) -> None:
        self.paced.run()
        self.flow.check()
        out = self.bridge.take()
        if self.unplugged:
            self.unplugged_tx += len(out)
            return
        # Bytes the pty cannot take now go out when it has room, not on the next deadline.
        self._output.write(out)
        # Nobody read for longer than the backlog: the oldest bytes are gone, counted rather
        # than blocking the board.
        self.dropped_tx += self._output.trim(self._backlog)

    async def close(self) -> None:
        await self.pacer.stop()
        if self.unplugged:
            return
        self._output.discard()
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

