"""The emulator's golden trace: a mixed scenario (telemetry, references every millisecond,
parameter sets and gets, garbage, a timer-period change, a watchdog lapse, re-enable, RD),
and every byte the board put on its TX pin with the cycle its stop bit ended.

Recorded before the house was restructured and required unchanged by every change that is
not meant to change behaviour — the restructure, and every speed-up. Changes that were
meant to: the power-up PID runs on the float32 value the board stores (Ti 0.23999999 s, as
it reports it); then the fidelity work (2026-11-22) — the motor winding's inductance makes
the reported current lag the duty, and ActiveController 3, which the scenario sets on
channel B, is now run (the hardware current loop) instead of refused. The speed-ups of the
performance work came after that and keep this trace. A digest keeps the test small; on a
mismatch the first diverging byte is reported, and the scenario can be rerun against an
older checkout to compare. Since issue 29 the same trace is required of the C firmware core
running in the emulator in place of the Python model.
"""

from __future__ import annotations

import hashlib
import struct

from fpgaemu import build_board, ms
from fpgaemu.board import Board
from fpgalink.protocol import encode_frame

GOLDEN_BYTES = 146_471
GOLDEN_SHA256 = "65cd7bb116c2e52f4facc05bfa5ebb598957d86fdb32d0774c5bad20cc9c6c21"


def _counted(msg_id: bytes, counter: int, body: bytes) -> bytes:
    return encode_frame(msg_id + b"%05d" % counter + b"{" + bytes((len(body),)) + body + b"}")


def ps(counter: int, param_id: int, channel: int, value_type: int, value: float) -> bytes:
    raw = struct.pack("<i", int(value)) if value_type == 1 else struct.pack("<f", value)
    return _counted(b"PS", counter, bytes((param_id, channel, value_type)) + raw)


def pg(counter: int, param_id: int, channel: int) -> bytes:
    return _counted(b"PG", counter, bytes((param_id, channel)))


def rv(counter: int, a: float, b: float) -> bytes:
    return _counted(b"RV", counter, struct.pack("<ff", a, b))


def scenario() -> list[tuple[int, bytes]]:
    """(cycle, bytes) the host writes. Built by hand, not through the library, so a change
    in the host's codec cannot move the trace."""
    writes: list[tuple[int, bytes]] = []
    counter = iter(range(100_000))
    re, rd = encode_frame(b"RE"), encode_frame(b"RD")
    writes.append((ms(1), ps(next(counter), 2, 0, 1, 1)))  # GetDataPeriodical = 1
    writes.append((ms(3), re))
    for k in range(2000):  # RE every 100 ms, RV every 1 ms for 2 s
        t = ms(5) + k * ms(1)
        if k % 100 == 0:
            writes.append((t, re))
        ref = 45.0 if k < 1000 else -30.0
        writes.append((t + 137, rv(next(counter), ref, ref / 2)))
        if k == 500:
            writes.append((t + 400, ps(next(counter), 8, 1, 2, 400.0)))
        if k == 700:
            writes.append((t + 400, pg(next(counter), 8, 1) + b"xx garbage \\S"
                           + ps(next(counter), 4, 2, 1, 3)))
        if k == 900:
            writes.append((t + 400, ps(next(counter), 1, 0, 1, 2)))  # TsTimerPeriod 2
        if k == 1300:
            writes.append((t + 400, ps(next(counter), 1, 0, 1, 1)))
        if k == 1500:
            writes.append((t + 400, ps(next(counter), 7, 2, 1, -1) + ps(next(counter), 6, 1,
                                                                            1, 1000)))
    # Silence: the watchdog lapses 300 ms after the last RE; then re-enable, and RD.
    writes.append((ms(2600), re))
    writes.append((ms(2700), rd))
    return writes


def trace(board: Board, until: int = ms(2900)) -> list[tuple[int, int]]:
    tx: list[tuple[int, int]] = []
    for cycle, data in scenario():
        board.run_until(cycle)
        board.host_write(data, cycle)
        tx += board.read_host_bytes_timed()
    board.run_until(until)
    tx += board.read_host_bytes_timed()
    return tx


def digest(tx: list[tuple[int, int]]) -> str:
    h = hashlib.sha256()
    for byte, cycle in tx:
        h.update(struct.pack("<BQ", byte, cycle))
    return h.hexdigest()


def test_the_board_reproduces_its_golden_trace(firmware_kind: str) -> None:
    # The C firmware core (firmware/, issue 29) must put the very same bytes on the wire at
    # the very same cycles as the Python model it was written after.
    tx = trace(build_board(firmware=firmware_kind))
    assert (len(tx), digest(tx)) == (GOLDEN_BYTES, GOLDEN_SHA256)
