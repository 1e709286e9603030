"""The asyncio link against a real ``fpgaemu serve --pty`` board paced at 1 MBd.

Two measurements, both through the public ``open_link`` API and a pseudo-terminal served by
a separate process (so the board's CPU is not the host's):

* ``set_param`` round trip: ``N`` sets of ``Kp_Wheel_PidA`` (alternating values, so each one
  changes something), each timed from the call to the confirmed ``PA`` (p50, p99, max);
* sustained telemetry: ``TsTimerPeriod`` = 1 ms, ``GetDataPeriodical`` = 1 and the heartbeat
  running, for ``S`` seconds. Reported: ``TM`` received and lost (counter gaps, which should
  be 0; the counters seen plus those missing account for the whole counter span),
  inter-arrival time p50/p99 as the host's receive path sees it (stamped in a link listener),
  and the host process's CPU time per received ``TM`` (``time.process_time()`` over the
  window divided by the count; target ≤ 20 µs).

Run ``python -m benchmarks.link`` from the repository root; ``--quick`` is 100 sets and 3 s
of telemetry. Results go to ``benchmarks/results/link.json`` (or ``--output``).
"""

from __future__ import annotations

import asyncio
import itertools
import statistics
import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    percentile,
    print_table,
    report_header,
    start_emulator,
    stop_emulator,
    write_results,
)
from fpgalink import Telemetry, open_link
from fpgalink.protocol import COUNTER_MODULUS

NAME = "link"
BAUD = 1_000_000
DEFAULT_SETS, QUICK_SETS = 1000, 100
DEFAULT_SECONDS, QUICK_SECONDS = 30.0, 3.0
CPU_TARGET_US = 20.0
BATCH_BOUND_S = 0.010  #: the read-latency bound of the batched telemetry phase
BATCHED_CPU_TARGET_US = 30.0


async def run(baud: int, sets: int, seconds: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """Start the emulator, measure, stop it: the results and what the emulator did."""
    proc, ready = await start_emulator(1, baud)
    try:
        results = await measure(ready[0][1], baud, sets, seconds)
    finally:
        exit_code, said = await stop_emulator(proc)
    return results, {"exit_code": exit_code, "stderr": said}


async def measure(path: str, baud: int, sets: int, seconds: float) -> dict[str, Any]:
    async with open_link(path, baud, request_timeout=0.05, request_tries=5,
                         reconnect=False) as link:
        # --- set_param round trip (telemetry off, so only the request and its echo move).
        assert await link.set_param("GetDataPeriodical", 0) == 0
        latencies: list[float] = []
        retries_before = link.stats.retries
        for i in range(sets):
            value = 1.5 if i % 2 else 2.5
            start = time.perf_counter()
            confirmed = await link.set_param("Kp_Wheel_PidA", value)
            latencies.append(time.perf_counter() - start)
            if confirmed != value:
                raise AssertionError(f"set {value} confirmed {confirmed}")
        set_retries = link.stats.retries - retries_before

        # --- sustained telemetry at 1 kHz with the heartbeat running: every read handled at
        # once, then with reads batched under a 10 ms bound (a 100 Hz consumer's choice).
        link.enable()
        assert await link.set_param("TsTimerPeriod", 1) == 1
        assert await link.set_param("GetDataPeriodical", 1) == 1
        telemetry = await stream(link, seconds)
        link.set_read_latency(BATCH_BOUND_S)
        batched = await stream(link, seconds)
        # A parameter request while batching: answered at wire speed, not after a batch.
        start = time.perf_counter()
        assert await link.set_param("Kp_Wheel_PidA", 3.5) == 3.5
        batched["set_param_while_batching_us"] = (time.perf_counter() - start) * 1e6
        link.set_read_latency(None)
        await link.set_param("GetDataPeriodical", 0)
        link.disable()
        floor_us = await idle_wakeup_cpu_us(telemetry["received"])
        lat_us = [x * 1e6 for x in latencies]
        return {
            "set_param": {
                "count": sets,
                "retries": set_retries,
                "p50_us": percentile(lat_us, 50),
                "p99_us": percentile(lat_us, 99),
                "max_us": max(lat_us),
                "mean_us": statistics.fmean(lat_us),
            },
            "telemetry": {**telemetry, "idle_wakeup_cpu_us": floor_us,
                          "cpu_us_per_tm_above_idle": (
                              telemetry["cpu_us_per_tm"] - floor_us
                              if telemetry["cpu_us_per_tm"] is not None else None)},
            "telemetry_batched": {**batched, "read_latency_s": BATCH_BOUND_S},
        }


async def stream(link: Any, seconds: float) -> dict[str, Any]:
    """``seconds`` of 1 kHz telemetry through a subscriber: counts, losses, arrival
    spacing as the receive path sees it, and the process's CPU per TM."""
    arrivals: list[float] = []
    counters: list[int] = []
    recording = False
    perf = time.perf_counter

    def on_event(event: object) -> None:
        if recording and isinstance(event, Telemetry):
            arrivals.append(perf())
            counters.append(event.counter or 0)

    remove = link.add_listener(on_event)
    sub = link.telemetry(maxsize=4096)
    await asyncio.wait_for(sub.__anext__(), 2.0)  # streaming has begun
    loop = asyncio.get_running_loop()
    lost_before = link.stats.lost
    received_before = link.stats.telemetry_received
    recording = True
    cpu0, wall0 = time.process_time(), perf()
    end = loop.time() + seconds

    async def consume() -> None:
        async for _ in sub:
            if loop.time() >= end:
                return

    await asyncio.wait_for(consume(), seconds + 5.0)
    recording = False
    cpu1, wall1 = time.process_time(), perf()
    remove()
    sub.close()
    received = link.stats.telemetry_received - received_before
    gaps = sum(1 for a, b in itertools.pairwise(counters) if (b - a) % COUNTER_MODULUS != 1)
    missing = sum((b - a - 1) % COUNTER_MODULUS for a, b in itertools.pairwise(counters))
    # Every counter from the first seen to the last is either seen or missing; with
    # duplicates or reordering (neither happens on a pty) the sum would not match.
    span = (counters[-1] - counters[0]) % COUNTER_MODULUS + 1 if counters else 0
    deltas_ms = [(b - a) * 1e3 for a, b in itertools.pairwise(arrivals)]
    jitter_ms = [abs(d - 1.0) for d in deltas_ms]
    return {
        "seconds": wall1 - wall0,
        "received": received,
        "listener_received": len(counters),
        "counter_span": span,
        "expected_approx": round((wall1 - wall0) * 1000),
        "lost": link.stats.lost - lost_before,
        "counter_gaps": gaps,
        "missing_counters": missing,
        "subscriber_drops": sub.dropped,
        "decode_errors": link.stats.decode_errors,
        "interarrival_p50_ms": percentile(deltas_ms, 50),
        "interarrival_p99_ms": percentile(deltas_ms, 99),
        "interarrival_max_ms": max(deltas_ms),
        "jitter_p50_ms": percentile(jitter_ms, 50),
        "jitter_p99_ms": percentile(jitter_ms, 99),
        "host_cpu_s": cpu1 - cpu0,
        "cpu_us_per_tm": (cpu1 - cpu0) / received * 1e6 if received else None,
        "host_cpu_share": (cpu1 - cpu0) / (wall1 - wall0),
    }


async def idle_wakeup_cpu_us(count: int) -> float:
    """CPU per wake-up of an event loop that only sleeps 1 ms at a time: the floor under
    any per-message figure when messages arrive one per millisecond."""
    count = max(200, min(count, 3000))
    cpu0 = time.process_time()
    for _ in range(count):
        await asyncio.sleep(0.001)
    return (time.process_time() - cpu0) / count * 1e6


def targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    tm, batched, sp = results["telemetry"], results["telemetry_batched"], results["set_param"]
    cpu = tm["cpu_us_per_tm"]
    return [
        {"name": "tm.lost", "measured": tm["lost"], "threshold": 0, "unit": "messages",
         "required": True,
         "pass": tm["lost"] == 0 and tm["counter_gaps"] == 0 and tm["subscriber_drops"] == 0},
        {"name": "tm.cpu_us_per_tm", "measured": cpu, "threshold": CPU_TARGET_US, "unit": "µs",
         "required": False, "pass": cpu is not None and cpu <= CPU_TARGET_US},
        {"name": "tm.cpu_us_per_tm_above_idle", "measured": tm["cpu_us_per_tm_above_idle"],
         "threshold": CPU_TARGET_US, "unit": "µs", "required": False,
         "pass": tm["cpu_us_per_tm_above_idle"] is not None
         and tm["cpu_us_per_tm_above_idle"] <= CPU_TARGET_US},
        {"name": "tm_batched.lost", "measured": batched["lost"], "threshold": 0,
         "unit": "messages", "required": True,
         "pass": batched["lost"] == 0 and batched["counter_gaps"] == 0
         and batched["subscriber_drops"] == 0},
        {"name": "tm_batched.cpu_us_per_tm", "measured": batched["cpu_us_per_tm"],
         "threshold": BATCHED_CPU_TARGET_US, "unit": "µs", "required": False,
         "pass": batched["cpu_us_per_tm"] is not None
         and batched["cpu_us_per_tm"] <= BATCHED_CPU_TARGET_US},
        {"name": "set_param.p50_us", "measured": sp["p50_us"], "threshold": 1000.0,
         "unit": "µs", "required": False, "pass": sp["p50_us"] <= 1000.0},
        {"name": "set_param.p99_us", "measured": sp["p99_us"], "threshold": 2500.0,
         "unit": "µs", "required": False, "pass": sp["p99_us"] <= 2500.0},
    ]


def print_report(report: dict[str, Any], goals: list[dict[str, Any]]) -> None:
    sp, tm, bt = report["set_param"], report["telemetry"], report["telemetry_batched"]
    rows = [
        ["set_param round trip p50", f"{sp['p50_us']:.0f} µs", f"{sp['count']} sets"],
        ["set_param round trip p99", f"{sp['p99_us']:.0f} µs", f"max {sp['max_us']:.0f} µs"],
        ["set_param retries", str(sp["retries"]), ""],
        ["TM received", str(tm["received"]), f"in {tm['seconds']:.1f} s"],
        ["TM lost", str(tm["lost"]),
         f"{tm['counter_gaps']} counter gaps, {tm['missing_counters']} counters missing"],
        ["TM inter-arrival p50", f"{tm['interarrival_p50_ms']:.3f} ms", "period 1 ms"],
        ["TM inter-arrival p99", f"{tm['interarrival_p99_ms']:.3f} ms",
         f"max {tm['interarrival_max_ms']:.3f} ms"],
        ["TM jitter |Δt−1 ms| p50", f"{tm['jitter_p50_ms']:.3f} ms", ""],
        ["TM jitter |Δt−1 ms| p99", f"{tm['jitter_p99_ms']:.3f} ms", ""],
        ["host CPU per TM", f"{tm['cpu_us_per_tm']:.1f} µs",
         f"target ≤ {CPU_TARGET_US:g} µs; {tm['host_cpu_share'] * 100:.1f} % of a core"],
        ["idle loop, per 1 ms wake-up", f"{tm['idle_wakeup_cpu_us']:.1f} µs",
         "asyncio.sleep(0.001) alone, same process"],
        ["host CPU per TM above that", f"{tm['cpu_us_per_tm_above_idle']:.1f} µs",
         "the link's own work per message"],
        ["batched reads (10 ms bound): TM received", str(bt["received"]),
         f"in {bt['seconds']:.1f} s, lost {bt['lost']}, gaps {bt['counter_gaps']}"],
        ["batched reads: host CPU per TM", f"{bt['cpu_us_per_tm']:.1f} µs",
         f"target ≤ {BATCHED_CPU_TARGET_US:g} µs; {bt['host_cpu_share'] * 100:.1f} % of a core"],
        ["batched reads: TM arrival gap p99", f"{bt['interarrival_p99_ms']:.3f} ms",
         f"max {bt['interarrival_max_ms']:.3f} ms (bound {bt['read_latency_s'] * 1e3:g} ms)"],
        ["batched reads: a set_param meanwhile", f"{bt['set_param_while_batching_us']:.0f} µs",
         "reading resumes at once for a request"],
    ]
    print(environment_line(report))
    print_table([f"link over fpgaemu serve --pty, {report['config']['baud']:,} Bd", "value",
                 "note"], rows, align="<><")
    for goal in goals:
        verdict = "pass" if goal["pass"] else "FAIL"
        kind = "required" if goal["required"] else "target"
        measured = goal["measured"]
        shown = "n/a" if measured is None else f"{measured:.3g}"
        print(f"{kind} {goal['name']}: {shown} vs {goal['threshold']:g} {goal['unit']}: "
              f"{verdict}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME,
                           f"{QUICK_SETS} sets and {QUICK_SECONDS:g} s of telemetry "
                           "(the smoke test)")
    parser.add_argument("--sets", type=int, default=None, help="set_param round trips")
    parser.add_argument("--seconds", type=float, default=None, help="telemetry window")
    parser.add_argument("--baud", type=int, default=BAUD)
    args = parser.parse_args(argv)
    sets = args.sets or (QUICK_SETS if args.quick else DEFAULT_SETS)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else DEFAULT_SECONDS)

    started = time.perf_counter()
    results, serve = asyncio.run(run(args.baud, sets, seconds))
    goals = targets(results)
    payload: dict[str, Any] = {
        **report_header(NAME, ["pyserial"]),
        "config": {"quick": args.quick, "sets": sets, "seconds": seconds, "baud": args.baud,
                   "transport": "pty", "period_ms": 1,
                   "argv": sys.argv[1:] if argv is None else list(argv)},
        **results,
        "serve": serve,
        "targets": goals,
        "timing": {"total_s": time.perf_counter() - started},
    }
    out = write_results(NAME, payload, args.output)
    print_report(payload, goals)
    if serve["stderr"]:
        print(f"serve: {serve['stderr']}")
    print(f"results: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
