"""The USB-UART bridge between the board's TX pin and a host's port: frames handed on whole
as the line idles, never a byte before its stop bit, never more than the latency timer late
while the line stays busy. Checked against the line itself (the bytes' completion cycles) on
a fake clock, and on a served pty."""

from __future__ import annotations

import asyncio
import os

from fpgaemu.build import build_board
from fpgaemu.serve import PacedBoard, PtyEndpoint, TcpEndpoint
from fpgaemu.serving.bridge import BRIDGE_LATENCY_S, TxBridge
from fpgaemu.timeline import CLOCK_HZ
from fpgalink import Connection
from fpgalink.protocol import DEFAULT_FRAMING, Enable, FrameDecoder, ParamSet
from tests.support.wire import sent

STEP_S = 50e-6  #: how often the fake serving loop wakes: finer than a byte's 10 µs × 5
LATENCY = round(BRIDGE_LATENCY_S * CLOCK_HZ)


def streaming_board(now: list[float]) -> PacedBoard:
    """A board sending telemetry every millisecond (and echoing the requests that asked)."""
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    host = Connection(baud=None)
    paced.host_write(sent(Enable(), host) + sent(ParamSet(2, 0, 1, 1), host))
    return paced


def whole_frames(chunk: bytes) -> int:
    """How many frames ``chunk`` is; fails unless it is frames whole and nothing else."""
    decoder = FrameDecoder()
    items = decoder.feed(chunk)
    assert all(isinstance(item, bytes) for item in items), items
    assert decoder.pending == 0
    return len(items)


def frame_ends(chunk: bytes) -> list[int]:
    """The index of each frame's last byte in ``chunk`` (its STOP, not an escaped one)."""
    ends, escaped = [], False
    for i, byte in enumerate(chunk):
        if escaped:
            escaped = False
        elif byte == DEFAULT_FRAMING.skip:
            escaped = True
        elif byte == DEFAULT_FRAMING.stop:
            ends.append(i)
    return ends


def test_each_frame_is_handed_on_whole_at_the_first_wake_up_after_it_ends() -> None:
    now, ref_now = [100.0], [100.0]
    paced, reference = streaming_board(now), streaming_board(ref_now)
    bridge = TxBridge(paced)
    chunks: list[tuple[bytes, int]] = []  # what the host got, and the board's cycle then
    timed: list[tuple[int, int]] = []  # the line itself: each byte and when it ended
    for _ in range(int(0.03 / STEP_S)):  # 30 ms: ~30 TM and the echoes
        now[0] += STEP_S
        ref_now[0] += STEP_S
        paced.run()
        out = bridge.take()
        if out:
            chunks.append((out, paced.board.now))
        reference.run()
        timed += reference.board.read_host_bytes_timed()
    wire = b"".join(c for c, _ in chunks)
    assert len(wire) >= 28 * 54
    assert wire == bytes(b for b, _ in timed[:len(wire)])  # every byte, in order
    step = round(STEP_S * CLOCK_HZ)
    at = 0
    for chunk, handed_at in chunks:
        assert whole_frames(chunk) == len(frame_ends(chunk))
        ends = [timed[at + i][1] for i in frame_ends(chunk)]
        # Never before its last stop bit; at the first wake-up after the first frame in it
        # ended (a frame that had ended by a wake-up was handed on then, not held).
        assert ends[-1] <= handed_at < ends[0] + step + 1
        at += len(chunk)
    assert bridge.handovers == len(chunks)


def test_a_frame_longer_than_the_latency_timer_goes_out_within_it() -> None:
    now = [5.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    line = paced.board.uartwrite
    bridge = TxBridge(paced)
    long_frame = bytes(range(256)) + bytes(44)  # 300 bytes back to back: 3 ms of line
    line.transmit(long_frame)
    got = bytearray()
    parts = 0
    step = round(STEP_S * CLOCK_HZ)
    while len(got) < len(long_frame):
        now[0] += STEP_S
        paced.run()
        oldest = line.oldest_unread
        assert oldest is not None
        # The serving loop is asked to wake when the latency timer runs out.
        assert bridge.next_wake() == paced.time_of(oldest + LATENCY + 1)
        out = bridge.take()
        if out and len(got) + len(out) < len(long_frame):  # the frame not ended yet
            parts += 1
            assert oldest + LATENCY <= paced.board.now < oldest + LATENCY + step
        elif not out:
            assert paced.board.now < oldest + LATENCY
        got += out
    assert bytes(got) == long_frame
    assert parts >= 2
    assert line.oldest_unread is None and bridge.next_wake() is None


async def test_a_host_on_a_served_pty_reads_a_frame_once_not_in_parts() -> None:
    # What the host sees under any load: every frame whole, and no more hand-overs than
    # frames (a starved serve catching up may hand on several at once, never a part).
    import termios
    import tty

    endpoint = PtyEndpoint(PacedBoard(build_board()))
    endpoint.start()
    loop = asyncio.get_running_loop()
    fd = os.open(endpoint.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    decoder = FrameDecoder()
    frames: list[bytes] = []
    broken: list[object] = []
    enough = loop.create_future()

    def drain() -> None:
        while True:
            try:
                data = os.read(fd, 65536)
            except BlockingIOError:
                return
            for item in decoder.feed(data):
                if isinstance(item, bytes):
                    frames.append(item)
                else:
                    broken.append(item)

    def readable() -> None:
        drain()
        if len(frames) >= 200 and not enough.done():
            enough.set_result(None)

    try:
        tty.setraw(fd, termios.TCSANOW)
        loop.add_reader(fd, readable)
        host = Connection(baud=None)
        os.write(fd, sent(Enable(), host) + sent(ParamSet(2, 0, 1, 1), host))
        await asyncio.wait_for(enough, 60.0)
        await endpoint.pacer.stop()  # nothing handed on between the count and the drain
        loop.remove_reader(fd)
        drain()
        assert broken == [] and decoder.stats.dropped_bytes == 0
        assert decoder.pending == 0 and endpoint.bridge.handovers <= len(frames)
    finally:
        os.close(fd)
        await endpoint.close()


async def test_a_tcp_host_gets_a_frame_in_one_segment_not_in_parts() -> None:
    # The same bridge in front of a TCP host: a frame is one write, whole (the host may
    # read several at once; a part never).
    endpoint = TcpEndpoint(PacedBoard(build_board()), "127.0.0.1", 0)
    await endpoint.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", endpoint.port)
        host = Connection(baud=None)
        writer.write(sent(Enable(), host) + sent(ParamSet(2, 0, 1, 1), host))
        decoder = FrameDecoder()
        frames = 0
        while frames < 200:
            data = await asyncio.wait_for(reader.read(65536), 10.0)
            assert data, "serve closed the connection"
            items = decoder.feed(data)
            assert all(isinstance(item, bytes) for item in items), items
            # On loopback a write is one segment, and a read returns whole segments.
            assert decoder.pending == 0, f"a frame cut after {decoder.pending} bytes"
            frames += len(items)
        writer.close()
        assert decoder.stats.dropped_bytes == 0
    finally:
        await endpoint.close()
