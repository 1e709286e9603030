"""Opening ports from URLs: the scheme registry, the emulator's entry point, TCP against a
scripted board, and every way a URL can be wrong (a one-line PortError, never a traceback)."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import textwrap

import pytest

from fpgalink import PortError, open_link
from fpgalink.aio.transport import open_transport, register_scheme, scheme_of
from fpgalink.testing import MemoryTransport
from tests.support.fakeboard import FakeBoard

pytestmark = pytest.mark.timeout(30)


@pytest.mark.parametrize(
    ("url", "match"),
    [
        ("/dev/does-not-exist", r"/dev/does-not-exist"),
        ("socket://127.0.0.1:1", r"127\.0\.0\.1:1"),
        ("socket://127.0.0.1:99999", r"out of range"),
        ("socket://nohost", r"socket://HOST:PORT"),
        ("loop://", r"unsupported port"),
        ("rfc2217://localhost:1", r"unsupported port"),
        ("emu://?gear=sideways", r"gear"),
        ("emu://?colour=red", r"unknown emu:// option"),
        ("emu://?seed=x", r"seed must be an integer"),
    ],
)
async def test_bad_urls_are_one_port_error(url: str, match: str) -> None:
    with pytest.raises(PortError, match=match) as caught:
        await open_link(url).open()
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("baud", [0, -1, 49, 20_000_001, 99_999_999_999, 10**30])
async def test_impossible_baud_rates_are_refused_before_opening(baud: int) -> None:
    # ``emu://`` with --baud 99999999999 divided by zero in the emulator.
    with pytest.raises(ValueError, match="baud"):
        open_link("emu://", baud)
    with pytest.raises(PortError, match="baud"):
        await open_transport("emu://", baud, asyncio.Protocol)


def test_scheme_of() -> None:
    assert scheme_of("/dev/ttyUSB0") == ""
    assert scheme_of("socket://h:1") == "socket"
    assert scheme_of("EMU://") == "emu"


async def test_a_registered_scheme_opens_with_its_opener() -> None:
    opened: list[tuple[str, int]] = []

    async def opener(url, baud, factory):  # type: ignore[no-untyped-def]
        opened.append((url, baud))
        transport = MemoryTransport()
        protocol = factory()
        transport.set_protocol(protocol)
        return transport, protocol

    register_scheme("memtest", opener)
    async with open_link("memtest://x", 57_600) as link:
        assert link.url == "memtest://x"
    assert opened == [("memtest://x", 57_600)]


async def test_an_opener_that_raises_anything_becomes_a_port_error() -> None:
    async def opener(url, baud, factory):  # type: ignore[no-untyped-def]
        raise ValueError("this board is on fire")

    register_scheme("broken", opener)
    with pytest.raises(PortError, match="on fire"):
        await open_transport("broken://", 9600, asyncio.Protocol)


def test_fpgalink_finds_emu_through_the_entry_point_and_never_imports_fpgaemu_itself() -> None:
    code = textwrap.dedent("""
        import asyncio, sys
        import fpgalink, fpgalink.aio, fpgalink.cli, fpgalink.connection, fpgalink.testing
        assert not any(m.split(".")[0] == "fpgaemu" for m in sys.modules), "imported early"
        async def main():
            async with fpgalink.open_link("emu://") as link:
                print(await link.get_param("TsTimerPeriod"))
        asyncio.run(main())
        print("fpgaemu" in sys.modules)
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["1", "True"]


async def test_tcp_to_a_scripted_board() -> None:
    board = FakeBoard()
    url = await board.start()
    try:
        async with open_link(url) as link:
            assert await link.set_param("TsTimerPeriod", 5) == 5
            assert await link.get_param("Kp_Wheel_PidB") == pytest.approx(520.0)
    finally:
        await board.stop()


async def _open_recorded(path: str
                         ) -> tuple[asyncio.BaseTransport, asyncio.Future[Exception | None]]:
    """A serial port's transport, and a future its protocol's connection_lost resolves."""
    lost: asyncio.Future[Exception | None] = asyncio.get_running_loop().create_future()

    class Recorder(asyncio.Protocol):
        def connection_lost(self, exc: Exception | None) -> None:
            lost.set_result(exc)

    transport, _ = await open_transport(path, 1_000_000, Recorder)
    return transport, lost


async def test_a_write_to_a_vanished_serial_port_closes_the_link_without_a_traceback() -> None:
    """A pty whose other end is gone (a killed ``fpgaemu serve``, an unplugged adapter)
    fails the next write. pyserial-asyncio hands that to the loop's exception handler,
    which prints a traceback; the port must instead close, the protocol told why."""
    import os
    import pty

    loop = asyncio.get_running_loop()
    handled: list[dict[str, object]] = []
    loop.set_exception_handler(lambda _loop, context: handled.append(context))
    master, slave = pty.openpty()
    transport, lost = await _open_recorded(os.ttyname(slave))
    os.close(slave)
    os.close(master)
    try:
        assert isinstance(transport, asyncio.WriteTransport)
        transport.write(b"SRE" + b"P")  # fails at once: the pty has no other end
        exc = await asyncio.wait_for(lost, 5)
    finally:
        transport.close()
        loop.set_exception_handler(None)
    assert exc is not None, "the protocol must learn that the port failed"
    assert handled == []


def _drain(master: int, until: int) -> bytes:
    """Everything a pty's master side can read until ``until`` bytes came (blocking)."""
    import os
    import select

    got = bytearray()
    while len(got) < until:
        ready, _, _ = select.select([master], [], [], 10)
        assert ready, f"only {len(got)} of {until} bytes came"
        got += os.read(master, 65536)
    return bytes(got)


async def test_a_serial_port_queues_a_hundred_thousand_frames_each_once() -> None:
    """Issue 37: pyserial-asyncio's transport summed its whole write buffer on every write,
    so n frames queued cost O(n²) (100,000 frames: minutes, the loop deaf meanwhile). Ours
    keeps a running count: written to a pty nobody reads, every frame is queued, counted
    exactly, and reaches the other side whole and in order once it is read. (Before, this
    test ran into its timeout.)"""
    import os
    import pty
    import tty

    from fpgalink.protocol import DEFAULT_FRAMING, encode_frame

    master, slave = pty.openpty()
    tty.setraw(slave)
    frames = [encode_frame(b"PG%05d{\x02\x01\x00}" % (i % 100000), DEFAULT_FRAMING)
              for i in range(100_000)]
    transport, lost = await _open_recorded(os.ttyname(slave))
    os.close(slave)
    try:
        assert isinstance(transport, asyncio.WriteTransport)
        for frame in frames:
            transport.write(frame)
        total = sum(map(len, frames))
        waiting = transport.get_write_buffer_size()
        # The kernel took what fits in the pty (16 KiB or so); the rest waits, counted.
        assert 0 < total - waiting <= 65536 and waiting > total // 2
        expected = b"".join(frames)
        read = asyncio.ensure_future(asyncio.to_thread(_drain, master, len(expected)))
        got = await asyncio.wait_for(read, 60)
        assert got == expected
        assert transport.get_write_buffer_size() == 0
        transport.close()
        assert await asyncio.wait_for(lost, 5) is None
    finally:
        transport.close()
        os.close(master)


async def test_a_closing_serial_port_nobody_reads_does_not_hang() -> None:
    """Closing goes on writing what is queued (the RD a link wrote last must go out), the
    port's driver taking it; abort drops what is left and lets the port go at once."""
    import os
    import pty

    master, slave = pty.openpty()
    transport, lost = await _open_recorded(os.ttyname(slave))
    os.close(slave)
    try:
        assert isinstance(transport, asyncio.WriteTransport)
        transport.write(b"x" * 100_000)
        transport.close()
        await asyncio.sleep(0.05)
        assert not lost.done()  # still writing out what it took
        transport.abort()
        assert await asyncio.wait_for(lost, 5) is None
    finally:
        os.close(master)


async def test_a_link_refuses_requests_while_the_line_is_backed_up() -> None:
    """Issue 37: what a writer queues toward a board is bounded by line time. A link whose
    board does not read (a pty nobody reads) takes requests until a quarter second of line
    time waits unwritten, then refuses them with LineBusy, counted; an RD still goes, last.
    (Before: every request was queued, without end.)"""
    import os
    import pty
    import tty

    from fpgalink.aio.link import MAX_LINE_BACKLOG_S
    from fpgalink.errors import LineBusy
    from fpgalink.protocol import ParamGet

    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    try:
        async with open_link(path, reconnect=False) as link:
            sent = bytearray()
            with pytest.raises(LineBusy, match="ms of line time already waits") as caught:
                for _ in range(20_000):
                    sent += link.send(ParamGet(1, 0))
            assert "\n" not in str(caught.value)
            assert link.stats.line_busy == 1
            with pytest.raises(LineBusy):
                await link.set_param("TsTimerPeriod", 2)
            assert link.stats.line_busy == 2
            link.disable()
            written = await asyncio.wait_for(
                asyncio.to_thread(_drain, master, len(sent) + 4), 30)
        assert written == bytes(sent) + b"SRDP"
        # Refused once a quarter second of line time (25,000 bytes at 1 MBd) waited beside
        # what the kernel took (16 KiB or so on a pty).
        bound = MAX_LINE_BACKLOG_S * 100_000
        assert bound < len(sent) <= bound + 65536
    finally:
        os.close(master)
