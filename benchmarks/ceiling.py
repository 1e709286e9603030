"""How fast could one emulated board go in this Python? The arithmetic of a millisecond alone,
with no module, no timeline, no UART timing: the ceiling any fused per-millisecond path
could approach, beside the emulator's board case measured in the same run.

Per emulated millisecond, in one flat loop over local variables:

* ``arithmetic``: both wheels' plants (three modes each, complex, as ``motor.py`` steps
  them), their winding currents, encoder counts, the M/T speed, both PIDs and the PWM
  clamp — what the firmware's tick computes;
* ``+ TM``: and the ``TM`` packed (``encode_telemetry``) and framed (``encode_frame``), as
  the board sends it;
* ``+ RV``: and one ``RV`` taken from its wire bytes (unframed, unpacked), as the board
  receives one every millisecond in the benchmark's scenario;
* ``board``: ``benchmarks.emulator``'s board case (the same work through the modules, with
  the line's bit timing, the BRAM, the interrupt and the timing report).

Run ``python -m benchmarks.ceiling`` from the repository root; ``--quick`` is the smoke test.
"""

from __future__ import annotations

import cmath
import math
import statistics
import struct
import sys
import time
from collections.abc import Callable

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)
from benchmarks.emulator import scenario
from fpgalink.protocol import ChannelTelemetry
from fpgalink.protocol.codec import encode_telemetry
from fpgalink.protocol.framing import encode_frame

NAME = "ceiling"
DT = 1e-3
#: The high gear's continuous poles and a residue per mode (docs/emulator.md §13); the
#: values only need to be of the right kind for a timing.
POLES = (-4.15 + 0j, -13.5 + 19.3j, -13.5 - 19.3j)
RESIDUES = (30.0 + 0j, -15.0 + 4.0j, -15.0 - 4.0j)


def arithmetic_loop(ms: int, tm: bool, rv: bool) -> Callable[[], float]:
    """A closure running ``ms`` emulated milliseconds; returns a checksum (so nothing is
    optimised away, and a reader can see the loop did work)."""
    coefficients = []
    for s, c in zip(POLES, RESIDUES, strict=True):
        e = cmath.exp(s * DT)
        phi = (e - 1) / s
        coefficients.append((e, phi, c * phi, c * (phi - DT) / s))
    (e0, g0, s0, i0), (e1, g1, s1, i1), (e2, g2, s2, i2) = coefficients
    decay = math.exp(-DT * 1.2 / 0.0009)
    rv_wire = encode_frame(struct.pack("<2s5s2sff1s", b"RV", b"00001", b"{\x08", 45.0, 45.0,
                                       b"}"))
    unpack_rv = struct.Struct("<ff").unpack_from
    kp, ti, limit, res = 520.0, 0.24, 32760.0, 500 * 4

    def run() -> float:
        # Two channels' state as locals: x modes, angle, current, count, last count, PID.
        xa = [0j, 0j, 0j]
        xb = [0j, 0j, 0j]
        angle_a = angle_b = cur_a = cur_b = integ_a = integ_b = 0.0
        last_a = last_b = 0
        duty_a = duty_b = 0
        ref_a = ref_b = 45.0
        sent = 0
        for tick in range(ms):
            if rv:
                content = rv_wire[1:-1].replace(b"\\\\", b"\\")
                ref_a, ref_b = unpack_rv(content, 9)
            # plants
            u = duty_a / 32760.0
            x0, x1, x2 = xa
            gain = 0.0 + (s0 * x0 + i0 * u).real
            gain += (s1 * x1 + i1 * u).real
            gain += (s2 * x2 + i2 * u).real
            xa = [e0 * x0 + g0 * u, e1 * x1 + g1 * u, e2 * x2 + g2 * u]
            angle_a += gain
            steady = (24.0 * u - 0.05 * math.radians(gain / DT) * 70) / 1.2
            cur_a = steady + (cur_a - steady) * decay
            u = duty_b / 32760.0
            x0, x1, x2 = xb
            gain = 0.0 + (s0 * x0 + i0 * u).real
            gain += (s1 * x1 + i1 * u).real
            gain += (s2 * x2 + i2 * u).real
            xb = [e0 * x0 + g0 * u, e1 * x1 + g1 * u, e2 * x2 + g2 * u]
            angle_b += gain
            steady = (24.0 * u - 0.05 * math.radians(gain / DT) * 70) / 1.2
            cur_b = steady + (cur_b - steady) * decay
            # encoders and the M/T speed
            count_a = math.floor(angle_a * res / 360.0)
            count_b = math.floor(angle_b * res / 360.0)
            speed_a = (count_a - last_a) * 360.0 / res / DT
            speed_b = (count_b - last_b) * 360.0 / res / DT
            last_a, last_b = count_a, count_b
            # PIDs and the PWM clamp
            error = ref_a - speed_a
            step = kp * DT / ti * error
            candidate = kp * error + integ_a + step
            if -limit < candidate < limit:
                integ_a += step
            duty_a = round(max(-limit, min(limit, candidate)))
            error = ref_b - speed_b
            step = kp * DT / ti * error
            candidate = kp * error + integ_b + step
            if -limit < candidate < limit:
                integ_b += step
            duty_b = round(max(-limit, min(limit, candidate)))
            if tm:
                content = encode_telemetry(
                    tick, tick * 1000,
                    tuple.__new__(ChannelTelemetry, (count_a, speed_a, cur_a, duty_a, ref_a, 1)),
                    tuple.__new__(ChannelTelemetry, (count_b, speed_b, cur_b, duty_b, ref_b, 1)))
                sent += len(encode_frame(content))
        return angle_a + angle_b + sent

    return run


def median_time(fn: Callable[[], object], reps: int) -> tuple[float, list[float]]:
    walls = []
    for _ in range(reps):
        started = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - started)
    return statistics.median(walls), walls


def main(argv: list[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, "1 s emulated, 2 repetitions (the smoke test)")
    args = parser.parse_args(argv)
    seconds, reps = (1.0, 2) if args.quick else (10.0, 7)
    ms = round(seconds * 1000)
    walls_of: dict[str, list[float]] = {}
    for label, tm, rv in (("arithmetic", False, False), ("+ TM", True, False),
                          ("+ RV", True, True)):
        walls_of[label] = median_time(arithmetic_loop(ms, tm, rv), reps)[1]
    # The emulator's board case, a fresh board per repetition (built outside the timing).
    walls_of["board"] = []
    for _ in range(reps):
        run = scenario(seconds, decode=False, rv_stream=True)
        started = time.perf_counter()
        run()
        walls_of["board"].append(time.perf_counter() - started)
    medians = {label: statistics.median(walls) for label, walls in walls_of.items()}
    cases = {label: {"median_s": medians[label], "walls": walls_of[label],
                     "us_per_ms": medians[label] / ms * 1e6,
                     "x_real_time": seconds / medians[label]} for label in walls_of}
    over = medians["board"] / medians["+ RV"]
    payload = {**report_header(NAME, []),
               "config": {"quick": args.quick, "emulated_s": seconds, "reps": reps},
               "cases": cases, "board_over_ceiling": over}
    path = write_results(NAME, payload, args.output)
    print(f"the per-millisecond ceiling: {seconds:g} s emulated, median of {reps}")
    print(environment_line(payload))
    print_table(("case", "µs per emulated ms", "× real time", "range s"),
                [(label, f"{medians[label] / ms * 1e6:.1f}", f"{seconds / medians[label]:.1f}×",
                  f"{min(walls_of[label]):.3f}–{max(walls_of[label]):.3f}")
                 for label in walls_of])
    print(f"the board through its modules takes {over:.2f}× the flat loop's time (+ RV)")
    print(f"results in {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
