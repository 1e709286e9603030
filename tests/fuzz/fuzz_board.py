"""Coverage-guided fuzzing of the emulated board's receive path: fuzzed bytes on the RX pin
at fuzzed moments go through ``uartread``, ``uartcommand`` and the firmware's message
handling while the board is enabled and its controllers run.

Run longer than CI does, from the repository root:

    .venv/bin/python -m tests.fuzz.fuzz_board -atheris_runs=0 -max_total_time=600

What must hold for any input: nothing raises; no duty outside ±32760 and no non-finite
reference or integrator (a NaN there once latched full PWM); every byte the board sends
decodes as frames (its TX side is never corrupted by what it received).
"""

from __future__ import annotations

import math
import sys

import atheris

with atheris.instrument_imports():
    from fpgaemu import build_board, ms
    from fpgaemu.firmware import Firmware
    from fpgalink.protocol import FrameDecoder, encode_frame

ENABLE = encode_frame(b"RE")
TELEMETRY_ON = encode_frame(b"PS00000{\x07\x02\x00\x01\x01\x00\x00\x00}")


def check(data: bytes) -> None:
    board = build_board()
    firmware = board.peripherals["firmware"]
    assert isinstance(firmware, Firmware)
    board.host_write(TELEMETRY_ON + ENABLE, 0)
    cycle = ms(2)
    position = 0
    while position < len(data):
        # Each piece: one byte of gap (in 10 µs steps), one byte of length, then the bytes.
        gap, length = data[position], (data[position + 1] if position + 1 < len(data) else 0)
        piece = data[position + 2 : position + 2 + length]
        position += 2 + length
        cycle += gap * 1000
        board.run_until(cycle)
        board.host_write(piece + ENABLE, cycle)
    board.run_until(cycle + ms(5))
    for code, channel in firmware.channels.items():
        duty = board.channels[code].pwm.duty_register
        if not -32760 <= duty <= 32760:
            raise AssertionError(f"duty {duty} on channel {code}")
        if not (math.isfinite(channel.reference) and math.isfinite(channel.pid.integral)):
            raise AssertionError(f"channel {code}: reference {channel.reference}, "
                                 f"integral {channel.pid.integral}")
    decoder = FrameDecoder()
    decoder.feed(board.read_host_bytes())
    if decoder.stats.dropped_bytes:
        raise AssertionError("the board's own output did not decode cleanly")


def main() -> None:
    atheris.Setup(sys.argv, check)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
