"""A host flooding ``fpgaemu serve``: every byte delivered, at line rate, in bounded memory.

For a pty and for TCP: ``fpgaemu serve`` in its own process; a host writes ``--mb``
megabytes of line noise (bytes that are never part of a frame) as fast as the serve lets it,
then a ``PG``, and waits for the board's ``PA``. Reported per transport: how long the write
took and when the answer came against the line's time for that many bytes (10 bits a byte
at 1 MBd: the answer cannot come sooner), serve's resident memory before, at its peak
during the flood (sampled every 0.1 s) and after, and the board's own count of what
arrived (printed by serve on exit): bytes on the RX line, noise, frames, and how many times
serve held the host back.

    python -m benchmarks.flood            # 50 MB per transport: about 500 s each
    python -m benchmarks.flood --mb 5     # 50 s each
    python -m benchmarks.flood --quick    # 0.3 MB: a smoke run

The host's TCP socket has a fixed 16 KiB send buffer, as a serial driver's is small; the
kernel would otherwise grow it to megabytes and absorb part of the flood (allowed — the
host's write returns sooner — but then the write time says less about serve).
"""

from __future__ import annotations

import asyncio
import json
import signal
import sys
import threading
import time
from typing import Any

from benchmarks._common import (
    EMULATOR_READY_TIMEOUT_S,
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)
from fpgalink.protocol import ParamGet
from tests.support.flood import BAUD, RawHost, board_counts, noise, rss_kb
from tests.support.serving import start_serve
from tests.support.wire import sent

NAME = "flood"


class PeakRss:
    """The largest resident size of a process, sampled every 0.1 s in a thread."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.peak_kb = rss_kb(pid)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            try:
                self.peak_kb = max(self.peak_kb, rss_kb(self.pid))
            except (OSError, StopIteration):
                return

    def stop(self) -> int:
        self._stop.set()
        self._thread.join()
        return self.peak_kb


async def flood(where: str, size: int) -> dict[str, Any]:
    args = ["--pty"] if where == "pty" else ["--tcp", "127.0.0.1:0"]
    proc = await asyncio.to_thread(start_serve, *args,
                                   ready_timeout=EMULATOR_READY_TIMEOUT_S)
    payload = noise(size) + sent(ParamGet(1, 0))
    line_s = len(payload) * 10 / BAUD
    before = rss_kb(proc.pid)
    peak = PeakRss(proc.pid)
    host = await asyncio.to_thread(RawHost, proc.url)

    def run() -> tuple[float, float]:
        start = time.monotonic()
        host.write_all(payload)
        wrote = time.monotonic() - start
        host.await_answer(1, 60 + 3 * line_s)
        return wrote, time.monotonic() - start

    try:
        write_s, answer_s = await asyncio.to_thread(run)
    finally:
        host.close()
    peak_kb = peak.stop()
    after = rss_kb(proc.pid)
    exit_code = await proc.stopped(signal.SIGINT, 30)
    counts = board_counts(proc.log_text())
    proc.discard()
    return {
        "transport": where, "bytes": len(payload), "line_s": line_s, "write_s": write_s,
        "answer_s": answer_s, "answer_over_line": answer_s / line_s,
        "rss_before_kb": before, "rss_peak_kb": peak_kb, "rss_after_kb": after,
        "rss_growth_kb": peak_kb - before, "exit_code": exit_code,
        "board": {"written": counts.written, "received": counts.received,
                  "noise": counts.noise, "frames": counts.frames, "held_back": counts.held,
                  "discarded": counts.discarded},
        "every_byte_delivered": counts.written == counts.received == len(payload)
        and counts.noise == size and counts.frames == 1,
    }


def main() -> int:
    parser = common_parser(__doc__, NAME, "0.3 MB per transport instead of --mb")
    parser.add_argument("--mb", type=float, default=50.0, help="megabytes of noise per "
                        "transport (default 50: about 500 s each at 1 MBd)")
    options = parser.parse_args()
    size = 300_000 if options.quick else int(options.mb * 1_000_000)
    report = report_header(NAME, [])
    report["config"] = {"quick": options.quick, "bytes": size, "baud": BAUD,
                        "transports": ["pty", "tcp"]}
    print(environment_line(report))
    results = []
    for where in ("pty", "tcp"):
        results.append(asyncio.run(flood(where, size)))
        print(f"{where}: {json.dumps(results[-1])}", flush=True)  # kept if the next fails
    report["cases"] = {r["transport"]: r for r in results}
    print_table(
        ["transport", "bytes", "line s", "write s", "answer s", "RSS before MB",
         "RSS peak MB", "growth MB", "held back", "every byte"],
        [[r["transport"], f"{r['bytes']:,}", f"{r['line_s']:.1f}", f"{r['write_s']:.1f}",
          f"{r['answer_s']:.1f}", f"{r['rss_before_kb'] / 1024:.1f}",
          f"{r['rss_peak_kb'] / 1024:.1f}", f"{r['rss_growth_kb'] / 1024:.2f}",
          f"{r['board']['held_back']:,}", "yes" if r["every_byte_delivered"] else "NO"]
         for r in results])
    path = write_results(NAME, report, options.output)
    print(f"results: {path}")
    return 0 if all(r["every_byte_delivered"] and r["exit_code"] == 0 for r in results) \
        else 1


if __name__ == "__main__":
    sys.exit(main())
