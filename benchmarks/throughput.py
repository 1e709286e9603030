"""Message throughput of the whole stack, side by side with pymavlink (issue 7).

Run ``python -m benchmarks.throughput [--quick] [--reps N] [--window S] [--output PATH]``
from the repository root; results go to ``benchmarks/results/throughput.json``. ``--quick``
(one repetition, small counts, 1 s windows; well under 20 s) is what the smoke test runs.

Four sections, every figure measured in this run (nothing is copied from elsewhere):

1. **Codec only.** ``TM``, ``RV`` and ``PS``/``PA`` encoded as a library user does
   (``Connection.send`` then ``data_to_send`` per message) and decoded by
   ``Connection.receive_data`` to typed events, against pymavlink encoding (``MAVLink.send``)
   and decoding (``MAVLink.parse_buffer``) MAVLink v2 messages of the same payload size, in the
   same process, repetitions interleaved, so ratios pair repetitions of one run. ``TM`` is
   also decoded by the protocol layer alone (``FrameDecoder.feed``, then ``parse_contents``
   on each chunk's frames, no link bookkeeping): issue 17's "typed TM decode" beside
   "through Connection".
2. **Host stack, no pacing.** Pre-encoded ``TM`` bytes fed in chunks to a
   :class:`~fpgalink.testing.MemoryTransport` under a :class:`~fpgalink.aio.link.Link`, to a
   sample taken from a ``link.telemetry()`` subscription; wall rate and host CPU µs per
   message; every message must arrive (nothing lost, nothing dropped).
3. **Paced wire, one board.** ``fpgaemu serve --pty`` in a subprocess (1 MBd, paced to the
   wall clock), ``TsTimerPeriod`` 1 ms: achieved ``TM`` rate against the line's limit for that
   frame size, loss, latency from the board's sample time to the subscriber, host CPU.
4. **Paced wire, two boards** at 1 kHz each, as on the robot.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import importlib
import itertools
import os
import random
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from benchmarks._common import (
    Summary,
    chunked,
    common_parser,
    environment_line,
    percentile,
    print_table,
    report_header,
    start_emulator,
    stop_emulator,
    summarize,
    time_once,
    write_results,
)
from fpgalink import Connection, Role, open_link
from fpgalink.aio import Link
from fpgalink.protocol import (
    COUNTER_MODULUS,
    Binary,
    ChannelTelemetry,
    CountedMessage,
    FrameDecoder,
    MessageId,
    ParamAck,
    ParamSet,
    ParamType,
    References,
    Telemetry,
    encode_frame,
    encode_message,
    parse_contents,
    resolve,
)
from fpgalink.protocol.catalogue import layout
from fpgalink.protocol.wire import (
    Flow,
    bytes_per_second,
    frame_wire_bytes,
    largest_frame_wire_bytes,
    plan,
    wire_bytes,
)
from fpgalink.testing import MemoryTransport

NAME = "throughput"
SEED = 20_240_701
CHUNK = 4096  #: bytes per read for the bulk paths: what a serial read returns under load
LINE_RATE = 100_000  #: bytes/s of a 1 MBd UART, for the ``now`` the codec passes
BAUD = 1_000_000
PERIOD_MS = 1
#: ``E`` every 300 ms (SPEC §4): the board's own share of the board→host wire.
ALIVE_PERIOD_S = 0.3

#: issue 17: ours over pymavlink in messages/s, median of the repetitions paired in one run
TARGET_TYPED_TM_VS_PYMAVLINK = 4.0  #: FrameDecoder.feed + parse_contents
TARGET_CONNECTION_TM_VS_PYMAVLINK = 3.5  #: Connection.receive_data + events

#: MAVLink v2 messages with the same payload size as ours (the sizes actually sent are measured
#: and reported). Chosen for size first, then for a similar field mix.
MAVLINK_PEERS = {
    # TM: u32 time + ints and floats, 42 bytes. HIL_CONTROLS: u64 time, 8 floats, 2 u8.
    "TM": "HIL_CONTROLS",
    # RV: two float32. TERRAIN_CHECK: two int32.
    "RV": "TERRAIN_CHECK",
    # PS/PA: three u8 + 4-byte value. MISSION_REQUEST_PARTIAL_LIST: two i16 + three u8.
    "PS/PA": "MISSION_REQUEST_PARTIAL_LIST",
}


@dataclass(frozen=True, slots=True)
class BenchConfig:
    quick: bool = False
    reps: int = 5
    codec_messages: int = 100_000  #: per message kind and implementation
    stack_messages: int = 100_000  #: section 2, bulk reads
    stack_frame_messages: int = 40_000  #: section 2, one frame per read
    window_s: float = 5.0  #: sections 3 and 4: one repetition's wall time
    warmup_s: float = 1.0
    seed: int = SEED

    @classmethod
    def make(cls, *, quick: bool = False, reps: int | None = None,
             window_s: float | None = None, seed: int = SEED) -> BenchConfig:
        # --quick is small enough that the whole run, two emulator start-ups included, stays
        # well under 20 s: the smoke test checks the plumbing, not the speed.
        base = cls(True, 1, 2_000, 2_000, 500, 1.0, 0.3, seed) if quick else cls(seed=seed)
        return cls(
            base.quick, reps if reps is not None else base.reps, base.codec_messages,
            base.stack_messages, base.stack_frame_messages,
            window_s if window_s is not None else base.window_s, base.warmup_s, seed,
        )


# --- section 1: codec only --------------------------------------------------------------------


class _NullFile:
    """pymavlink's ``MAVLink`` wants a file to write to; bytes are only counted."""

    def __init__(self) -> None:
        self.bytes = 0

    def write(self, data: bytes) -> None:
        self.bytes += len(data)


@dataclass
class CodecCase:
    key: str  #: ``tm.encode.fpgalink``
    kind: str  #: ``TM``, ``RV``, ``PS/PA``
    operation: str  #: ``encode``, ``decode`` or ``decode_typed`` (protocol layer alone)
    impl: str  #: ``fpgalink`` or ``pymavlink``
    message: str  #: what is encoded or decoded
    payload_bytes: int
    messages: int
    wire_bytes: int
    run: Callable[[], int]
    seconds: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)  #: messages handled per repetition

    def rates(self) -> dict[str, list[float]]:
        return {
            "messages_per_s": [self.messages / s for s in self.seconds],
            "mb_per_s": [self.wire_bytes / s / 1e6 for s in self.seconds],
        }

    def result(self) -> dict[str, Any]:
        rates = self.rates()
        return {
            "kind": self.kind, "operation": self.operation, "implementation": self.impl,
            "message": self.message, "payload_bytes": self.payload_bytes,
            "messages": self.messages, "wire_bytes": self.wire_bytes,
            "wire_bytes_per_message": self.wire_bytes / self.messages,
            "repetitions": [
                {"seconds": s, "messages_handled": self.counts[i],
                 **{k: v[i] for k, v in rates.items()}}
                for i, s in enumerate(self.seconds)
            ],
            "summary": {k: summarize(v) for k, v in rates.items()},
        }


def _random_tm(rng: random.Random, i: int) -> Telemetry:
    # In-range random values: the codec only cares how many bytes need escaping, and random
    # low-order bytes give that its natural rate.
    def channel() -> ChannelTelemetry:
        return ChannelTelemetry(
            rng.randint(-(2**31), 2**31 - 1), rng.uniform(-720, 720), rng.uniform(-5, 5),
            rng.randint(-32760, 32760), rng.uniform(-360, 360), rng.randint(0, 7),
        )

    return Telemetry(rng.getrandbits(32), channel(), channel())


def _our_messages(rng: random.Random, n: int) -> dict[str, tuple[list[Any], list[Any]]]:
    """Per kind: (messages to encode, messages whose wire is decoded). ``PS`` is what the host
    sends and ``PA`` what it receives; they share one body layout."""
    kp, kp_channel = resolve("Kp_Wheel_PidA")
    tm = [_random_tm(rng, i) for i in range(n)]
    rv = [References(rng.uniform(-90, 90), rng.uniform(-90, 90)) for _ in range(n)]
    values = [rng.uniform(0.0, 50.0) for _ in range(n)]
    ps = [ParamSet(kp.id, kp_channel, int(ParamType.FLOAT), v) for v in values]
    pa = [ParamAck(kp.id, kp_channel, int(ParamType.FLOAT), v) for v in values]
    return {"TM": (tm, tm), "RV": (rv, rv), "PS/PA": (ps, pa)}


def _connection(role: Role) -> Connection:
    # baud=None: no reference pacing, so every RV leaves at once. With pacing, RVs sent
    # faster than the line drains would wait and be superseded, and the codec would be
    # measured doing less than one frame per message.
    return Connection(role=role, baud=None)


def _wire_of(messages: list[Any], role: Role) -> list[bytes]:
    """Each message's frame as a user of the library gets it (untimed: the streams to decode
    and the byte counts)."""
    conn = _connection(role)
    frames = []
    for m in messages:
        conn.send(m, 0.0)
        frames.append(conn.data_to_send())
    return frames


def _encode_ours(messages: list[Any], role: Role) -> Callable[[], int]:
    def run() -> int:
        conn = _connection(role)
        send, take = conn.send, conn.data_to_send
        n = 0
        for m in messages:
            send(m, 0.0)
            if take():
                n += 1
        return n

    return run


def _decode_ours(chunks: list[bytes], expected: type) -> Callable[[], int]:
    # A chunk takes CHUNK / LINE_RATE s on the wire; passing that ``now`` keeps liveness in
    # the measured work, as on a real port.
    dt = CHUNK / LINE_RATE

    def run() -> int:
        conn = Connection(role=Role.HOST if expected in (Telemetry, ParamAck) else Role.BOARD)
        receive, events = conn.receive_data, conn.events
        now = 0.0
        n = 0
        for chunk in chunks:
            receive(chunk, now)
            now += dt
            for event in events():
                if type(event) is expected:
                    n += 1
        return n

    return run


def _decode_typed(chunks: list[bytes]) -> Callable[[], int]:
    """The protocol layer alone: a chunk's frames, then their contents to typed messages
    (``parse_contents``: a chunk at a time, as ``MAVLink.parse_buffer`` takes one)."""

    def run() -> int:
        feed = FrameDecoder().feed
        n = 0
        for chunk in chunks:
            # A consumer must tell frames from framing-error events; so does this loop.
            frames = [item for item in feed(chunk) if type(item) is bytes]
            n += sum(type(m) is Telemetry for m in parse_contents(frames))
        return n

    return run


def _mavlink_module() -> Any:
    """The MAVLink v2 ``common`` dialect, or ``None`` without pymavlink (an optional extra)."""
    try:
        return importlib.import_module("pymavlink.dialects.v20.common")
    except ImportError:
        return None


def _mavlink_messages(mav_mod: Any, rng: random.Random, n: int) -> dict[str, list[Any]]:
    # Every field non-zero where it ends the payload: MAVLink v2 strips trailing zero bytes,
    # which would make the pymavlink frames shorter than the size being compared.
    mav = mav_mod.MAVLink(_NullFile(), srcSystem=1, srcComponent=1)

    def hil_controls() -> Any:
        floats = [rng.uniform(-1, 1) for _ in range(8)]
        return mav.hil_controls_encode(rng.getrandbits(63), *floats, rng.randint(1, 255),
                                       rng.randint(1, 255))

    return {
        "TM": [hil_controls() for _ in range(n)],
        "RV": [mav.terrain_check_encode(rng.randint(1, 2**31 - 1), rng.randint(1, 2**31 - 1))
               for _ in range(n)],
        "PS/PA": [mav.mission_request_partial_list_encode(
            rng.randint(1, 255), rng.randint(1, 255), rng.randint(1, 30000),
            rng.randint(1, 30000), rng.randint(1, 255)) for _ in range(n)],
    }


def _encode_mavlink(mav_mod: Any, messages: list[Any]) -> Callable[[], int]:
    def run() -> int:
        mav = mav_mod.MAVLink(_NullFile(), srcSystem=1, srcComponent=1)
        send = mav.send
        for m in messages:
            send(m)
        return int(mav.total_packets_sent)

    return run


def _decode_mavlink(mav_mod: Any, chunks: list[bytes]) -> Callable[[], int]:
    def run() -> int:
        mav = mav_mod.MAVLink(_NullFile())
        parse = mav.parse_buffer
        n = 0
        for chunk in chunks:
            got = parse(chunk)
            if got:
                n += len(got)
        if mav.total_receive_errors:
            raise AssertionError(f"pymavlink reported {mav.total_receive_errors} errors")
        return n

    return run


def _codec_cases(config: BenchConfig, rng: random.Random) -> tuple[list[CodecCase], dict[str, Any]]:
    cases: list[CodecCase] = []
    ours = _our_messages(rng, config.codec_messages)
    body_size = {"TM": layout(MessageId.TM).sizeof(), "RV": layout(MessageId.RV).sizeof(),
                 "PS/PA": layout(MessageId.PS).sizeof()}
    for kind, (to_encode, to_decode) in ours.items():
        key = kind.split("/")[0].lower()
        enc_role = Role.BOARD if kind == "TM" else Role.HOST
        dec_role = Role.BOARD if kind in ("TM", "PS/PA") else Role.HOST
        enc_wire = sum(map(len, _wire_of(to_encode, enc_role)))
        dec_stream = b"".join(_wire_of(to_decode, dec_role))
        expected = type(to_decode[0])
        enc_name, dec_name = to_encode[0].msg_id.decode(), to_decode[0].msg_id.decode()
        cases.append(CodecCase(f"{key}.encode.fpgalink", kind, "encode", "fpgalink", enc_name,
                               body_size[kind], len(to_encode), enc_wire,
                               _encode_ours(to_encode, enc_role)))
        cases.append(CodecCase(f"{key}.decode.fpgalink", kind, "decode", "fpgalink", dec_name,
                               body_size[kind], len(to_decode), len(dec_stream),
                               _decode_ours(chunked(dec_stream, CHUNK), expected)))
        if kind == "TM":
            cases.append(CodecCase(f"{key}.decode_typed.fpgalink", kind, "decode_typed",
                                   "fpgalink", dec_name, body_size[kind], len(to_decode),
                                   len(dec_stream), _decode_typed(chunked(dec_stream, CHUNK))))

    mav_mod = _mavlink_module()
    peers: dict[str, Any] = {"available": mav_mod is not None}
    if mav_mod is None:
        return cases, peers
    peers["fast_crc"] = getattr(mav_mod, "x25crc", None) is getattr(mav_mod, "_x25crc_fast", 0)
    theirs = _mavlink_messages(mav_mod, rng, config.codec_messages)
    for kind, messages in theirs.items():
        key = kind.split("/")[0].lower()
        # One encoding pass, untimed, gives the decode stream and the real payload sizes.
        mav = mav_mod.MAVLink(_NullFile(), srcSystem=1, srcComponent=1)
        frames = []
        for m in messages:
            frames.append(m.pack(mav))
            mav.seq = (mav.seq + 1) % 256
        payloads = [len(m.get_payload()) for m in messages]
        name = messages[0].msgname
        if name != MAVLINK_PEERS[kind]:
            raise AssertionError(f"{kind}: built {name}, meant {MAVLINK_PEERS[kind]}")
        peers[kind] = {
            "message": name, "id": messages[0].id, "ours_payload_bytes": body_size[kind],
            "payload_bytes_min": min(payloads), "payload_bytes_max": max(payloads),
            "wire_bytes_per_message": sum(map(len, frames)) / len(frames),
        }
        stream = b"".join(frames)
        label = f"{name} (#{messages[0].id})"
        cases.append(CodecCase(f"{key}.encode.pymavlink", kind, "encode", "pymavlink", label,
                               max(payloads), len(messages), len(stream),
                               _encode_mavlink(mav_mod, messages)))
        cases.append(CodecCase(f"{key}.decode.pymavlink", kind, "decode", "pymavlink", label,
                               max(payloads), len(messages), len(stream),
                               _decode_mavlink(mav_mod, chunked(stream, CHUNK))))
    return cases, peers


def _codec_ratios(cases: dict[str, CodecCase]) -> dict[str, Any]:
    """ours/pymavlink in messages/s, pairing the repetitions of this run one to one."""
    out: dict[str, Any] = {}
    for key, case in cases.items():
        if case.impl != "fpgalink":
            continue
        # pymavlink has one decode path: both of ours are held against it.
        peer = cases.get(f"{key.split('.')[0]}.{case.operation.split('_')[0]}.pymavlink")
        if peer is None:
            continue
        ours, theirs = case.rates()["messages_per_s"], peer.rates()["messages_per_s"]
        per_rep = [a / b for a, b in zip(ours, theirs, strict=True)]
        out[key.replace(".fpgalink", "")] = {"repetitions": per_rep, "summary": summarize(per_rep)}
    return out


# --- section 2: host stack without wire pacing ------------------------------------------------


@dataclass
class StackCase:
    key: str
    label: str
    chunks: list[bytes]
    messages: int
    seconds: list[float] = field(default_factory=list)
    cpu_seconds: list[float] = field(default_factory=list)
    #: per repetition: delivered to the subscriber, lost (counter gaps), subscriber drops
    counts: list[dict[str, int]] = field(default_factory=list)

    def result(self) -> dict[str, Any]:
        rates = [self.messages / s for s in self.seconds]
        cpu_us = [c / self.messages * 1e6 for c in self.cpu_seconds]
        return {
            "label": self.label, "messages": self.messages,
            "wire_bytes": sum(map(len, self.chunks)), "reads": len(self.chunks),
            "repetitions": [
                {"seconds": s, "messages_per_s": r, "cpu_seconds": c, "cpu_us_per_message": u,
                 **n}
                for s, r, c, u, n in zip(self.seconds, rates, self.cpu_seconds, cpu_us,
                                         self.counts, strict=True)
            ],
            "summary": {"messages_per_s": summarize(rates),
                        "cpu_us_per_message": summarize(cpu_us)},
        }


def _tm_wire(rng: random.Random, n: int) -> tuple[bytes, list[bytes]]:
    frames = _wire_of([_random_tm(rng, i) for i in range(n)], Role.BOARD)
    return b"".join(frames), frames


async def _run_stack_once(case: StackCase) -> tuple[float, float, dict[str, int]]:
    # The benchmark plays the event loop's reader: MemoryTransport.feed hands each read to
    # the same protocol callback a serial port's transport would call.
    transport = MemoryTransport()
    link = Link(Connection(), transport, name="bench", reconnect=False)
    await link.open()
    sub = link.telemetry()
    feed = transport.feed
    delivered = 0

    async def consume() -> None:
        nonlocal delivered
        async for _sample in sub:
            delivered += 1

    consumer = asyncio.ensure_future(consume())
    await asyncio.sleep(0)  # the consumer is now waiting on the subscription, as in real use
    gc.collect()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for chunk in case.chunks:
        feed(chunk)
        # One loop iteration per read, as a selector-driven transport gives: the subscriber
        # task runs and drains what this read delivered before the next read arrives.
        await asyncio.sleep(0)
    sub.close()  # ends the consumer once it has drained the last read
    await consumer
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    stats = link.stats.snapshot()
    await link.close()
    if delivered != case.messages or stats.lost or stats.subscriber_drops:
        raise AssertionError(
            f"{case.key}: delivered {delivered} of {case.messages} (lost {stats.lost}, "
            f"subscriber drops {stats.subscriber_drops})")
    return wall, cpu, {"sent": case.messages, "delivered": delivered, "lost": stats.lost,
                       "subscriber_drops": stats.subscriber_drops,
                       "decode_errors": stats.decode_errors}


def _stack_cases(config: BenchConfig, rng: random.Random) -> list[StackCase]:
    bulk, _ = _tm_wire(rng, config.stack_messages)
    _, frames = _tm_wire(rng, config.stack_frame_messages)
    return [
        StackCase("tm.bulk", f"TM, {CHUNK}-byte reads", chunked(bulk, CHUNK),
                  config.stack_messages),
        # At 1 kHz on a real port each read carries about one frame: the per-read cost of the
        # transport callback and one loop iteration is then paid per message.
        StackCase("tm.per_frame", "TM, one frame per read", frames, config.stack_frame_messages),
    ]


# --- sections 3 and 4: the paced wire ---------------------------------------------------------


def _proc_cpu_seconds(pid: int) -> float | None:
    """User + system CPU of another process (the emulator), from /proc; ``None`` elsewhere."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        # Fields 14 and 15 of stat(5), counted after the ")" that ends the command name.
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class _Recorder:
    """Consumes one link's telemetry subscription, stamping each sample on arrival."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.sub = link.telemetry()
        self.window: list[tuple[float, float, Telemetry]] | None = None
        self._last_raw: int | None = None
        self._wraps = 0
        self.task = asyncio.ensure_future(self._consume())

    async def _consume(self) -> None:
        clock = time.monotonic
        async for sample in self.sub:
            arrived = clock()
            raw = sample.t_us
            # t_us wraps at 2**32 µs (71 min); unwrap so long runs stay monotonic.
            if self._last_raw is not None and raw < self._last_raw - 2**31:
                self._wraps += 1
            self._last_raw = raw
            if self.window is not None:
                board_s = (raw + self._wraps * 2**32) / 1e6
                self.window.append((arrived, board_s, sample))

    def start(self) -> None:
        self.window = []

    def stop(self) -> list[tuple[float, float, Telemetry]]:
        taken, self.window = self.window or [], None
        return taken


def _payload_limits(baud: int, period_ms: int) -> dict[str, Any]:
    """The largest binary payload one counted message can carry per timer period, from the
    budget arithmetic, and checked by encoding a real frame of that size."""
    period_s = period_ms / 1000
    capacity = largest_frame_wire_bytes(baud, period_s)
    # ID, counter, "{", LEN, "}": the content a message has around its payload.
    overhead = len(encode_message(CountedMessage("XX", (Binary(b""),)), 0))
    alive = Flow("E", 1, per_period=period_s / ALIVE_PERIOD_S)

    def largest(escaped: bool, with_alive: bool) -> int:
        best = 0
        for d in range(0, 255):
            flows = [Flow("payload", overhead + d, escapes=d if escaped else 0)]
            if with_alive:
                flows.append(alive)
            if plan(baud, period_s, flows).fits:
                best = d
        return best

    plain, escaped = largest(False, False), largest(True, False)
    # Encode frames of those sizes for real: plain bytes, and bytes that all need escaping.
    check_plain = wire_bytes(encode_message(CountedMessage("XX", (Binary(b"a" * plain),)), 0))
    check_esc = len(encode_frame(encode_message(CountedMessage("XX", (Binary(b"S" * escaped),)),
                                                0)))
    if check_plain > capacity or check_esc > capacity:
        raise AssertionError("budget arithmetic disagrees with the encoder")
    return {
        "period_ms": period_ms, "capacity_wire_bytes": capacity,
        "message_overhead_content_bytes": overhead,
        "framing_wire_bytes": frame_wire_bytes(overhead),
        "largest_payload_bytes": plain,
        "largest_payload_bytes_all_escaped": escaped,
        "largest_payload_bytes_with_alive": largest(False, True),
        "largest_payload_bytes_all_escaped_with_alive": largest(True, True),
        "tm_payload_bytes": layout(MessageId.TM).sizeof(),
    }


async def _paced(config: BenchConfig, boards: int,
                 step: Callable[[str], None]) -> dict[str, Any]:
    proc, ready = await start_emulator(boards, BAUD)
    reps: list[dict[str, Any]] = []
    windows: dict[str, list[list[tuple[float, float, Telemetry]]]] = {n: [] for n, _ in ready}
    try:
        async with contextlib.AsyncExitStack() as stack:
            links: dict[str, Link] = {}
            for name, path in ready:
                link = open_link(path, BAUD, name=name, reconnect=False)
                links[name] = await stack.enter_async_context(link)
            for link in links.values():
                await link.set_param("TsTimerPeriod", PERIOD_MS)
                await link.set_param("GetDataPeriodical", 1)
            recorders = {name: _Recorder(link) for name, link in links.items()}
            step(f"{boards} board(s): warm-up")
            await asyncio.sleep(config.warmup_s)
            for rep in range(config.reps):
                step(f"{boards} board(s): repetition {rep + 1}/{config.reps}")
                before = {n: link.stats.snapshot() for n, link in links.items()}
                emu0 = _proc_cpu_seconds(proc.pid)
                for rec in recorders.values():
                    rec.start()
                wall0, cpu0 = time.monotonic(), time.process_time()
                await asyncio.sleep(config.window_s)
                taken = {n: rec.stop() for n, rec in recorders.items()}
                wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
                emu1 = _proc_cpu_seconds(proc.pid)
                rep_out: dict[str, Any] = {
                    "seconds": wall,
                    "host_cpu_percent": cpu / wall * 100,
                    "emulator_cpu_percent": (
                        (emu1 - emu0) / wall * 100 if emu0 is not None and emu1 is not None
                        else None),
                    "boards": {},
                }
                for n, link in links.items():
                    after, b = link.stats, before[n]
                    windows[n].append(taken[n])
                    rep_out["boards"][n] = {
                        **_counter_check([s.counter for _, _, s in taken[n]]),
                        "tm_received": len(taken[n]),
                        "tm_per_s": len(taken[n]) / wall,
                        "lost": after.lost - b.lost,
                        "subscriber_drops": after.subscriber_drops - b.subscriber_drops,
                        "decode_errors": after.decode_errors - b.decode_errors,
                        "wire_bytes_per_s": (after.bytes_received - b.bytes_received) / wall,
                    }
                reps.append(rep_out)
            for rec in recorders.values():
                rec.sub.close()
                await rec.task
    finally:
        emulator_exit, emulator_said = await stop_emulator(proc)
    result = _paced_result(config, boards, reps, windows, emulator_said)
    result["emulator_exit_code"] = emulator_exit
    return result


def _counter_check(counters: list[int | None]) -> dict[str, int]:
    """From the samples a subscriber took: every counter from the first to the last is
    either received or missing (lost on the wire or dropped by a slow subscriber)."""
    seen = [c for c in counters if c is not None]
    if not seen:
        return {"counter_span": 0, "counters_missing": 0}
    missing = sum((b - a - 1) % COUNTER_MODULUS for a, b in itertools.pairwise(seen))
    return {"counter_span": (seen[-1] - seen[0]) % COUNTER_MODULUS + 1,
            "counters_missing": missing}


def _percentile_or_none(values: Sequence[float], q: float) -> float | None:
    # A board that delivered nothing in a window has no latency; None keeps the report
    # valid JSON where a NaN would not be.
    return percentile(values, q) if values else None


def _summary_or_none(values: Sequence[float | None]) -> Summary | None:
    present = [v for v in values if v is not None]
    return summarize(present) if present else None


def _paced_result(config: BenchConfig, boards: int, reps: list[dict[str, Any]],
                  windows: dict[str, list[list[tuple[float, float, Telemetry]]]],
                  emulator_said: str) -> dict[str, Any]:
    line_bps = bytes_per_second(BAUD)
    scheduled = 1000 / PERIOD_MS
    # The emulator's board clock starts at its power-up, at an instant this process does not
    # know; arrival − board time is that offset plus the latency. Its minimum over the run is
    # the offset plus the fastest delivery, so latencies are reported above that minimum.
    offsets = {
        n: min(arrived - board for w in ws for arrived, board, _ in w)
        for n, ws in windows.items() if any(ws)
    }
    for i, rep in enumerate(reps):
        all_latency: list[float] = []
        for n, ws in windows.items():
            samples = ws[i]
            board_out = rep["boards"][n]
            # The frames as the board sent them: re-encoded with the counter each carried.
            wires = [len(encode_frame(encode_message(s, s.counter or 0))) for _, _, s in samples]
            mean_wire = sum(wires) / len(wires) if wires else None
            latency = [(arrived - board - offsets[n]) * 1000 for arrived, board, _ in samples]
            all_latency += latency
            board_out.update({
                "tm_wire_bytes_mean": mean_wire,
                "line_limit_tm_per_s": line_bps / mean_wire if mean_wire else None,
                "line_fraction": (board_out["tm_per_s"] / (line_bps / mean_wire)
                                  if mean_wire else None),
                "scheduled_tm_per_s": scheduled,
                "scheduled_fraction": board_out["tm_per_s"] / scheduled,
                "wire_utilisation": board_out["wire_bytes_per_s"] / line_bps,
                "latency_ms_p50": _percentile_or_none(latency, 50),
                "latency_ms_p99": _percentile_or_none(latency, 99),
                "latency_ms_max": max(latency, default=None),
            })
        rep["tm_per_s_total"] = sum(b["tm_per_s"] for b in rep["boards"].values())
        rep["lost_total"] = sum(b["lost"] for b in rep["boards"].values())
        rep["latency_ms_p50"] = _percentile_or_none(all_latency, 50)
        rep["latency_ms_p99"] = _percentile_or_none(all_latency, 99)
    names = list(windows)

    def series(key: str) -> Summary | None:
        return _summary_or_none([r[key] for r in reps])

    summary: dict[str, Any] = {
        "tm_per_s_total": series("tm_per_s_total"),
        "lost_total": sum(r["lost_total"] for r in reps),
        "subscriber_drops_total": sum(b["subscriber_drops"] for r in reps
                                      for b in r["boards"].values()),
        "latency_ms_p50": series("latency_ms_p50"),
        "latency_ms_p99": series("latency_ms_p99"),
        "host_cpu_percent": series("host_cpu_percent"),
        "emulator_cpu_percent": series("emulator_cpu_percent"),
        "boards": {
            n: {k: _summary_or_none([r["boards"][n][k] for r in reps])
                for k in ("tm_per_s", "line_limit_tm_per_s", "line_fraction",
                          "scheduled_fraction", "wire_utilisation", "tm_wire_bytes_mean",
                          "latency_ms_p50", "latency_ms_p99")}
            for n in names
        },
    }
    return {
        "boards": boards, "board_names": names, "baud": BAUD,
        "line_bytes_per_s": line_bps, "ts_timer_period_ms": PERIOD_MS,
        "scheduled_tm_per_s_per_board": scheduled, "window_s": config.window_s,
        "warmup_s": config.warmup_s,
        "latency_reference": (
            "arrival (host monotonic clock, at the subscriber) minus the TM's t_us, minus the "
            "minimum of that difference over the run per board"),
        "latency_offset_s": offsets,
        "emulator_pacing": "deadlines (no fixed tick)",
        "emulator_stderr": emulator_said,
        "repetitions": reps,
        "summary": summary,
    }


# --- the run ----------------------------------------------------------------------------------


def _steps(config: BenchConfig, codec_cases: int, stack_cases: int) -> int:
    # One per unit of work: preparing each of the first two sections, their cases per
    # repetition, and per paced section a start-up, a warm-up and the repetitions.
    return 2 + config.reps * (codec_cases + stack_cases) + 2 * (2 + config.reps)


@contextlib.contextmanager
def _progress(enabled: bool, total: int) -> Iterator[Callable[[str], None]]:
    if not enabled:
        yield lambda _label: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    # On stderr, so stdout carries only the report and can be redirected to a file.
    with Progress(TextColumn("{task.description:<44}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(),
                  console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("starting", total=total)
        first = True

        def step(label: str) -> None:
            nonlocal first
            # Each call starts a unit; the previous one is then done.
            bar.update(task, description=label, advance=0 if first else 1)
            first = False

        yield step
        bar.update(task, completed=total)


def _run_codec(config: BenchConfig, rng: random.Random,
               step: Callable[[str], None]) -> dict[str, Any]:
    step("1 codec: preparing messages")
    codec, peers = _codec_cases(config, rng)
    # Repetitions interleave the cases, so a slow spell on the machine spreads over all of
    # them instead of sinking one, and each ratio pairs neighbours in time.
    for rep in range(config.reps):
        for case in codec:
            step(f"1 codec: {case.key} ({rep + 1}/{config.reps})")
            seconds, count = time_once(case.run)
            if count != case.messages:
                raise AssertionError(f"{case.key}: {count} messages, not {case.messages}")
            case.seconds.append(seconds)
            case.counts.append(count)
    by_key = {c.key: c for c in codec}
    ratios = _codec_ratios(by_key)
    return {
        "pymavlink": peers,
        "cases": {k: c.result() for k, c in by_key.items()},
        "ratios_fpgalink_over_pymavlink": ratios,
        "targets": _codec_targets(ratios),
    }


def _codec_targets(ratios: dict[str, Any]) -> list[dict[str, Any]]:
    """Issue 17's codec targets against pymavlink; none without pymavlink to measure."""
    metric = "× pymavlink msg/s (median of paired repetitions)"
    out = []
    for name, key, threshold in (
        ("typed TM decode vs pymavlink", "tm.decode_typed", TARGET_TYPED_TM_VS_PYMAVLINK),
        ("TM through Connection vs pymavlink", "tm.decode", TARGET_CONNECTION_TM_VS_PYMAVLINK),
    ):
        if key not in ratios:
            continue
        measured = ratios[key]["summary"]["median"]
        out.append({"name": name, "case": key, "metric": metric, "measured": measured,
                    "threshold": threshold, "pass": measured >= threshold})
    return out


def _run_stack(config: BenchConfig, rng: random.Random,
               step: Callable[[str], None]) -> dict[str, Any]:
    step("2 host stack: preparing TM streams")
    stack = _stack_cases(config, rng)
    for rep in range(config.reps):
        for case in stack:
            step(f"2 host stack: {case.key} ({rep + 1}/{config.reps})")
            wall, cpu, counts = asyncio.run(_run_stack_once(case))
            case.seconds.append(wall)
            case.cpu_seconds.append(cpu)
            case.counts.append(counts)
    return {
        "path": "MemoryTransport.feed → Link → Connection → telemetry() subscriber",
        "cases": {c.key: c.result() for c in stack},
    }


def run(config: BenchConfig, *, progress: bool = True,
        argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Run every section and return the report (what ``write_results`` stores)."""
    started = time.perf_counter()
    rng = random.Random(config.seed)
    codec_cases = 7 + (6 if _mavlink_module() is not None else 0)
    with _progress(progress, _steps(config, codec_cases, 2)) as step:
        codec = _run_codec(config, rng, step)
        stack = _run_stack(config, rng, step)
        # The first sections' millions of message objects are gone by now; collect them here,
        # or a full collection that scans them could stall the paced streams mid-run (seen as
        # a half-second gap, pty overflow and lost TMs), which would be the benchmark's own
        # doing, not the stack's.
        gc.collect()
        paced: dict[str, Any] = {}
        for boards in (1, 2):
            step(f"{boards + 2} paced: starting {boards} emulated board(s)")
            paced[str(boards)] = asyncio.run(_paced(config, boards, step))

    elapsed = time.perf_counter() - started
    return {
        **report_header(NAME, ["pymavlink", "fastcrc", "pyserial", "pyserial-asyncio", "rich",
                               "construct"]),
        "config": {
            "quick": config.quick, "reps": config.reps, "seed": config.seed,
            "codec_messages": config.codec_messages,
            "stack_messages": config.stack_messages,
            "stack_frame_messages": config.stack_frame_messages,
            "paced_window_s": config.window_s, "paced_warmup_s": config.warmup_s,
            "chunk_size": CHUNK, "baud": BAUD, "ts_timer_period_ms": PERIOD_MS,
            "mb": "10^6 wire bytes",
            "argv": list(argv) if argv is not None else sys.argv[1:],
        },
        "codec": codec,
        "host_stack": stack,
        "paced_1_board": paced["1"],
        "paced_2_boards": paced["2"],
        "payload_limit": _payload_limits(BAUD, PERIOD_MS),
        "timing": {"total_s": elapsed},
    }


# --- the report -------------------------------------------------------------------------------


def _num(x: float | None) -> str:
    if x is None:
        return "n/a"
    if abs(x) >= 99.5:  # rounds to a whole number of three or more digits
        return f"{x:,.0f}"
    return f"{x:.3g}" if abs(x) >= 1 else f"{x:.2g}"


def _range(s: dict[str, float] | None) -> str:
    return "" if s is None else f"{_num(s['min'])}–{_num(s['max'])}"


def _med(s: dict[str, float] | None) -> str:
    return "n/a" if s is None else _num(s["median"])


def _pct(x: dict[str, float] | None) -> dict[str, float] | None:
    return None if x is None else {k: v * 100 for k, v in x.items()}


def print_report(report: dict[str, Any]) -> None:
    rows: list[list[str]] = []

    def row(section: str, what: str, s: dict[str, float] | None, unit: str,
            note: str = "") -> None:
        rows.append([section, what, _med(s), _range(s), unit, note])

    codec = report["codec"]
    cases, ratios, peers = codec["cases"], codec["ratios_fpgalink_over_pymavlink"], \
        codec["pymavlink"]
    for kind in ("tm", "rv", "ps"):
        for op in ("encode", "decode", "decode_typed"):
            ours = cases.get(f"{kind}.{op}.fpgalink")
            if ours is None:
                continue
            label = f"{ours['message']} {op} ({ours['payload_bytes']} B payload)"
            if op == "decode_typed":
                label = f"{ours['message']} decode, FrameDecoder.feed + parse_contents"
            row("1 codec", f"fpgalink {label}", ours["summary"]["messages_per_s"], "msg/s",
                f"{ours['summary']['mb_per_s']['median']:.2f} MB/s, "
                f"{ours['wire_bytes_per_message']:.1f} wire B/msg")
            theirs = cases.get(f"{kind}.{op.split('_')[0]}.pymavlink")
            if theirs is None:
                continue
            if op != "decode_typed":  # its peer row is the decode row just above
                row("1 codec", f"pymavlink {theirs['message']} ({theirs['payload_bytes']} B)",
                    theirs["summary"]["messages_per_s"], "msg/s",
                    f"{theirs['summary']['mb_per_s']['median']:.2f} MB/s, "
                    f"{theirs['wire_bytes_per_message']:.1f} wire B/msg")
            row("1 codec", "  ratio fpgalink/pymavlink", ratios[f"{kind}.{op}"]["summary"],
                "×", "same run, repetitions paired")

    for case in report["host_stack"]["cases"].values():
        s = case["summary"]
        delivered = sum(r["delivered"] for r in case["repetitions"])
        lost = sum(r["lost"] + r["subscriber_drops"] for r in case["repetitions"])
        row("2 host stack", case["label"], s["messages_per_s"], "msg/s",
            f"MemoryTransport.feed → Link → telemetry(); {delivered:,} delivered, {lost} lost")
        row("2 host stack", "  host CPU per message", s["cpu_us_per_message"], "µs",
            "time.process_time")

    paced = (("paced_1_board", "3 paced 1 board"), ("paced_2_boards", "4 paced 2 boards"))
    for sec, label in paced:
        p = report[sec]
        summ = p["summary"]
        for name in p["board_names"]:
            b = summ["boards"][name]
            fraction = b["line_fraction"]
            row(label, f"TM rate, board {name}", b["tm_per_s"], "msg/s",
                f"timer {_num(p['scheduled_tm_per_s_per_board'])}/s; line limit "
                f"{_med(b['line_limit_tm_per_s'])}/s at {_med(b['tm_wire_bytes_mean'])} "
                f"wire B/TM = {_med(_pct(fraction))} % of it")
        if p["boards"] > 1:
            row(label, "TM rate, all boards", summ["tm_per_s_total"], "msg/s")
        received = sum(b["tm_received"] for r in p["repetitions"] for b in r["boards"].values())
        rows.append([label, "TM lost (counter gaps)", str(summ["lost_total"]), "", "",
                     f"{received:,} received; subscriber drops "
                     f"{summ['subscriber_drops_total']}; all repetitions"])
        row(label, "latency p50 (above fastest)", summ["latency_ms_p50"], "ms",
            "board sample time → subscriber")
        row(label, "latency p99 (above fastest)", summ["latency_ms_p99"], "ms")
        row(label, "host CPU", summ["host_cpu_percent"], "% core", "this process")
        row(label, "emulator CPU", summ["emulator_cpu_percent"], "% core", "fpgaemu serve")
        if sec == "paced_1_board":
            lim = report["payload_limit"]
            rows.append([label, f"largest payload per {lim['period_ms']} ms period",
                         str(lim["largest_payload_bytes"]), "", "B",
                         f"{lim['capacity_wire_bytes']} wire B − "
                         f"{lim['framing_wire_bytes']} framing; TM uses "
                         f"{lim['tm_payload_bytes']}"])
            rows.append([label, "  … if every payload byte is escaped",
                         str(lim["largest_payload_bytes_all_escaped"]), "", "B",
                         f"{lim['largest_payload_bytes_with_alive']} / "
                         f"{lim['largest_payload_bytes_all_escaped_with_alive']} B leaving room "
                         "for E every 300 ms"])

    cfg = report["config"]
    first = report["paced_1_board"]
    tm_wire = first["summary"]["boards"][first["board_names"][0]]["tm_wire_bytes_mean"]
    tm_wire_us = (None if tm_wire is None
                  else tm_wire["median"] / bytes_per_second(cfg["baud"]) * 1e6)
    # A section's name only on its first row, so the table reads as groups.
    for i in range(len(rows) - 1, 0, -1):
        if rows[i][0] == rows[i - 1][0]:
            rows[i][0] = ""
    print("fpgalink throughput")
    print(environment_line(report))
    print(f"median of {cfg['reps']} repetition(s), min–max beside it; MB = 10^6 wire bytes; "
          f"line {cfg['baud']:,} Bd 8N1 = {bytes_per_second(cfg['baud']):,.0f} B/s")
    print()
    print_table(["section", "measurement", "median", "min–max", "unit", "notes"], rows,
                align="<<>><<")
    print()
    if codec.get("targets"):
        print_table(
            ["target", "measured", "threshold", "result"],
            [[t["name"], f"{t['measured']:.2f}", f"≥ {t['threshold']:g}",
              "PASS" if t["pass"] else "FAIL"] for t in codec["targets"]],
            align="<>><",
        )
        print()
    lines: list[str] = []
    if peers.get("available"):
        lines.append(
            "pymavlink: MAVLink v2 (dialect common), encode = MAVLink.send to a null file, decode "
            f"= MAVLink.parse_buffer on {CHUNK}-byte chunks; fast CRC "
            f"{'on' if peers.get('fast_crc') else 'off'}. Peers: "
            + ", ".join(f"{k} ↔ {v['message']}" for k, v in peers.items()
                        if isinstance(v, dict)) + ".")
    else:
        lines.append("pymavlink is not installed (pip install fpgalink[bench]): no comparison.")
    lines += [
        "fpgalink: encode = Connection.send + data_to_send per message, as a library user "
        "does (baud=None: no reference pacing, so every RV is sent), decode = "
        f"Connection.receive_data on {CHUNK}-byte chunks to typed events (PS/PA: the host "
        "encodes PS and decodes PA); TM is also decoded by FrameDecoder.feed + parse_contents on "
        "each chunk's frames (the protocol layer without the link), held against the same "
        "pymavlink decode.",
        "Latency: the board stamps each TM with t_us, its sample time in µs since its power-up; "
        "the host stamps arrival at the subscriber. The emulator is paced to the wall clock "
        "from its own start, an instant not known here, so latency is arrival − t_us minus the "
        "minimum of that over the run (per board): the fastest sample counts as 0, though it "
        f"too spent at least its frame's wire time (~{_num(tm_wire_us)} µs) on the line. The "
        "emulator hands each frame to its pty when its last stop bit ends.",
    ]
    for sec in ("paced_1_board", "paced_2_boards"):
        said = report[sec]["emulator_stderr"]
        if said:
            lines.append(f"emulator ({sec}): {' | '.join(said.splitlines())}")
    for line in lines:
        print(line)


# --- the command line -------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME,
                           "tiny counts and short streams, one repetition (< 20 s; the smoke "
                           "test)")
    parser.add_argument("--reps", type=int, default=None,
                        help="repetitions per measurement (default 5, --quick 1)")
    parser.add_argument("--window", dest="window_s", type=float, default=None,
                        help="seconds of paced streaming per repetition (default 5, --quick 1)")
    parser.add_argument("--seed", type=int, default=SEED,
                        help=f"seed for the random message contents (default {SEED})")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    args = parser.parse_args(argv)
    if args.reps is not None and not 1 <= args.reps <= 100:
        parser.error("--reps must be from 1 to 100")
    if args.window_s is not None and not 0.2 <= args.window_s <= 600:
        parser.error("--window must be from 0.2 to 600 s")
    config = BenchConfig.make(quick=args.quick, reps=args.reps, window_s=args.window_s,
                              seed=args.seed)
    report = run(config, progress=not args.no_progress,
                 argv=sys.argv[1:] if argv is None else argv)
    path = write_results(NAME, report, args.output)
    print_report(report)
    print(f"\n{report['timing']['total_s']:.0f} s in all; results in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
