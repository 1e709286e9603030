"""Damaged telemetry accepted as valid, with and without the wire CRC (issue 29,
docs/protocol.md §7): at bit-error rates 1e-5 and 1e-4, how many TM frames per frame sent
reach the host's user as a valid ``Telemetry`` with other values than the board sent.

**Model (the fast one, stated).** A 1 kHz stream of TM frames (random but plausible
values, t_us advancing 1 ms a frame, counters in order), framed as the board frames them,
each byte 10 bit slots on the 8N1 line. Every slot is inverted independently with
probability BER: a data bit inverts that bit of the byte; an inverted start or stop bit
loses the byte (the receiver's framing error, as ``fpgaemu.uart.LineFaults`` does for a low
stop bit; for a start bit read high the emulator's receiver may instead resynchronise on a
falling edge inside the byte and deliver one or two garbage bytes — here the byte is lost,
which is damage all the same). The stream goes through the host's real decode path, a
``fpgalink.Connection`` (plain, or with its CRC on), and every ``Telemetry`` it delivers is
compared with what was sent under its counter.

**Cross-check (the emulator's own line model).** The same count on an emulated board (the
Python firmware at 1 kHz, ``tx-ber`` faults in ``uart.LineFaults`` with its start-bit
resynchronisation), fewer frames, so the fast model's figures can be held against it.

``python -m benchmarks.crc_ber`` (10^6 frames per case; ``--frames N``); ``--quick``: 10,000
frames and a 1 s cross-check (the smoke test).
"""

from __future__ import annotations

import random
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)
from fpgalink import Connection, Telemetry
from fpgalink.protocol import ChannelTelemetry, encode_frame, encode_telemetry
from fpgalink.protocol.crc import CRC16, append_crc

NAME = "crc_ber"
RATES = (1e-5, 1e-4)
DEFAULT_FRAMES = 1_000_000
QUICK_FRAMES = 10_000
#: Frames generated, damaged and decoded at a time (a counter is unique within two).
CHUNK = 50_000
CROSS_CHECK_S = 60.0
QUICK_CROSS_CHECK_S = 1.0
SEED = 29


@dataclass
class Tally:
    frames: int = 0  #: TM frames sent
    damaged: int = 0  #: frames with at least one inverted slot
    delivered: int = 0  #: Telemetry events the host's user got
    accepted_corrupt: int = 0  #: of those, with other values or another counter than sent
    crc_failures: int = 0  #: frames the host's CRC check dropped
    decode_errors: int = 0  #: frames the framing or the parser refused

    def result(self) -> dict[str, Any]:
        return {**self.__dict__, "accepted_corrupt_per_frame": self.accepted_corrupt
                / self.frames if self.frames else 0.0,
                "share_of_damaged_accepted": self.accepted_corrupt / self.damaged
                if self.damaged else 0.0}


def _channel(rng: random.Random, k: int) -> ChannelTelemetry:
    speed = 45.0 * (1 - 0.5 ** (k % 500 / 50)) + rng.gauss(0, 0.2)
    return ChannelTelemetry(k * 3 + rng.randrange(3), speed, rng.gauss(2.0, 0.5),
                            rng.randrange(-32760, 32761), 45.0, rng.choice((1, 1, 5)))


def _contents(rng: random.Random, first: int, count: int) -> list[bytes]:
    return [encode_telemetry(k % 100_000, (k * 1000) & 0xFFFF_FFFF, _channel(rng, k),
                             _channel(rng, k + 7)) for k in range(first, first + count)]


def _damage(wire: bytes, ber: float, rng: np.random.Generator) -> tuple[bytes, np.ndarray]:
    """The wire after the line: data bits inverted, bytes with a start or stop bit inverted
    lost. Returns the damaged wire and the damaged byte indexes."""
    slots = len(wire) * 10
    hits = np.unique(rng.integers(0, slots, rng.binomial(slots, ber)))
    data = np.frombuffer(wire, dtype=np.uint8).copy()
    index, slot = hits // 10, hits % 10
    flips = (slot >= 1) & (slot <= 8)
    np.bitwise_xor.at(data, index[flips], (1 << (slot[flips] - 1)).astype(np.uint8))
    lost = np.unique(index[~flips])
    return np.delete(data, lost).tobytes(), np.unique(index)


def fast_model(frames: int, ber: float, crc: bool, seed: int) -> Tally:
    rng, nprng = random.Random(seed), np.random.default_rng(seed)
    conn = Connection(baud=None)
    conn.wire_crc.on = crc  # as after the board's PA for WireCrc = 1
    tally = Tally()
    sent: dict[int, bytes] = {}
    for first in range(0, frames, CHUNK):
        count = min(CHUNK, frames - first)
        contents = _contents(rng, first, count)
        framed = [encode_frame(append_crc(c) if crc else c) for c in contents]
        ends = np.cumsum([len(f) for f in framed])
        damaged_wire, hit_bytes = _damage(b"".join(framed), ber, nprng)
        tally.frames += count
        tally.damaged += len(np.unique(np.searchsorted(ends, hit_bytes, side="right")))
        if len(sent) > CHUNK:  # keep the last two chunks: counters are unique within them
            for key in list(sent)[:count]:
                del sent[key]
        for k, content in zip(range(first, first + count), contents, strict=True):
            sent[k % 100_000] = content
        _decode(conn, damaged_wire, sent, tally)
    tally.crc_failures = conn.stats.crc_failures
    tally.decode_errors = conn.stats.decode_errors
    return tally


def _decode(conn: Connection, wire: bytes, sent: dict[int, bytes], tally: Tally) -> None:
    for start in range(0, len(wire), 4096):  # what serial reads return under load
        conn.receive_data(wire[start:start + 4096], 0.0)
        for event in conn.events():
            if type(event) is Telemetry:
                tally.delivered += 1
                if _corrupt(event, sent):
                    tally.accepted_corrupt += 1


def _corrupt(tm: Telemetry, sent: dict[int, bytes]) -> bool:
    expected = sent.get(tm.counter or 0)
    try:
        again = encode_telemetry(tm.counter or 0, tm.t_us, tm.a, tm.b)
    except Exception:  # a value no TM field holds: certainly not what was sent
        return True
    return again != expected


def emulator_cross_check(seconds: float, ber: float, crc: bool, seed: int) -> Tally:
    """The same count on an emulated board with the emulator's own line model."""
    from fpgaemu import build_board
    from fpgaemu.firmware import Firmware
    from fpgalink.protocol import ParamSet, encode_message

    board = build_board(seed=seed, faults=[f"tx-ber={ber}"])
    firmware = board.peripherals["firmware"]
    assert isinstance(firmware, Firmware)
    sent: dict[int, bytes] = {}

    def record(content: bytes, cycle: int) -> None:
        if content[:2] == b"TM":
            plain = content[:-2] if firmware.wire_crc.on else content
            sent[int(plain[2:7])] = plain

    board.uartsend.on_frame(record)
    conn = Connection(baud=None)
    for counter, (param, value) in enumerate(((2, 1), (11, 1 if crc else 0))):
        board.host_write(encode_frame(encode_message(ParamSet(param, 0, 1, value), counter)))
    board.run_for(0.01)
    board.read_host_bytes()  # the answers; the line is damaging them too
    conn.wire_crc.on = crc
    tally = Tally()
    first = firmware.stats.telemetry_sent
    end = board.now + round(seconds * 1e8)
    while board.now < end:
        board.run_until(min(end, board.now + 1_000_000))
        _decode(conn, board.read_host_bytes(), sent, tally)
    tally.frames = firmware.stats.telemetry_sent - first
    tally.damaged = -1  # the line model does not say per frame
    tally.crc_failures = conn.stats.crc_failures
    tally.decode_errors = conn.stats.decode_errors
    return tally


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME,
                           f"{QUICK_FRAMES:,} frames per case, a {QUICK_CROSS_CHECK_S:g} s "
                           "cross-check (the smoke test)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"TM frames per case (default {DEFAULT_FRAMES:,})")
    parser.add_argument("--cross-check-s", type=float, default=None,
                        help=f"emulated seconds per cross-check case (default "
                             f"{CROSS_CHECK_S:g})")
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args(argv)
    frames = args.frames or (QUICK_FRAMES if args.quick else DEFAULT_FRAMES)
    cross_s = args.cross_check_s or (QUICK_CROSS_CHECK_S if args.quick else CROSS_CHECK_S)
    started = time.perf_counter()
    cases: dict[str, dict[str, Any]] = {}
    for ber in RATES:
        for crc in (False, True):
            key = f"ber{ber:g}.{'crc' if crc else 'plain'}"
            t0 = time.perf_counter()
            fast = fast_model(frames, ber, crc, args.seed)
            t1 = time.perf_counter()
            emulated = emulator_cross_check(cross_s, ber, crc, args.seed)
            t2 = time.perf_counter()
            cases[key] = {"ber": ber, "crc": crc, "fast_model": fast.result(),
                          "emulator": emulated.result(),
                          "seconds": {"fast_model": t1 - t0, "emulator": t2 - t1}}
            print(f"{key} done in {t2 - t0:.1f} s", file=sys.stderr)
    payload: dict[str, Any] = {
        **report_header(NAME, ["numpy"]),
        "config": {"frames": frames, "cross_check_s": cross_s, "rates": list(RATES),
                   "quick": args.quick, "seed": args.seed, "crc": CRC16.name,
                   "argv": sys.argv[1:] if argv is None else list(argv)},
        "cases": cases,
        "timing": {"total_s": time.perf_counter() - started},
    }
    path = write_results(NAME, payload, args.output)
    print(environment_line(payload))
    rows = []
    for case in cases.values():
        for model in ("fast_model", "emulator"):
            r = case[model]
            rows.append([f"{case['ber']:g}", "CRC-16" if case["crc"] else "none",
                         "fast" if model == "fast_model" else "emulator", f"{r['frames']:,}",
                         f"{r['damaged']:,}" if r["damaged"] >= 0 else "—",
                         f"{r['decode_errors'] + r['crc_failures']:,}",
                         f"{r['accepted_corrupt']:,}", f"{r['accepted_corrupt_per_frame']:.1e}"])
    print_table(["BER", "check", "model", "TM frames", "damaged", "detected",
                 "accepted corrupt", "per frame"], rows, align="<<<>>>>>")
    print(f"\nresults in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
