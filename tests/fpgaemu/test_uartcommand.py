"""uartcommand: the hardware decoder, RX RAM halves, interrupt timing, error counters, and
agreement with fpgalink's FrameDecoder.

global_enable: RE raises it, RD drops it in its STOP cycle, the 300 ms watchdog is an
exact deadline counted from the STOP of the last RE."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.board import Board
from fpgaemu.uart import ByteRun, LineFaults
from fpgaemu.uartcommand import WATCHDOG_CYCLES, EnableCause, EnableChange, RxInterrupt
from fpgalink.protocol.framing import DEFAULT_FRAMING, FrameDecoder, Framing, encode_frame
from tests.support.reference import NaiveUartCommand, naive_line_timing

S, P, K = b"S", b"P", b"\\"


class Recorder:
    """A processor that reads (and optionally acknowledges) each frame in its interrupt."""

    def __init__(self, board: Board, ack: bool = True) -> None:
        self.board = board
        self.ack = ack
        self.frames: list[tuple[int, int, bytes]] = []
        board.axi.on_rx_interrupt(self.on_rx)

    def on_rx(self, irq: RxInterrupt) -> None:
        assert irq.cycle == self.board.now
        content = self.board.axi.read_rx(irq.start_address, irq.length)
        self.frames.append((irq.cycle, irq.start_address, content))
        if self.ack:
            self.board.axi.ack_rx(irq.start_address)


def test_take_rx_is_read_rx_then_ack_rx() -> None:
    # The interrupt handler's one call against its two; a third frame must not overrun.
    for take in (True, False):
        board = Board()
        irqs: list[RxInterrupt] = []
        board.axi.on_rx_interrupt(irqs.append)
        board.run_until(board.host_write(b"SfirstP" + b"SsecondP"))
        if take:
            got = board.axi.take_rx(irqs[0].start_address, irqs[0].length)
        else:
            got = board.axi.read_rx(irqs[0].start_address, irqs[0].length)
            board.axi.ack_rx(irqs[0].start_address)
        assert got == b"first"
        board.run_until(board.host_write(b"SXP"))
        assert (board.uartcommand.stats.overruns, board.axi.read_rx(200, 6)) == (0, b"second")
        assert board.axi.read_rx(0, 1) == b"X"
    board = Board()
    with pytest.raises(ValueError, match="not the start of an RX RAM half"):
        board.axi.take_rx(3, 1)


def test_frame_lands_byte_exact_and_interrupts_at_stop_completion() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"SabcdeP", 1_000)
    board.run_for(0.001)
    # START completes at 2,000; the STOP, the 7th byte, at 1,000 + 7 × 1,000.
    assert cpu.frames == [(8_000, 0, b"abcde")]
    assert board.axi.rx_start_address == 0 and board.axi.rx_length == 5
    assert board.axi.read_rx_word(0) == int.from_bytes(b"abcd", "little")
    assert board.blk_mem_gen_rx.read_bytes(4, 1) == b"e"


def test_frames_alternate_between_the_halves() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"SoneP" + b"StwoP" + b"SthreeP")
    board.run_for(0.001)
    assert [(a, c) for _, a, c in cpu.frames] == [(0, b"one"), (200, b"two"), (0, b"three")]
    assert board.uartcommand.stats.overruns == 0


def test_a_second_frame_does_not_overwrite_an_unread_first() -> None:
    board = Board()
    cpu = Recorder(board, ack=False)
    board.host_write(b"SfirstP" + b"SsecondP")
    board.run_for(0.001)
    assert board.axi.read_rx(0, 5) == b"first"
    assert board.axi.read_rx(200, 6) == b"second"
    assert board.uartcommand.stats.overruns == 0
    assert len(cpu.frames) == 2


def test_a_third_frame_before_the_first_is_acknowledged_is_an_overrun() -> None:
    board = Board()
    Recorder(board, ack=False)
    board.host_write(b"SfirstP" + b"SsecondP" + b"SXP")
    board.run_for(0.001)
    assert board.axi.read_rx(0, 5) == b"Xirst"  # the logic overwrote the older half
    assert board.uartcommand.stats.overruns == 1
    assert board.uartcommand.stats.frames == 3


def test_acknowledging_in_time_avoids_the_overrun() -> None:
    board = Board()
    irqs: list[RxInterrupt] = []
    board.axi.on_rx_interrupt(irqs.append)
    end = board.host_write(b"SfirstP" + b"SsecondP")
    board.run_until(end)
    board.axi.ack_rx(irqs[0].start_address)
    board.host_write(b"SXP")
    board.run_for(0.001)
    assert board.uartcommand.stats.overruns == 0
    assert not board.uartcommand.stats.overflows


def test_overflow_at_the_201st_content_byte() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"S" + b"x" * 200 + b"P")
    board.run_for(0.01)
    assert cpu.frames[-1][2] == b"x" * 200
    board.host_write(b"S" + b"y" * 201 + b"zP" + b"SokP")
    board.run_for(0.01)
    stats = board.uartcommand.stats
    assert stats.overflows == 1
    assert stats.noise_bytes == 2  # "zP" after the overflow: hunting again
    assert [c for _, _, c in cpu.frames] == [b"x" * 200, b"ok"]


def test_a_clean_frame_one_byte_too_long_is_an_overflow_whole_or_in_pieces() -> None:
    # START, 201 plain bytes, STOP: in one run (the clean-frame shortcut's case) or in two.
    for pieces in ([b"S" + b"q" * 201 + b"P"], [b"S" + b"q" * 100, b"q" * 101 + b"P"]):
        board = Board()
        cpu = Recorder(board)
        for piece in pieces:
            board.host_write(piece, board.uartread.line_free_at)
        board.run_for(0.01)
        stats = board.uartcommand.stats
        # The 201st byte overflows; hunting again, the STOP is noise.
        assert (stats.overflows, stats.noise_bytes, cpu.frames) == (1, 1, []), pieces


def test_escaped_specials_are_content() -> None:
    board = Board()
    cpu = Recorder(board)
    content = b"a" + S + b"b" + P + b"c" + K + b"d"
    wire = encode_frame(content)
    assert wire == b"Sa\\Sb\\Pc\\\\dP"
    board.host_write(wire)
    board.run_for(0.001)
    assert cpu.frames[0][2] == content


def test_a_frame_interrupted_by_start_is_discarded_and_counted() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"SabcSdefP")
    board.run_for(0.001)
    assert [c for _, _, c in cpu.frames] == [b"def"]
    assert board.uartcommand.stats.restarts == 1


def test_noise_between_frames_is_dropped_and_counted() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"zz\\PSaP??\x00SbP!")
    board.run_for(0.001)
    assert [c for _, _, c in cpu.frames] == [b"a", b"b"]
    assert board.uartcommand.stats.noise_bytes == 4 + 3 + 1


def test_direct_commands_are_consumed_by_the_logic() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"SREP" + b"SmsgP" + b"SRDP" + b"SREXP")
    board.run_for(0.001)
    assert [(a, c) for _, a, c in cpu.frames] == [(0, b"msg"), (200, b"REX")]
    assert board.uartcommand.stats.direct_commands == 2


def test_empty_frames_are_delivered() -> None:
    board = Board()
    cpu = Recorder(board)
    board.host_write(b"SP")
    board.run_for(0.001)
    assert cpu.frames == [(2_000, 0, b"")]


def test_the_processor_sees_a_partial_frame_at_the_exact_cycle() -> None:
    board = Board()
    board.host_write(b"Sabcdef", 0)
    board.run_until(3_999)  # START at 1,000, 'a' at 2,000, 'b' at 3,000
    assert board.blk_mem_gen_rx.read_bytes(0, 3) == b"ab\x00"
    board.run_until(4_000)
    assert board.blk_mem_gen_rx.read_bytes(0, 3) == b"abc"


def test_custom_framing_bytes() -> None:
    framing = Framing(start=0x02, stop=0x03, skip=0x10)
    board = Board(framing=framing)
    cpu = Recorder(board)
    content = b"\x02S\x03P\x10\\"
    board.host_write(encode_frame(content, framing) + b"SxP")
    board.run_for(0.001)
    assert [c for _, _, c in cpu.frames] == [content]


def test_framing_set_by_the_processor_at_start_up() -> None:
    board = Board()
    cpu = Recorder(board)
    framing = Framing(start=ord("<"), stop=ord(">"), skip=ord("~"))
    board.axi.set_framing(framing)
    board.host_write(b"SaP<b~>>")
    board.run_for(0.001)
    assert [c for _, _, c in cpu.frames] == [b"b>"]
    board.axi.write_tx(b">")
    board.axi.strobe_tx()
    board.run_for(0.001)
    assert board.read_host_bytes() == b"<~>>"


garbage = st.binary(max_size=12).map(lambda b: b.replace(b"S", b"s"))
special_heavy = st.lists(st.sampled_from([b"S", b"P", b"\\", b"x", b"RE", b"RD", b"\x00"]),
                         max_size=30).map(b"".join)


@st.composite
def streams(draw: st.DrawFn) -> bytes:
    parts: list[bytes] = []
    for _ in range(draw(st.integers(0, 6))):
        kind = draw(st.integers(0, 4))
        if kind == 0:
            parts.append(draw(garbage))
        elif kind == 1:
            parts.append(draw(special_heavy))
        elif kind == 2:
            parts.append(b"S" + b"q" * draw(st.integers(195, 205)) + b"P")
        else:
            parts.append(encode_frame(draw(st.binary(max_size=60))))
    return b"".join(parts)


@given(streams(), st.lists(st.integers(1, 40), min_size=1, max_size=8),
       st.lists(st.integers(0, 3_000), min_size=1, max_size=8))
def test_stored_frames_equal_fpgalink_decoder_frames(
    stream: bytes, chunk_sizes: list[int], gaps: list[int]
) -> None:
    board = Board()
    cpu = Recorder(board)
    writes: list[tuple[int, bytes]] = []
    pos, cycle, k = 0, 0, 0
    while pos < len(stream):
        size = chunk_sizes[k % len(chunk_sizes)]
        cycle += gaps[k % len(gaps)]
        chunk = stream[pos : pos + size]
        board.host_write(chunk, cycle)
        writes.append((cycle, chunk))
        pos += size
        k += 1
        # Sometimes let time pass between writes, sometimes pile writes up in the future.
        if k % 3 == 0:
            board.run_until(max(board.now, cycle))
    end = 0 if not writes else board.uartread.line_free_at
    board.run_until(max(board.now, end))

    decoder = FrameDecoder(DEFAULT_FRAMING)
    expected = [f for f in decoder.feed(stream) if isinstance(f, bytes)]
    expected = [f for f in expected if f not in (b"RE", b"RD")]
    assert [c for _, _, c in cpu.frames] == expected

    stats = board.uartcommand.stats
    assert stats.restarts == decoder.stats.restarts
    assert stats.overflows == decoder.stats.overflows
    assert stats.noise_bytes == decoder.stats.noise_bytes

    # Cycle by cycle: interrupt cycles, halves and enable edges match the per-byte model.
    model = NaiveUartCommand()
    model.feed(naive_line_timing(writes, board.cycles_per_byte))
    assert cpu.frames == model.interrupts


@given(streams(), st.lists(st.integers(1, 40), min_size=1, max_size=8),
       st.lists(st.integers(0, 3_000), min_size=1, max_size=8),
       st.lists(st.tuples(st.integers(0, 10**6), st.integers(-1, 1)), min_size=1,
                max_size=12))
def test_what_an_observer_sees_at_any_cycle_is_every_byte_completed_by_then(
    stream: bytes, chunk_sizes: list[int], gaps: list[int], looks: list[tuple[int, int]]
) -> None:
    # The lazy processing (sync, the STOP candidate, the early return while the next byte is
    # still on the wire) against a per-byte decoder fed what has completed by each look.
    board = Board()
    Recorder(board)
    writes: list[tuple[int, bytes]] = []
    pos, cycle, k = 0, 0, 0
    while pos < len(stream):  # all written ahead, at future cycles
        size = chunk_sizes[k % len(chunk_sizes)]
        cycle += gaps[k % len(gaps)]
        writes.append((cycle, stream[pos : pos + size]))
        board.host_write(stream[pos : pos + size], cycle)
        pos += size
        k += 1
    timed = naive_line_timing(writes, board.cycles_per_byte)
    decoder = FrameDecoder(DEFAULT_FRAMING)
    fed = 0
    # Looks at a byte's completion cycle, or one cycle either side of it.
    for look in sorted({max(0, timed[x % len(timed)][1] + d) for x, d in looks if timed}):
        board.run_until(look)
        completed = sum(1 for _, at in timed if at <= look)
        decoder.feed(stream[fed:completed])
        fed = completed
        stats = board.uartcommand.stats  # the observer's read: a sync at this cycle
        assert (stats.noise_bytes, stats.restarts, stats.overflows) == (
            decoder.stats.noise_bytes, decoder.stats.restarts, decoder.stats.overflows), look
        assert stats.frames + stats.direct_commands == decoder.stats.frames, look


@given(st.lists(st.binary(max_size=30), max_size=8), st.integers(0, 2**16),
       st.sampled_from([0.0, 0.001, 0.01]))
def test_uneven_runs_from_a_noisy_line_match_the_models(
    contents: list[bytes], seed: int, ber: float
) -> None:
    board = Board(seed=seed, rx_faults=LineFaults(bit_error_rate=ber, break_stop={3, 40}))
    cpu = Recorder(board)
    runs: list[ByteRun] = []
    deliver = board.uartread.sink

    def tap(run: ByteRun) -> None:
        runs.append(run)
        deliver(run)

    board.uartread.sink = tap
    for k, content in enumerate(contents):
        board.host_write(encode_frame(content), k * 7_000)
        if k % 2:
            board.run_until(k * 7_000 + 3_500)
    board.run_until(max(board.now, board.uartread.line_free_at + 10_000))
    timed = [pair for run in runs for pair in run.timed()]
    model = NaiveUartCommand()
    model.feed(timed)
    assert cpu.frames == model.interrupts
    decoder = FrameDecoder()
    decoder.feed(bytes(b for b, _ in timed))
    assert board.uartcommand.stats.noise_bytes == decoder.stats.noise_bytes
    assert board.uartcommand.stats.restarts == decoder.stats.restarts


RE, RD = b"SREP", b"SRDP"


def watch(board: Board) -> list[EnableChange]:
    changes: list[EnableChange] = []
    board.axi.on_global_enable(changes.append)
    return changes


def test_watchdog_constant_is_300_ms_of_the_clock() -> None:
    assert WATCHDOG_CYCLES == 30_000_000


def test_enable_falls_exactly_300_ms_after_the_last_re_stop() -> None:
    board = Board()
    changes = watch(board)
    stop = board.host_write(RE, 12_345)
    assert stop == 12_345 + 4_000
    board.run_until(stop - 1)
    assert not board.global_enable
    board.run_until(stop)
    assert board.global_enable
    board.run_until(stop + WATCHDOG_CYCLES - 1)
    assert board.global_enable
    board.run_until(stop + WATCHDOG_CYCLES)
    assert not board.global_enable
    assert changes == [
        EnableChange(stop, True, EnableCause.ENABLE),
        EnableChange(stop + WATCHDOG_CYCLES, False, EnableCause.WATCHDOG),
    ]


def test_re_every_299_ms_keeps_it_high_for_10_s() -> None:
    board = Board()
    changes = watch(board)
    period = 29_900_000
    last = 0
    for k in range(34):  # 34 × 299 ms ≈ 10.2 s
        last = board.host_write(RE, k * period)
        board.run_until(k * period + period // 2)
    assert board.now >= 10 * 100_000_000
    assert board.global_enable
    assert changes == [EnableChange(4_000, True, EnableCause.ENABLE)]
    board.run_until(last + WATCHDOG_CYCLES)
    assert changes[-1] == EnableChange(last + WATCHDOG_CYCLES, False, EnableCause.WATCHDOG)


def test_rd_drops_it_in_the_cycle_it_completes_and_disarms_the_watchdog() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(RE, 0)
    rd_stop = board.host_write(RD, 1_000_000)
    board.run_until(rd_stop - 1)
    assert board.global_enable
    board.run_until(rd_stop)
    assert not board.global_enable
    assert board.uartcommand.watchdog_deadline is None
    board.run_for(1.0)
    assert changes == [
        EnableChange(4_000, True, EnableCause.ENABLE),
        EnableChange(rd_stop, False, EnableCause.DISABLE),
    ]


def test_a_lapsed_watchdog_is_rearmed_by_the_next_re() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(RE, 0)
    board.run_for(0.5)
    assert not board.global_enable
    again = board.host_write(RE)
    board.run_until(again)
    assert board.global_enable
    assert board.uartcommand.watchdog_deadline == again + WATCHDOG_CYCLES
    board.run_until(again + WATCHDOG_CYCLES)
    assert not board.global_enable
    assert [c.enabled for c in changes] == [True, False, True, False]


def test_an_re_completing_in_the_lapse_cycle_keeps_enable_high() -> None:
    board = Board()
    changes = watch(board)
    first = board.host_write(RE, 0)
    board.host_write(RE, first + WATCHDOG_CYCLES - 4_000)
    board.run_until(first + 2 * WATCHDOG_CYCLES)
    assert [(c.cycle, c.enabled) for c in changes] == [
        (first, True), (first + 2 * WATCHDOG_CYCLES, False)
    ]


def test_re_inside_a_burst_is_timed_by_its_own_stop() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(b"SabcP" + RE + b"SxyzP", 0)
    board.run_for(0.001)
    assert changes[0].cycle == 9_000


@given(st.lists(st.tuples(st.integers(0, 45_000_000), st.sampled_from([RE, RD, b"SxP"])),
                max_size=8))
def test_edges_match_the_per_byte_model(steps: list[tuple[int, bytes]]) -> None:
    board = Board()
    changes = watch(board)
    writes: list[tuple[int, bytes]] = []
    cycle = 0
    for gap, data in steps:
        cycle += gap
        board.host_write(data, cycle)
        writes.append((cycle, data))
    end = cycle + 10 * WATCHDOG_CYCLES
    board.run_until(end)
    model = NaiveUartCommand()
    timed = naive_line_timing(writes, 1_000)
    model.feed(timed)
    model.finish(end)
    assert [(c.cycle, c.enabled) for c in changes] == model.enable


# --- the host unplugged mid-stream -------------------------------------------------------------


def test_bytes_not_yet_on_the_wire_when_the_host_goes_never_arrive() -> None:
    board = Board()
    frames: list[bytes] = []

    def on_frame(irq: RxInterrupt) -> None:
        frames.append(board.axi.read_rx(irq.start_address, irq.length))
        board.axi.ack_rx(irq.start_address)

    board.axi.on_rx_interrupt(on_frame)
    cpb = board.cycles_per_byte
    first = encode_frame(b"AB00001")  # 9 wire bytes
    second = encode_frame(b"CD00002")
    board.host_write(first + second, 0)
    # Unplugged while the 12th byte (the second frame's third) is on the wire: it still
    # arrives, nothing after it does.
    lost = board.host_unplugged(11 * cpb + cpb // 2)
    assert lost == len(first) + len(second) - 12
    board.run_until(100 * cpb)
    assert frames == [b"AB00001"]
    assert board.uartcommand.stats.bytes_received == 12
    assert board.uartread.line_free_at == 12 * cpb
    # The next host's bytes start right after the byte that made it.
    board.host_write(encode_frame(b"EF00003"), 100 * cpb)
    board.run_until(200 * cpb)
    assert frames == [b"AB00001", b"EF00003"]
