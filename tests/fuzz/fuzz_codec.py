"""Coverage-guided fuzzing of the frame decoder and the message parser with atheris.

Run longer than CI does, from the repository root:

    .venv/bin/python -m tests.fuzz.fuzz_codec -atheris_runs=0 -max_total_time=600 \
        tests/fuzz/corpus

Each input is split in two: the first byte picks framing bytes and chunk sizes, the rest is
the stream. The harness checks what must always hold, beyond "does not raise":
the fast decoder agrees with the naive reference, every byte is accounted for, and every
delivered frame parses to something (a message or a Malformed event) without raising.
Any crash found becomes a file in tests/fuzz/regressions/, replayed by test_fuzz_regressions.
"""

from __future__ import annotations

import sys

import atheris

with atheris.instrument_imports():
    from fpgalink import Connection
    from fpgalink.protocol import FrameDecoder, Framing, parse_content
    from tests.support.reference import NaiveFrameDecoder


def check(data: bytes) -> None:
    if not data:
        return
    selector, stream = data[0], data[1:]
    framing = Framing() if selector & 1 else Framing(0x02, 0x03, 0x10, 1 + selector % 60)
    chunk = 1 + (selector >> 2)
    decoder = FrameDecoder(framing)
    got: list[bytes] = []
    for i in range(0, len(stream), chunk):
        got += [e for e in decoder.feed(stream[i : i + chunk]) if isinstance(e, bytes)]
    reference = NaiveFrameDecoder(framing)
    if got != reference.feed(stream):
        raise AssertionError("fast decoder disagrees with the reference")
    s = decoder.stats
    if s.frame_bytes + s.escape_bytes + s.dropped_bytes + decoder.pending != len(stream):
        raise AssertionError("bytes not accounted for")
    for frame in got:
        parse_content(frame)
    conn = Connection()
    conn.receive_data(stream, now=0.0)
    list(conn.events())


def main() -> None:
    atheris.Setup(sys.argv, check)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
