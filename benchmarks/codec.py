"""Throughput of the sans-I/O codec: framing, typed decoding, ``Connection``, and encoding.

Four streams, fed to the decoders in 4096-byte chunks (what a serial read returns under
load, and chunk edges fall mid-frame as they do on the wire):

* ``tm``: ``TM`` telemetry, 52 content bytes, random but in-range values, so a share of the
  frames carry bytes that need escaping, as real telemetry does;
* ``counted190``: a generic counted message with a 180-byte random binary section
  (190 content bytes, near the 200-byte limit), decoded to :class:`CountedMessage`;
* ``escaped52`` and ``escaped190``: 52 (a ``TM``'s size) or 190 content bytes drawn only
  from START/STOP/SKIP, so every content byte is escaped and the wire doubles: the decoder's
  worst case, at both sizes.

``--frames`` frames of the first two; the all-escaped streams have a share of that (they are
far dearer per frame). Every rate is per frame, so the streams still compare.

The byte-at-a-time reference models (``tests/support/reference.py``: ``NaiveFrameDecoder``
and ``naive_encode``) run in the same process on a prefix of each stream as the baselines, so
speed-ups are measured in one run on one machine. They are slow, so they see fewer frames;
every rate is per frame or per byte, so they compare.

Encoding is measured as a user of the library encodes: ``Connection.send(message, now)`` then
``Connection.data_to_send()`` per message (a board-side connection with ``baud=None``, so no
reference pacing applies), beside ``encode_frame`` of ready-made contents (framing alone).

Rates are reported as frames/s, MB/s of wire bytes, and as a multiple of the 1 MBd line rate
(10 bits a byte on the UART: 100,000 B/s). Run ``python -m benchmarks.codec`` from the
repository root; ``--quick`` is one repetition of 10,000 frames (the smoke test uses it).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchmarks._common import (
    Summary,
    chunked,
    common_parser,
    environment_line,
    print_table,
    report_header,
    summarize,
    time_once,
    write_results,
)
from fpgalink import Connection, Role
from fpgalink.protocol import (
    DEFAULT_FRAMING,
    Binary,
    ChannelTelemetry,
    CountedMessage,
    FrameDecoder,
    Telemetry,
    encode_frame,
    encode_message,
    parse_content,
)
from tests.support.reference import NaiveFrameDecoder, naive_encode

NAME = "codec"
CHUNK = 4096
LINE_RATE = 100_000  #: bytes/s of a 1 MBd UART (start + 8 data + stop bits)
SEED = 20_240_601
DEFAULT_FRAMES = 100_000
QUICK_FRAMES = 10_000
#: Frames of TM the naive decoder sees; other streams get as many wire bytes, not frames,
#: so each baseline costs about the same time whatever its frame size.
NAIVE_TM_FRAMES = 10_000
QUICK_NAIVE_TM_FRAMES = 2_000
#: The all-escaped streams have this share of the frames: at 106 and 382 wire bytes a frame
#: they are 2× and 7× the TM stream's bytes per frame, and the codec is far slower on them, so
#: full-size streams would overrun the time budget. Rates are per frame, so they still compare.
WORST_CASE_DIVISORS = {52: 4, 190: 10}

TARGET_FRAMING_TM = 1_000_000  #: frames/s, FrameDecoder.feed on the TM stream
TARGET_TYPED_TM = 500_000  #: typed TM events/s
TARGET_WORST_VS_NAIVE = 2.0  #: all-escaped streams, fast decoder vs the naive one
#: issue 17: FrameDecoder.feed on the TM stream, × the naive decoder in the same run
TARGET_FRAMING_VS_NAIVE = 8.0

#: A timed call: returns how many frames it handled, which must be all of them.
Run = Callable[[], int]


# --- the streams ------------------------------------------------------------------------------


@dataclass
class Stream:
    key: str
    label: str
    description: str
    contents: list[bytes]
    #: what Connection.send takes to produce ``contents`` (None: not a message, framing only)
    messages: Sequence[Telemetry | CountedMessage] | None
    wire: bytes = b""
    chunks: list[bytes] = field(default_factory=list)
    naive_frames: int = 0
    naive_wire: int = 0
    naive_chunks: list[bytes] = field(default_factory=list)

    def __post_init__(self) -> None:
        frames = [encode_frame(c) for c in self.contents]
        self.wire = b"".join(frames)
        self.chunks = chunked(self.wire, CHUNK)

    def take_naive(self, frames: int) -> None:
        self.naive_frames = min(frames, len(self.contents))
        naive_wire = b"".join(encode_frame(c) for c in self.contents[: self.naive_frames])
        self.naive_wire = len(naive_wire)
        self.naive_chunks = chunked(naive_wire, CHUNK)

    def info(self) -> dict[str, Any]:
        n = len(self.contents)
        content_bytes = sum(map(len, self.contents))
        # A frame needs escapes exactly when its wire is longer than content + START/STOP.
        escaped = sum(
            any(b in c for b in DEFAULT_FRAMING.specials) for c in self.contents
        )
        return {
            "label": self.label,
            "description": self.description,
            "frames": n,
            "content_bytes": content_bytes,
            "content_bytes_per_frame": content_bytes / n,
            "wire_bytes": len(self.wire),
            "wire_bytes_per_frame": len(self.wire) / n,
            "escape_bytes": len(self.wire) - content_bytes - 2 * n,
            "frames_with_escapes": escaped,
            "frames_with_escapes_fraction": escaped / n,
            "chunk_size": CHUNK,
            "chunks": len(self.chunks),
            "naive_frames": self.naive_frames,
            "naive_wire_bytes": self.naive_wire,
        }


def _tm_stream(n: int, rng: np.random.Generator) -> Stream:
    # Values are uniformly random within the ranges a board reports; the codec cares only
    # how many bytes need escaping, and random low-order bytes give that its natural rate
    # (float exponent bytes and small ints never hit S/P/\, as in real telemetry).
    t_us = rng.integers(0, 2**32, n).tolist()
    per_channel = [
        (
            rng.integers(-(2**31), 2**31, n).tolist(),  # position, counts
            rng.uniform(-720.0, 720.0, n).tolist(),  # speed, deg/s
            rng.uniform(-5.0, 5.0, n).tolist(),  # current, A
            rng.integers(-32760, 32761, n).tolist(),  # pwm
            rng.uniform(-360.0, 360.0, n).tolist(),  # reference
            rng.integers(0, 8, n).tolist(),  # flags
        )
        for _ in range(2)
    ]
    (pa, sa, ca, wa, ra, fa), (pb, sb, cb, wb, rb, fb) = per_channel
    messages = [
        Telemetry(
            t_us[i],
            ChannelTelemetry(pa[i], sa[i], ca[i], wa[i], ra[i], fa[i]),
            ChannelTelemetry(pb[i], sb[i], cb[i], wb[i], rb[i], fb[i]),
        )
        for i in range(n)
    ]
    # Counters as Connection.send numbers them, so its output can be checked against ours.
    contents = [encode_message(m, i) for i, m in enumerate(messages)]
    return Stream(
        "tm", "TM 52 B", "TM telemetry, 52 content bytes, random in-range values",
        contents, messages,
    )


def _counted_stream(n: int, rng: np.random.Generator) -> Stream:
    blobs = rng.integers(0, 256, (n, 180), dtype=np.uint8)
    messages = [CountedMessage("BL", (Binary(row.tobytes()),)) for row in blobs]
    contents = [encode_message(m, i) for i, m in enumerate(messages)]
    return Stream(
        "counted190", "counted 190 B",
        "generic counted message 'BL' with one 180-byte random binary section",
        contents, messages,
    )


def _escaped_stream(n: int, rng: np.random.Generator, size: int) -> Stream:
    specials = np.frombuffer(DEFAULT_FRAMING.specials, dtype=np.uint8)
    rows = specials[rng.integers(0, 3, (n, size))]
    contents = [row.tobytes() for row in rows]
    return Stream(
        f"escaped{size}", f"all-escaped {size} B",
        f"{size} content bytes drawn only from S/P/\\: every content byte escaped (worst case)",
        contents, None,
    )


# --- what is timed ----------------------------------------------------------------------------


def _decode_frames(chunks: list[bytes], make_decoder: Callable[[], Any]) -> Run:
    """Framing only, with the fast decoder or the naive reference: the same loop times both."""

    def run() -> int:
        feed = make_decoder().feed
        n = 0
        for chunk in chunks:
            n += len(feed(chunk))
        return n

    return run


def _decode_typed(chunks: list[bytes]) -> Run:
    def run() -> int:
        feed = FrameDecoder().feed
        parse = parse_content
        n = 0
        for chunk in chunks:
            for item in feed(chunk):
                # A consumer must tell frames from framing-error events; so does this loop.
                if type(item) is bytes:
                    parse(item)
                    n += 1
        return n

    return run


def _decode_connection(chunks: list[bytes]) -> Run:
    # A 4096-byte chunk takes 41 ms at line rate; passing ``now`` exercises liveness too.
    dt = CHUNK / LINE_RATE

    def run() -> int:
        conn = Connection()
        receive, next_event = conn.receive_data, conn.next_event
        now = 0.0
        for chunk in chunks:
            receive(chunk, now)
            now += dt
            while next_event() is not None:
                pass
        stats = conn.stats
        # Counted after the clock stops mattering (one look at the end): a fast path that
        # dropped or mangled frames would otherwise pass for a fast one.
        if stats.lost or stats.decode_errors or stats.noise_bytes:
            raise AssertionError(f"Connection saw lost={stats.lost}, "
                                 f"decode_errors={stats.decode_errors}, "
                                 f"noise={stats.noise_bytes} on a clean stream")
        return stats.messages_received

    return run


def _encode_frames(contents: list[bytes], encode: Callable[[bytes], bytes]) -> Run:
    """Framing only, with ``encode_frame`` or the naive reference: one loop times both."""

    def run() -> int:
        enc = encode
        return len([enc(c) for c in contents])

    return run


def _encode_connection(messages: Sequence[Telemetry | CountedMessage]) -> Run:
    def run() -> int:
        # baud=None: a board's connection does no reference pacing, so every message leaves
        # at once, as from firmware that sends whenever its timer says.
        conn = Connection(role=Role.BOARD, baud=None)
        send, take = conn.send, conn.data_to_send
        n = 0
        for m in messages:
            send(m, 0.0)
            if take():
                n += 1
        return n

    return run


@dataclass
class Case:
    key: str
    stream: Stream
    operation: str  #: "decode" or "encode"
    path: str
    frames: int
    wire_bytes: int
    run: Run
    seconds: list[float] = field(default_factory=list)
    #: frames each repetition handled (checked equal to ``frames``)
    counts: list[int] = field(default_factory=list)

    def rates(self) -> dict[str, list[float]]:
        return {
            "frames_per_s": [self.frames / s for s in self.seconds],
            "mb_per_s": [self.wire_bytes / s / 1e6 for s in self.seconds],
            "line_rate_x": [self.wire_bytes / s / LINE_RATE for s in self.seconds],
        }

    def summary(self) -> dict[str, Summary]:
        out = {name: summarize(values) for name, values in self.rates().items()}
        out["seconds"] = summarize(self.seconds)
        return out

    def result(self) -> dict[str, Any]:
        rates = self.rates()
        return {
            "stream": self.stream.key,
            "operation": self.operation,
            "path": self.path,
            "frames": self.frames,
            "wire_bytes": self.wire_bytes,
            "repetitions": [
                {"seconds": s, "frames_handled": self.counts[i],
                 **{name: values[i] for name, values in rates.items()}}
                for i, s in enumerate(self.seconds)
            ],
            "summary": self.summary(),
        }


def _cases(streams: list[Stream]) -> list[Case]:
    cases: list[Case] = []
    for st in streams:
        n, wire = len(st.contents), len(st.wire)

        def add(op: str, name: str, path: str, run: Run, frames: int = n, nbytes: int = wire,
                st: Stream = st) -> None:
            cases.append(Case(f"{st.key}.{op}.{name}", st, op, path, frames, nbytes, run))

        add("decode", "framing", "FrameDecoder.feed", _decode_frames(st.chunks, FrameDecoder))
        add("decode", "naive", "NaiveFrameDecoder.feed (byte loop)",
            _decode_frames(st.naive_chunks, NaiveFrameDecoder), st.naive_frames, st.naive_wire)
        if st.messages is not None:
            add("decode", "typed", "feed + parse_content", _decode_typed(st.chunks))
            add("decode", "connection", "Connection.receive_data + next_event",
                _decode_connection(st.chunks))
        add("encode", "framing", "encode_frame", _encode_frames(st.contents, encode_frame))
        add("encode", "naive", "naive_encode (byte loop)",
            _encode_frames(st.contents[: st.naive_frames], naive_encode), st.naive_frames,
            st.naive_wire)
        if st.messages is not None:
            add("encode", "connection", "Connection.send + data_to_send",
                _encode_connection(st.messages))
    return cases


# --- checks, untimed: a fast wrong answer is no result ----------------------------------------


def _verify(streams: list[Stream]) -> None:
    """Both decoders, both framers and ``Connection.send`` against the known contents, on the
    prefix the naive models see (the timed runs then check every frame is accounted for)."""
    for st in streams:
        expected = st.contents[: st.naive_frames]
        decoder = FrameDecoder()
        if [item for chunk in st.naive_chunks for item in decoder.feed(chunk)] != expected:
            raise AssertionError(f"{st.key}: FrameDecoder does not return the contents")
        ref = NaiveFrameDecoder()
        if [item for chunk in st.naive_chunks for item in ref.feed(chunk)] != expected:
            raise AssertionError(f"{st.key}: naive decoder does not return the contents")
        if b"".join(map(naive_encode, expected)) != b"".join(st.naive_chunks):
            raise AssertionError(f"{st.key}: naive_encode does not give the stream")
        if st.messages is None:
            continue
        board = Connection(role=Role.BOARD, baud=None)
        for m in st.messages[: st.naive_frames]:
            board.send(m, 0.0)
        if board.data_to_send() != b"".join(st.naive_chunks):
            raise AssertionError(f"{st.key}: Connection.send does not give the stream")
        # Decoding gives back what was sent (TM floats come back rounded to float32, so
        # compare by re-encoding).
        for i in range(0, st.naive_frames, max(1, st.naive_frames // 7)):
            msg = parse_content(st.contents[i])
            if not isinstance(msg, type(st.messages[i])):
                raise AssertionError(f"{st.key}: frame {i} parsed as {type(msg).__name__}")
            if encode_message(msg, i) != st.contents[i]:
                raise AssertionError(f"{st.key}: frame {i} does not round-trip")


# --- running and reporting --------------------------------------------------------------------


def _si(x: float) -> str:
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= scale:
            return f"{x / scale:.3g}{suffix}"
    return f"{x:.3g}"


def _ratios(cases: dict[str, Case], streams: list[Stream]) -> dict[str, dict[str, Any]]:
    """Each path against the naive model of its operation on the same stream, per frame."""
    out: dict[str, dict[str, Any]] = {}
    for st in streams:
        for case in cases.values():
            if case.stream is not st or case.key.endswith(".naive"):
                continue
            baseline = f"{st.key}.{case.operation}.naive"
            naive = cases[baseline].summary()["frames_per_s"]
            fast = case.summary()["frames_per_s"]
            out[case.key] = {
                "baseline": baseline,
                "median": fast["median"] / naive["median"],
                # The most pessimistic pairing of repetitions, for a claim that must hold.
                "worst": fast["min"] / naive["max"],
            }
    return out


def _targets(cases: dict[str, Case], ratios: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    def target(name: str, case: str, metric: str, measured: float, threshold: float,
               required: bool = True, note: str = "") -> dict[str, Any]:
        return {
            "name": name, "case": case, "metric": metric, "measured": measured,
            "threshold": threshold, "pass": measured >= threshold, "required": required,
            "note": note,
        }

    def median_rate(key: str) -> float:
        return cases[key].summary()["frames_per_s"]["median"]

    return [
        target("framing decode", "tm.decode.framing", "TM frames/s (median)",
               median_rate("tm.decode.framing"), TARGET_FRAMING_TM),
        target("full decode to typed TM", "tm.decode.typed", "TM events/s (median)",
               median_rate("tm.decode.typed"), TARGET_TYPED_TM),
        target("framing decode vs naive", "tm.decode.framing",
               "× naive frames/s (median ratio)",
               ratios["tm.decode.framing"]["median"], TARGET_FRAMING_VS_NAIVE),
        *(target(f"worst case vs naive, {size} B", f"escaped{size}.decode.framing",
                 "× naive frames/s (median ratio)",
                 ratios[f"escaped{size}.decode.framing"]["median"], TARGET_WORST_VS_NAIVE)
          for size in WORST_CASE_DIVISORS),
        target("typed TM through Connection", "tm.decode.connection", "TM events/s (median)",
               median_rate("tm.decode.connection"), TARGET_TYPED_TM, required=False,
               note="not in the issue's targets: the same bar applied to the full link path"),
    ]


def _print_report(report: dict[str, Any], cases: list[Case], streams: list[Stream],
                  ratios: dict[str, dict[str, Any]], targets: list[dict[str, Any]],
                  reps: int) -> None:
    print(f"\ncodec throughput, median of {reps} repetition(s), {CHUNK}-byte chunks; "
          f"line rate 1 MBd = {LINE_RATE:,} B/s")
    print(environment_line(report))
    # The escape share decides which decoder paths run, so it belongs beside the rates.
    for st in streams:
        info = st.info()
        print(f"  {st.label}: {info['wire_bytes_per_frame']:.1f} wire B/frame, "
              f"{info['frames_with_escapes_fraction']:.1%} of frames need escapes")
    print()
    rows = []
    for case in cases:
        s = case.summary()
        fps = s["frames_per_s"]
        ratio = ratios.get(case.key)
        rows.append([
            case.stream.label,
            f"{case.operation} {case.path}",
            f"{case.frames:,}",
            f"{fps['median']:,.0f}",
            f"{_si(fps['min'])}–{_si(fps['max'])}",
            f"{s['mb_per_s']['median']:.2f}",
            f"{s['line_rate_x']['median']:.1f}",
            f"{ratio['median']:.1f}" if ratio else "",
        ])
    print_table(
        ["stream", "path", "frames", "frames/s", "min–max", "MB/s", "× line", "× naive"],
        rows, align="<<>>>>>>",
    )
    print("× naive: frames/s over the byte-loop model of the same operation on the same "
          "stream, this run.\nencode Connection.send + data_to_send: what a library user "
          "does, one message at a time\n(a board-side Connection, baud=None: no reference "
          "pacing); encode_frame: framing of ready contents.")
    print()
    print_table(
        ["target", "measured", "threshold", "result"],
        [
            [
                t["name"] + ("" if t["required"] else " (extra)"),
                f"{t['measured']:,.2f}" if t["measured"] < 100 else f"{t['measured']:,.0f}",
                f"≥ {t['threshold']:,.0f}",
                "PASS" if t["pass"] else "FAIL",
            ]
            for t in targets
        ],
        align="<>><",
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME,
                           f"1 repetition of {QUICK_FRAMES:,} frames (the smoke test)")
    parser.add_argument("--reps", type=int, default=None, help="repetitions (default 5)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"frames per stream (default {DEFAULT_FRAMES:,})")
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args(argv)
    reps = args.reps if args.reps is not None else (1 if args.quick else 5)
    frames = args.frames if args.frames is not None else (
        QUICK_FRAMES if args.quick else DEFAULT_FRAMES)
    naive_tm = QUICK_NAIVE_TM_FRAMES if args.quick else NAIVE_TM_FRAMES
    if reps < 1 or frames < 10:
        parser.error("--reps must be ≥ 1 and --frames ≥ 10")

    started = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    tm, counted = _tm_stream(frames, rng), _counted_stream(frames, rng)
    # Drawn in this order so the streams that came before the 52-byte one keep their bytes.
    escaped = {size: _escaped_stream(max(10, frames // WORST_CASE_DIVISORS[size]), rng, size)
               for size in (190, 52)}
    streams = [tm, counted, *(escaped[size] for size in WORST_CASE_DIVISORS)]
    naive_budget = naive_tm * len(streams[0].wire) / frames
    for st in streams:
        st.take_naive(max(100, round(naive_budget * len(st.contents) / len(st.wire))))
    _verify(streams)
    setup_s = time.perf_counter() - started

    cases = _cases(streams)
    # Reps interleave the cases rather than running each case N times in a row, so a slow
    # spell on the machine spreads over all cases instead of sinking one of them.
    for rep in range(reps):
        for case in cases:
            seconds, count = time_once(case.run)
            if count != case.frames:
                raise AssertionError(f"{case.key}: processed {count} frames, not {case.frames}")
            case.seconds.append(seconds)
            case.counts.append(count)
        print(f"repetition {rep + 1}/{reps} done", file=sys.stderr)

    by_key = {c.key: c for c in cases}
    ratios = _ratios(by_key, streams)
    targets = _targets(by_key, ratios)
    elapsed = time.perf_counter() - started
    payload: dict[str, Any] = {
        **report_header(NAME, ["numpy", "construct"]),
        "config": {
            "frames": frames,
            "worst_case_frames": {f"escaped{size}": len(st.contents)
                                  for size, st in escaped.items()},
            "reps": reps,
            "quick": args.quick,
            "seed": args.seed,
            "chunk_size": CHUNK,
            "line_rate_bytes_per_s": LINE_RATE,
            "mb": "10^6 wire bytes",
            "argv": sys.argv[1:] if argv is None else list(argv),
        },
        "streams": {st.key: st.info() for st in streams},
        "cases": {c.key: c.result() for c in cases},
        "ratios_vs_naive": ratios,
        "targets": targets,
        "timing": {"setup_s": setup_s, "total_s": elapsed},
    }
    path = write_results(NAME, payload, args.output)
    _print_report(payload, cases, streams, ratios, targets, reps)
    print(f"\n{len(cases)} cases × {reps} rep(s) in {elapsed:.1f} s "
          f"(setup {setup_s:.1f} s); results in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
