"""The USB-UART bridge between the board's TX pin and a host's port: frames handed on whole
as the line idles, never a byte before its stop bit, never more than the latency timer late
while the line stays busy. Checked against the line itself (the bytes' completion cycles) on
a fake clock, and on a served pty."""

from __future__ import annotations

import asyncio
import os

from fpgaemu.build import build_board
from fpgaemu.serve import PacedBoard, PtyEndpoint
from fpgaemu.serving.bridge import BRIDGE_LATENCY_S, TxBridge
from fpgaemu.timeline import CLOCK_HZ
from fpgalink import Connection
from fpgalink.protocol import Enable, FrameDecoder, ParamSet
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


def bursts(timed: list[tuple[int, int]], byte_cycles: int) -> list[tuple[bytes, int]]:
    """The reference: bytes with their stop bits' ends, cut where the line idled (the next
    byte ended more than a byte time after the one before), each burst with its end."""
    out: list[tuple[bytes, int]] = []
    group: list[tuple[int, int]] = []
    for byte, done in timed:
        if group and done - group[-1][1] > byte_cycles:
            out.append((bytes(b for b, _ in group), group[-1][1]))
            group = []
        group.append((byte, done))
    if group:
        out.append((bytes(b for b, _ in group), group[-1][1]))
    return out


def test_each_burst_is_handed_on_whole_as_its_last_stop_bit_ends() -> None:
    now, ref_now = [100.0], [100.0]
    paced, reference = streaming_board(now), streaming_board(ref_now)
    bridge = TxBridge(paced)
    chunks: list[tuple[bytes, int]] = []  # what the host got, and the board's cycle then
    timed: list[tuple[int, int]] = []
    for _ in range(int(0.02 / STEP_S)):  # 20 ms: ~20 TM and the echoes
        now[0] += STEP_S
        ref_now[0] += STEP_S
        paced.run()
        out = bridge.take()
        if out:
            chunks.append((out, paced.board.now))
        reference.run()
        timed += reference.board.read_host_bytes_timed()
    expected = bursts(timed, paced.board.uartwrite.cycles_per_byte)
    if bridge.held:  # a frame still on the pin when the run stopped
        expected = expected[:-1]
    assert len(expected) >= 18
    assert [c for c, _ in chunks] == [b for b, _ in expected]
    step = round(STEP_S * CLOCK_HZ)
    for (_, handed_at), (_, ended_at) in zip(chunks, expected, strict=True):
        # At the first wake-up after the burst's last stop bit: never before, never later.
        assert ended_at <= handed_at < ended_at + step + 1
    assert sum(whole_frames(c) for c, _ in chunks) == len(chunks)  # each TM alone
    assert bridge.handovers == len(chunks)


def test_a_burst_longer_than_the_latency_timer_goes_out_within_it() -> None:
    now = [5.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    bridge = TxBridge(paced)
    burst = bytes(range(256)) + bytes(44)  # 300 bytes back to back: 3 ms of line
    paced.board.uartwrite.transmit(burst)
    got = bytearray()
    handed: list[tuple[int, int]] = []  # (the oldest byte's hold, the hand-on) in cycles
    held_since: int | None = None
    while len(got) < len(burst):
        now[0] += STEP_S
        paced.run()
        wake = bridge.next_wake()
        out = bridge.take()
        if out:
            assert held_since is not None
            handed.append((held_since, paced.board.now))
            got += out
            held_since = None
        elif bridge.held and held_since is None:
            held_since = paced.board.now
            wake = bridge.next_wake()
            # The serving loop is asked to wake when the latency timer runs out.
            assert wake == paced.time_of(held_since + LATENCY + 1)
        if bridge.held == 0 and not out:
            assert wake is None
    assert bytes(got) == burst
    assert len(handed) >= 3
    step = round(STEP_S * CLOCK_HZ)
    for since, at in handed[:-1]:  # the line still busy: the latency timer's doing
        assert LATENCY <= at - since < LATENCY + step + 1
    assert not paced.tx_busy()


def test_what_the_bridge_held_goes_with_an_unplugged_port() -> None:
    now = [5.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    bridge = TxBridge(paced)
    paced.board.uartwrite.transmit(b"x" * 50)
    now[0] += 0.0002  # 20 bytes ended
    paced.run()
    assert bridge.take() == b""
    held = bridge.held
    assert 19 <= held <= 20
    assert bridge.discard() == held and bridge.held == 0 and bridge.next_wake() is None
    now[0] += 0.001
    paced.run()
    assert bridge.take() == b"x" * (50 - held)  # the rest of the frame, as it ended


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
        loop.remove_reader(fd)
        drain()
        assert broken == [] and decoder.stats.dropped_bytes == 0
        assert decoder.pending == 0 and endpoint.bridge.handovers <= len(frames)
        assert endpoint.bridge.handovers >= 100  # it did hand frames on, one by one mostly
    finally:
        os.close(fd)
        await endpoint.close()
