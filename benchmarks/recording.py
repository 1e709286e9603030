"""Damaged recordings (issue 37 item 11): what a single flipped bit inside a chunk of a real
recording does to each way of reading it, and what checking every chunk costs.

A real recording: ``fpgalink-cli record`` of the built-in emulated board (``--seconds``,
default 10 s of 1 kHz telemetry). Then ``--flips`` times (default 300, seeded): one bit
inverted at a random place inside a random chunk record, and the file read three ways:

* ``mcap`` — ``mcap.reader.make_reader(f).iter_messages()``, what ``plot`` used before;
* ``mcap+crc`` — the same with ``validate_crcs=True``;
* ``fpgalink`` — :class:`fpgalink.recording.RecordingReader` (every reader of a recording
  in fpgalink: ``plot`` and any other).

Each read is counted as *refused* (an exception: nothing read), *damage named* (fpgalink:
the damaged chunk skipped and said, the rest read), *same data* (every message as written)
or **silently different** (no error, other data: the case that must never happen).

Speed: the whole recording read by each, median of ``--reps`` (messages per second, and the
ratio to ``mcap`` measured in the same run).

``python -m benchmarks.recording``; ``--quick``: 1 s, 30 flips, 2 repetitions.
"""

from __future__ import annotations

import functools
import random
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    summarize,
    time_once,
    write_results,
)

NAME = "recording"
SEED = 3711

Messages = list[tuple[str, int, int, bytes]]


def _record(path: Path, seconds: float) -> None:
    subprocess.run([sys.executable, "-m", "fpgalink", "record", str(path), "--duration",
                    f"{seconds:g}", "--port", "emu://"], check=True, capture_output=True)


def read_mcap(path: Path, validate: bool = False) -> Messages:
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        return [(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in
                make_reader(stream, validate_crcs=validate).iter_messages()]


def read_fpgalink(path: Path) -> tuple[Messages, int]:
    from fpgalink.recording import RecordingReader

    with RecordingReader(path) as reader:
        messages = [(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in
                    reader.messages()]
        return messages, len(reader.damage) + (1 if reader.skipped_messages else 0)


def chunk_spans(path: Path) -> list[tuple[int, int]]:
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


def classify(read: Callable[[Path], Any], path: Path, whole: Messages) -> str:
    try:
        got = read(path)
    except Exception:  # what a reader raises on a damaged file: nothing read
        return "refused"
    if isinstance(got, tuple):  # fpgalink's: (messages, damage found)
        messages, damage = got
        if damage:
            return "damage named" if set(messages) <= set(whole) else "silently different"
        got = messages
    return "same data" if got == whole else "silently different"


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, "1 s recorded, 30 flips, 2 repetitions")
    parser.add_argument("--seconds", type=float, default=None, help="recorded (default 10)")
    parser.add_argument("--flips", type=int, default=None, help="default 300")
    parser.add_argument("--reps", type=int, default=None, help="speed repetitions (5)")
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args(argv)
    seconds = args.seconds or (1.0 if args.quick else 10.0)
    flips = args.flips or (30 if args.quick else 300)
    reps = args.reps or (2 if args.quick else 5)
    started = time.perf_counter()
    readers: dict[str, Callable[[Path], Any]] = {
        "mcap": read_mcap, "mcap+crc": lambda p: read_mcap(p, True), "fpgalink": read_fpgalink}
    with tempfile.TemporaryDirectory() as where:
        path = Path(where) / "run.mcap"
        _record(path, seconds)
        data = path.read_bytes()
        whole = read_mcap(path)
        spans = chunk_spans(path)
        speed: dict[str, Any] = {}
        for name, read in readers.items():
            times = [time_once(functools.partial(read, path))[0] for _ in range(reps)]
            speed[name] = {"seconds": summarize(times),
                           "messages_per_s": len(whole) / summarize(times)["median"]}
        rng = random.Random(args.seed)
        outcomes: dict[str, dict[str, int]] = {name: {} for name in readers}
        flipped = Path(where) / "flipped.mcap"
        for _ in range(flips):
            offset, length = rng.choice(spans)
            at = offset + rng.randrange(length)
            damaged = bytearray(data)
            damaged[at] ^= 1 << rng.randrange(8)
            flipped.write_bytes(damaged)
            for name, read in readers.items():
                outcome = classify(read, flipped, whole)
                outcomes[name][outcome] = outcomes[name].get(outcome, 0) + 1
    payload: dict[str, Any] = {
        **report_header(NAME, ["mcap", "zstandard"]),
        "config": {"seconds": seconds, "flips": flips, "reps": reps, "seed": args.seed,
                   "quick": args.quick, "argv": sys.argv[1:] if argv is None else list(argv)},
        "recording": {"bytes": len(data), "messages": len(whole), "chunks": len(spans)},
        "flips": outcomes,
        "speed": speed,
        "timing": {"total_s": time.perf_counter() - started},
    }
    out = write_results(NAME, payload, args.output)
    print(environment_line(payload))
    print(f"a {seconds:g} s recording: {len(data):,} bytes, {len(whole):,} messages, "
          f"{len(spans)} chunks; {flips} single-bit flips inside chunks (seed {args.seed})")
    kinds = ("refused", "damage named", "same data", "silently different")
    base = speed["mcap"]["seconds"]["median"]
    print_table(["reader", *kinds, "read msg/s", "time vs mcap"],
                [[name, *(str(outcomes[name].get(k, 0)) for k in kinds),
                  f"{speed[name]['messages_per_s']:,.0f}",
                  f"{speed[name]['seconds']['median'] / base:.2f}"] for name in readers],
                align="<>>>>>>")
    print(f"results: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
