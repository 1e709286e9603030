"""What ``fpgalink-cli router`` costs as its clients grow: one board (``fpgaemu serve
--pty`` in its own process) streaming telemetry at 1 kHz, one controller asking a parameter
every 20 ms, and 0 to 16 observers reading every frame. For each count: the router's CPU,
the controller's request round trip (against the same board without the router, the first
row), and whether every observer got every ``TM`` (the router's own count of frames dropped
for a client too slow to read, and the gaps in each observer's counters).

The controller is fpgalink's link; the observers are plain sockets decoding frames, all in
this process, so on a small machine they compete with the router and the emulator for the
CPUs: a quiet machine gives the figures worth quoting.

    python -m benchmarks.router [--quick] [--output FILE]
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
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
from fpgalink.protocol.framing import FrameDecoder

NAME = "router"
#: Observers per row (the controller comes on top); "direct" is the board without a router.
COUNTS = (0, 1, 2, 4, 8, 16)
QUICK_COUNTS = (0, 2)
REQUEST_EVERY_S = 0.02
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


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
    assert proc.stdout is not None
    line = (await asyncio.wait_for(proc.stdout.readline(), EMULATOR_READY_TIMEOUT_S)).decode()
    if not line.startswith("ready "):
        proc.kill()
        raise RuntimeError(f"the router did not start: {line!r}")
    return proc, line.split()[2]


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
        async with open_link(url) as link:
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
        if router is not None:
            router.kill()
            await router.wait()
        await stop_emulator(serve)
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
    path = write_results(NAME, report, args.output)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
