"""What ``fpgalink-cli router`` costs as its clients grow: one board (``fpgaemu serve
--pty`` in its own process) streaming telemetry at 1 kHz, one controller asking a parameter
every 20 ms, and 0 to 16 observers reading every frame. For each count: the router's CPU,
the controller's request round trip (against the same board without the router, the first
row), and whether every observer got every ``TM`` (the router's own count of frames dropped
for a client too slow to read, and the gaps in each observer's counters).

The controller is fpgalink's link; the observers are plain sockets decoding frames, all in
this process, so on a small machine they compete with the router and the emulator for the
CPUs: a quiet machine gives the figures worth quoting.

Two more tables (issue 37). **Queue cost**: what one frame costs to queue toward a serial
port, for 1e3, 1e4 and 1e5 frames written at once — fpgalink's ``SerialTransport`` on a
pty nobody reads, pyserial-asyncio's transport beside it where it is installed (up to 1e4:
its cost per frame grows with what waits), and the router taking a client's burst (paced
and bounded by line time: most of a big burst is refused, counted). **RD after a flood**:
a controller writes 10 s of line time (250,000 ``RE``) toward a TCP board through the
router and leaves; the time from its leaving to the first ``TM`` showing the board
disabled, on the board's clock (the loop's clock mapped onto the board's ``t_us`` through
the lower envelope of the ``TM`` arrivals, so the figure errs long by the forwarding delay,
never short).

    python -m benchmarks.router [--quick] [--output FILE]
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import statistics
import sys
import time
import tty
from typing import Any

from benchmarks._common import (
    EMULATOR_READY_TIMEOUT_S,
    common_parser,
    environment_line,
    percentile,
    print_table,
    report_header,
    start_emulator,
    stop_emulator,
    summarize,
    write_results,
)
from fpgalink.aio import open_link
from fpgalink.aio.transport import open_transport
from fpgalink.protocol import DEFAULT_FRAMING, Telemetry, encode_frame, parse_content
from fpgalink.protocol.framing import FrameDecoder
from tests.support.serving import Served, start_serve

NAME = "router"
#: Observers per row (the controller comes on top); "direct" is the board without a router.
COUNTS = (0, 1, 2, 4, 8, 16)
QUICK_COUNTS = (0, 2)
REQUEST_EVERY_S = 0.02
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
#: Frames queued at once, for the queue-cost table.
QUEUE_COUNTS = (1_000, 10_000, 100_000)
QUICK_QUEUE_COUNTS = (1_000, 10_000)
#: pyserial-asyncio's transport is timed up to this many frames (its cost is quadratic).
PYSERIAL_ASYNCIO_MAX = 10_000
#: A flooding controller's burst: 250,000 RE, 10 s of line time at 1 MBd; repeated.
FLOOD_FRAMES, FLOOD_RUNS = 250_000, 5
QUICK_FLOOD_FRAMES, QUICK_FLOOD_RUNS = 25_000, 1
#: One PG frame, as a link writes it (19 wire bytes).
FRAME = encode_frame(b"PG00000{\x02\x01\x00}", DEFAULT_FRAMING)


def _cpu_s(pid: int) -> float:
    """User and system CPU time of ``pid`` so far, s (Linux /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


class Observer(asyncio.Protocol):
    """Reads every frame the router hands it; counts TMs and the gaps in their counters."""

    def __init__(self) -> None:
        self.decoder = FrameDecoder()
        self.counters: list[int] = []
        self.transport: asyncio.BaseTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        for item in self.decoder.feed(data):
            if isinstance(item, bytes) and item[:2] == b"TM":
                self.counters.append(int(item[2:7]))

    def missing(self, driven: set[int]) -> int:
        """TMs the controller got in its window that this observer did not."""
        return len(driven - set(self.counters))


async def _start_router(port: str) -> tuple[asyncio.subprocess.Process, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "fpgalink", "router", "--format", "json", "--port", port,
        stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    return proc, await _ready(proc, "the router")


async def _end(router: asyncio.subprocess.Process | None, serve: Served) -> None:
    """After a row: a router not stopped cleanly is killed; the board's server stopped."""
    if router is not None:
        router.kill()
        await router.wait()
    await stop_emulator(serve)


async def _ready(proc: asyncio.subprocess.Process, what: str) -> str:
    """The URL of the first ``ready`` line ``proc`` prints."""
    assert proc.stdout is not None
    line = (await asyncio.wait_for(proc.stdout.readline(), EMULATOR_READY_TIMEOUT_S)).decode()
    if not line.startswith("ready "):
        proc.kill()
        raise RuntimeError(f"{what} did not start: {line!r}")
    return line.split()[2]


async def _stop_router(proc: asyncio.subprocess.Process) -> dict[str, Any]:
    proc.send_signal(signal.SIGINT)
    out, err = await asyncio.wait_for(proc.communicate(), 30)
    if proc.returncode != 0:
        raise RuntimeError(f"the router exited {proc.returncode}: {err.decode()[-500:]}")
    summary: dict[str, Any] = json.loads(out)
    return summary


async def _row(observers: int | None, duration: float) -> dict[str, Any]:
    """One count of observers (``None``: the controller straight on the board's pty)."""
    serve, [(_, pty)] = await start_emulator(1, 1_000_000)
    router = None
    try:
        url = pty
        if observers is not None:
            router, url = await _start_router(pty)
            host, port = url.removeprefix("socket://").rsplit(":", 1)
        loop = asyncio.get_running_loop()
        watching: list[Observer] = []
        for _ in range(observers or 0):
            _, observer = await loop.create_connection(Observer, host, int(port))
            watching.append(observer)
        # As patient as the robot: a loaded machine answers late (docs/robot.md, Faults); and
        # slower to call a board lost than a robot is (beside two busy loops the smoke run
        # heard nothing for 0.7 s once, host, router and serve all waiting for the CPU): a
        # round trip measured late is a figure, a board given up is no row at all.
        async with open_link(url, unanswered_rounds=4, liveness_timeout=5.0) as link:
            await link.set_param("GetDataPeriodical", 1)
            samples = link.telemetry(maxsize=1 << 16)
            await samples.__anext__()  # streaming
            while len(samples):  # what came before the window
                await samples.__anext__()
            cpu_before = _cpu_s(router.pid) if router is not None else 0.0
            started = time.monotonic()
            driven: set[int] = set()
            rtts: list[float] = []
            while time.monotonic() - started < duration:
                asked = time.perf_counter()
                await link.get_param("TsTimerPeriod")
                rtts.append((time.perf_counter() - asked) * 1000)
                await asyncio.sleep(REQUEST_EVERY_S)
                while len(samples):
                    counter = (await samples.__anext__()).counter
                    if counter is not None:
                        driven.add(counter)
            wall = time.monotonic() - started
            cpu = (_cpu_s(router.pid) - cpu_before) / wall if router is not None else None
            await link.set_param("GetDataPeriodical", 0)
        # The observers' copies of the controller's last TMs may still be on their way: the
        # router hands each frame to every client in the same pass, so they are at most a
        # read behind; waited for, up to a bound.
        deadline = time.monotonic() + 5
        while any(o.missing(driven) for o in watching) and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        missing = [o.missing(driven) for o in watching]
        for observer in watching:
            assert observer.transport is not None
            observer.transport.close()
        summary = await _stop_router(router) if router is not None else None
        router = None
    finally:
        await _end(router, serve)
    row: dict[str, Any] = {
        "observers": observers, "tm_in_window": len(driven), "requests": len(rtts),
        "rtt_ms": {**summarize(rtts), "p99": percentile(rtts, 99)},
        "router_cpu_percent": None if cpu is None else 100 * cpu,
        "observers_missing_tm": missing,
    }
    if summary is not None:
        clients = summary["clients"]
        row["router_dropped_frames"] = sum(c["dropped_frames"] for c in clients)
        row["router_refused_frames"] = sum(c["refused_frames"] for c in clients)
    return row


# --- the queue cost ---------------------------------------------------------------------


class _Quiet(asyncio.Protocol):
    pass


def _serial_queue_us(count: int, pyserial_asyncio: bool) -> float:
    """µs per frame for ``count`` frames written at once to a pty nobody reads."""

    async def run() -> float:
        master, slave = os.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        try:
            if pyserial_asyncio:
                import serial
                import serial_asyncio

                port = serial.Serial(path, baudrate=1_000_000, exclusive=True)
                transport: asyncio.BaseTransport = serial_asyncio.SerialTransport(
                    asyncio.get_running_loop(), _Quiet(), port)
            else:
                transport, _ = await open_transport(path, 1_000_000, _Quiet)
            await asyncio.sleep(0)
            assert isinstance(transport, asyncio.WriteTransport)
            began = time.perf_counter()
            for _ in range(count):
                transport.write(FRAME)
            elapsed = time.perf_counter() - began
            transport.abort()
            await asyncio.sleep(0.01)
            return elapsed / count * 1e6
        finally:
            os.close(master)
            os.close(slave)

    return asyncio.run(run())


def _router_intake_us(count: int) -> tuple[float, int, int]:
    """µs per frame for the router to take a client's burst of ``count`` RE (paced, the
    excess refused), and how many it passed and refused."""
    from fpgalink.router import CLIENT_READ_SIZE, BoardRoute, ClientStats

    class Port(asyncio.WriteTransport):
        def write(self, data: bytes | bytearray | memoryview) -> None:
            pass

        def is_closing(self) -> bool:
            return False

    class Client:
        def __init__(self) -> None:
            self.stats = ClientStats(0, "burst")

        def backlog(self) -> int:
            return 0

        def send(self, wire: bytes) -> None:
            pass

    async def run() -> tuple[float, int, int]:
        import contextlib
        import io

        route = BoardRoute("L", "burst", 1 << 20)
        route.board = Port()
        client: Any = Client()
        with contextlib.redirect_stderr(io.StringIO()):  # its notes are not the benchmark's
            route.joined(client, "burst")
            burst = b"SREP" * count
            decoder = FrameDecoder()
            began = time.perf_counter()
            for at in range(0, len(burst), CLIENT_READ_SIZE):  # as the router reads it
                items = decoder.feed(burst[at:at + CLIENT_READ_SIZE])
                route.from_client(client, [i for i in items if type(i) is bytes])
            elapsed = time.perf_counter() - began
            route.close()
        return (elapsed / count * 1e6, client.stats.frames_to_board,
                client.stats.line_full_frames)

    return asyncio.run(run())


def queue_cost(counts: tuple[int, ...]) -> list[dict[str, Any]]:
    try:
        import serial_asyncio  # noqa: F401
        have_pyserial_asyncio = True
    except ImportError:
        have_pyserial_asyncio = False
    rows = []
    for count in counts:
        router_us, passed, refused = _router_intake_us(count)
        rows.append({
            "frames": count,
            "serial_transport_us_per_frame": _serial_queue_us(count, False),
            "pyserial_asyncio_us_per_frame":
                _serial_queue_us(count, True)
                if have_pyserial_asyncio and count <= PYSERIAL_ASYNCIO_MAX else None,
            "router_intake_us_per_frame": router_us,
            "router_passed": passed, "router_refused": refused,
        })
    return rows


# --- an RD after a flood -----------------------------------------------------------------


async def _serve_tcp() -> tuple[Served, str]:
    served = await asyncio.to_thread(start_serve, "--tcp", "127.0.0.1:0", "--set",
                                     "GetDataPeriodical=1")
    return served, served.url


class Watcher(asyncio.Protocol):
    """Every TM: its board time, its enable flag and when it arrived (loop time)."""

    def __init__(self) -> None:
        self.decoder = FrameDecoder()
        self.samples: list[tuple[int, bool, float]] = []

    def data_received(self, data: bytes) -> None:
        now = asyncio.get_running_loop().time()
        for item in self.decoder.feed(data):
            if isinstance(item, bytes) and item[:2] == b"TM":
                sample = parse_content(item)
                if isinstance(sample, Telemetry):
                    self.samples.append((sample.t_us, sample.a.enabled, now))


async def _until(predicate: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


async def _one_flood(host: str, port: int, watcher: Watcher, frames: int
                     ) -> tuple[float, float]:
    """One flooding controller that leaves: ms from its close, and from the router letting
    it go (its connection closed: the router has read all it wrote and sent RD), to the
    board disabled, on the board's clock."""
    loop = asyncio.get_running_loop()
    start = len(watcher.samples)
    flooder = socket.create_connection((host, port))
    flooder.setblocking(False)
    try:
        await loop.sock_sendall(flooder, b"SREP" * frames)
        flooder.shutdown(socket.SHUT_WR)
        left = loop.time()
        while await loop.sock_recv(flooder, 65536):
            pass
        let_go = loop.time()
    finally:
        flooder.close()

    def disabled() -> int | None:
        """The first TM after the last one showing the board enabled."""
        samples = watcher.samples
        last_on = max((i for i in range(start, len(samples)) if samples[i][1]), default=None)
        return None if last_on is None or last_on + 1 >= len(samples) else last_on + 1

    await _until(lambda: disabled() is not None, 60, "the board disabled")
    # Settled: 300 more samples (the watchdog's 300 ms, had anything enabled it again).
    await _until(lambda: len(watcher.samples) > (disabled() or 0) + 300, 30, "300 TMs more")
    off = disabled()
    assert off is not None
    # Board time at the leaving: the loop's clock through the lower envelope of (arrival −
    # board time) over this run's samples: the least-delayed sample sets the offset.
    offset = min(arrival * 1e6 - t_us for t_us, _, arrival in watcher.samples[start:])
    disabled_us = watcher.samples[off][0]
    return ((disabled_us - (left * 1e6 - offset)) / 1000,
            (disabled_us - (let_go * 1e6 - offset)) / 1000)


async def rd_after_flood(frames: int, runs: int) -> dict[str, Any]:
    serve, board = await _serve_tcp()
    router = None
    try:
        router, url = await _start_router(board)
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        loop = asyncio.get_running_loop()
        _, watcher = await loop.create_connection(Watcher, host, int(port))
        await _until(lambda: len(watcher.samples) > 100, 30, "telemetry")
        both = [await _one_flood(host, int(port), watcher, frames) for _ in range(runs)]
        summary = await _stop_router(router)
        router = None
    finally:
        await _end(router, serve)
    floods = [c for c in summary["clients"] if c["role"] == "controller"]
    after_close = [b[0] for b in both]
    after_let_go = [b[1] for b in both]
    return {
        "frames": frames, "runs": runs,
        "rd_after_close_ms": after_close, "rd_after_let_go_ms": after_let_go,
        "median_after_close_ms": statistics.median(after_close),
        "median_after_let_go_ms": statistics.median(after_let_go),
        "max_after_let_go_ms": max(after_let_go),
        "passed": [c["frames_to_board"] for c in floods],
        "refused_line_full": [c["line_full_frames"] for c in floods],
        "dropped_behind_rd": [c["overtaken_frames"] for c in floods],
        "connected_s": [c["connected_s"] for c in floods],
    }


def main() -> None:
    parser = common_parser(__doc__, NAME, "two rows of 1.5 s (a smoke run)")
    args = parser.parse_args()
    counts = QUICK_COUNTS if args.quick else COUNTS
    duration = 1.5 if args.quick else 5.0
    report = report_header(NAME, [])
    report["config"] = {"quick": args.quick, "observers": list(counts), "duration_s": duration,
                        "request_every_s": REQUEST_EVERY_S}
    print(environment_line(report))
    rows: list[dict[str, Any]] = [asyncio.run(_row(None, duration))]
    rows += [asyncio.run(_row(n, duration)) for n in counts]
    table = []
    for row in rows:
        cpu = row["router_cpu_percent"]
        table.append([
            "direct (no router)" if row["observers"] is None else f"{row['observers']} + 1",
            "-" if cpu is None else f"{cpu:.1f}",
            f"{row['rtt_ms']['median']:.2f}", f"{row['rtt_ms']['p99']:.2f}",
            str(row["tm_in_window"]),
            str(max(row["observers_missing_tm"], default=0)),
            str(row.get("router_dropped_frames", "-")),
        ])
    print_table(["observers + controller", "router CPU %", "PG→PA ms", "p99 ms", "TMs",
                 "missed", "dropped"], table)
    print("(PG→PA: the controller's request round trip, median; TMs: what the controller got "
          "in the window;\n missed: of those, the most any one observer did not get; dropped: "
          "frames the router\n dropped for a client too slow to read)")
    print(f"({duration:g} s per row; the board at 1 kHz on a pty; PG every "
          f"{REQUEST_EVERY_S * 1000:.0f} ms)")
    report["rows"] = rows

    queue_counts = QUICK_QUEUE_COUNTS if args.quick else QUEUE_COUNTS
    report["queue_cost"] = queue = queue_cost(queue_counts)

    def us(value: float | None) -> str:
        return "-" if value is None else f"{value:.2f}"

    print("\nqueue cost: µs per frame, the frames written at once")
    print_table(["frames", "SerialTransport", "pyserial-asyncio", "router intake",
                 "passed", "refused"],
                [[f"{r['frames']:,}", us(r["serial_transport_us_per_frame"]),
                  us(r["pyserial_asyncio_us_per_frame"]), us(r["router_intake_us_per_frame"]),
                  f"{r['router_passed']:,}", f"{r['router_refused']:,}"] for r in queue])
    print(f"(a {len(FRAME)}-byte PG frame each, to a pty nobody reads; pyserial-asyncio up to "
          f"{PYSERIAL_ASYNCIO_MAX:,} frames, where installed; router intake: a client's burst "
          "of RE\n decoded, paced and bounded by line time — passed to the board or refused)")

    frames, runs = (QUICK_FLOOD_FRAMES, QUICK_FLOOD_RUNS) if args.quick else \
        (FLOOD_FRAMES, FLOOD_RUNS)
    report["rd_after_flood"] = flood = asyncio.run(rd_after_flood(frames, runs))
    print(f"\nRD after a flood: a controller writes {frames:,} RE ({frames * 4 / 1e5:g} s of "
          "line time) toward a TCP board and leaves")
    print_table(["run", "RD ms after its close", "after let go", "passed", "refused",
                 "dropped behind RD", "connected s"],
                [[str(i + 1), f"{a:.1f}", f"{b:.1f}", f"{p:,}", f"{r:,}", f"{d:,}", f"{c:.2f}"]
                 for i, (a, b, p, r, d, c) in enumerate(zip(
                     flood["rd_after_close_ms"], flood["rd_after_let_go_ms"], flood["passed"],
                     flood["refused_line_full"], flood["dropped_behind_rd"],
                     flood["connected_s"], strict=True))])
    print(f"(board time to the first TM showing it disabled, from the client's close — the "
          "router still reading what\n its kernel held — and from the router letting it go; "
          f"medians {flood['median_after_close_ms']:.1f} and "
          f"{flood['median_after_let_go_ms']:.1f} ms; TMs come every 1 ms)")
    path = write_results(NAME, report, args.output)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
