"""``fpgalink.ports.pty``: the raw pty both servers offer a board on, and the writes to its
master side, which never block however little the host reads."""

from __future__ import annotations

import asyncio
import os
import select
import termios
from collections.abc import Iterator

import pytest

from fpgalink.ports import PtyOutput, RawPty, open_raw_pty


@pytest.fixture
def pty() -> Iterator[RawPty]:
    opened = open_raw_pty()
    try:
        yield opened
    finally:
        os.close(opened.master)
        os.close(opened.slave)


def test_a_raw_pty_echoes_nothing_and_its_master_never_blocks(pty: RawPty) -> None:
    master, slave, path = pty
    assert path == os.ttyname(slave)
    assert not os.get_blocking(master)
    assert not termios.tcgetattr(slave)[3] & (termios.ECHO | termios.ICANON)  # lflag
    os.write(slave, b"\x7e\x0d\x0a")  # a host's bytes arrive as they are
    assert os.read(master, 16) == b"\x7e\x0d\x0a"
    os.write(master, b"RE\x03")  # nothing comes back to the sender
    assert os.read(slave, 16) == b"RE\x03"
    assert select.select([master], [], [], 0)[0] == []


async def test_what_a_pty_cannot_take_waits_and_goes_once_the_host_reads(pty: RawPty
                                                                          ) -> None:
    output = PtyOutput(pty.master)
    sent = bytes(range(256)) * 4096  # 1 MiB: more than any pty's buffer holds
    output.write(sent)  # returns at once
    assert 0 < len(output.pending) < len(sent)
    received = bytearray()
    loop = asyncio.get_running_loop()
    done = loop.create_future()

    def readable() -> None:
        received.extend(os.read(pty.slave, 65536))
        if len(received) >= len(sent) and not done.done():
            done.set_result(None)

    loop.add_reader(pty.slave, readable)
    try:
        await asyncio.wait_for(done, 60)
    finally:
        loop.remove_reader(pty.slave)
    assert bytes(received) == sent and not output.pending


async def test_trim_drops_the_oldest_and_discard_stops_watching_the_master(pty: RawPty
                                                                            ) -> None:
    output = PtyOutput(pty.master)
    output.write(bytes(range(256)) * 4096)
    waiting = len(output.pending)
    kept = output.pending[-1000:]
    assert output.trim(1000) == waiting - 1000 and output.pending == kept  # the newest
    assert output.trim(5000) == 0
    assert output.discard() == 1000 and not output.pending
    # The loop no longer watches the master: it may be closed at once (an fd closed while
    # the loop watches it is a stale registration another fd may inherit).
    assert not asyncio.get_running_loop().remove_writer(pty.master)
