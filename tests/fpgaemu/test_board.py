"""Board scenarios: a stand-in firmware on the AXI port, round trips through fpgalink's
codec, determinism, and the speed the 1 ms telemetry scenario needs."""

from __future__ import annotations

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board, BoardConfig
from fpgaemu.uart import LineFaults
from fpgaemu.uartcommand import RxInterrupt
from fpgalink.protocol.framing import FrameDecoder, encode_frame

MS = 100_000


class EchoFirmware:
    """Answers each message with its content reversed, from the receive interrupt."""

    def attach(self, board: Board) -> None:
        self.board = board
        self.queue = TxQueue(board.axi)
        board.axi.on_rx_interrupt(self.on_rx)

    def on_rx(self, irq: RxInterrupt) -> None:
        content = self.board.axi.read_rx(irq.start_address, irq.length)
        self.board.axi.ack_rx(irq.start_address)
        self.queue.send(content[::-1])


class TelemetryFirmware:
    """Every period, a 52-byte message; received messages read and acknowledged."""

    def __init__(self, period: int = MS) -> None:
        self.period = period
        self.received = 0

    def attach(self, board: Board) -> None:
        self.board = board
        self.queue = TxQueue(board.axi)
        board.axi.on_rx_interrupt(self.on_rx)
        board.timeline.schedule(self.period, self.tick)

    def tick(self, cycle: int) -> None:
        t = (cycle // 100).to_bytes(4, "little")
        self.queue.send(b"TM00001{\x2a" + t + bytes(range(38)) + b"}")
        self.board.timeline.schedule(cycle + self.period, self.tick)

    def on_rx(self, irq: RxInterrupt) -> None:
        self.board.axi.read_rx(irq.start_address, irq.length)
        self.board.axi.ack_rx(irq.start_address)
        self.received += 1


def test_echo_round_trip_through_fpgalink_codec() -> None:
    board = Board()
    board.add_peripheral("firmware", EchoFirmware())
    contents = [b"hello", b"S P \\", bytes(range(200))]
    stop = 0
    for c in contents:
        stop = board.host_write(encode_frame(c))
    first_stop = len(encode_frame(contents[0])) * 1_000
    board.run_for(0.01)
    got = board.read_host_bytes_timed()
    decoder = FrameDecoder()
    assert decoder.feed(bytes(b for b, _ in got)) == [c[::-1] for c in contents]
    # The reply's START leaves in the cycle the request's STOP completed.
    assert got[0][1] == first_stop + 1_000
    assert stop < got[-1][1]


def test_same_seed_same_bytes_under_random_bit_errors() -> None:
    def run(seed: int) -> bytes:
        config = BoardConfig(seed=seed, rx_faults=LineFaults(bit_error_rate=0.002))
        board = Board(config)
        board.add_peripheral("firmware", EchoFirmware())
        for k in range(50):
            board.host_write(encode_frame(b"message %d" % k), k * 20_000)
        board.run_for(0.01)
        return board.read_host_bytes()

    assert run(7) == run(7)


def test_peripheral_names_are_unique() -> None:
    board = Board()
    board.add_peripheral("fw", EchoFirmware())
    try:
        board.add_peripheral("fw", EchoFirmware())
    except ValueError:
        pass
    else:
        raise AssertionError("duplicate peripheral accepted")


def test_one_ms_references_and_telemetry_through_the_whole_path() -> None:
    # Speed is measured in benchmarks/emulator.py, not asserted here.
    board = Board()
    firmware = TelemetryFirmware()
    board.add_peripheral("firmware", firmware)
    rv = encode_frame(b"RV00001{\x08" + bytes(8) + b"}")
    re_ = encode_frame(b"RE")
    out = bytearray()
    emulated_s = 1.0
    for ms in range(int(emulated_s * 1000)):
        board.host_write(rv if ms % 100 else rv + re_)
        board.run_until((ms + 1) * MS)
        out += board.read_host_bytes()
    frames = [f for f in FrameDecoder().feed(bytes(out)) if isinstance(f, bytes)]
    assert len(frames) == 999  # the 1000th is still on the wire
    assert firmware.received == 1000
    assert board.global_enable


class DropNth:
    """Frame filter losing the ``n``-th frame (from 0) whose content starts with ``prefix``."""

    def __init__(self, prefix: bytes, n: int) -> None:
        self.prefix, self.n, self.seen = prefix, n, 0

    def __call__(self, content: bytes, cycle: int) -> bool:
        if not content.startswith(self.prefix):
            return True
        self.seen += 1
        return self.seen - 1 != self.n


def test_frame_filters_drop_the_nth_frame_each_way() -> None:
    board = Board()
    board.add_peripheral("firmware", EchoFirmware())
    board.uartcommand.frame_filter = DropNth(b"PS", 1)
    board.uartsend.frame_filter = DropNth(b"3", 0)  # replies are reversed
    for k in range(4):
        board.host_write(encode_frame(b"PS%d" % k))
    board.run_for(0.01)
    frames = FrameDecoder().feed(board.read_host_bytes())
    assert frames == [b"0SP", b"2SP"]  # PS1 lost on the way in, 3SP on the way out
    assert board.uartcommand.stats.filtered == 1
    assert board.uartsend.stats.filtered == 1
    assert board.uartwrite.stats.dropped_bytes == len(encode_frame(b"3SP"))


def test_dropping_re_lets_the_watchdog_lapse() -> None:
    board = Board()
    board.uartcommand.frame_filter = DropNth(b"RE", 1)
    first = board.host_write(b"SREP", 0)
    board.host_write(b"SREP", 20_000_000)
    board.run_for(0.5)
    assert not board.global_enable
    assert board.uartcommand.stats.direct_commands == 1
    assert first == 4_000
