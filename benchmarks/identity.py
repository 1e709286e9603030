"""What asking a board who it is costs at connect (docs/protocol.md §8):
``link.identification.identify()`` over ``fpgaemu serve --pty`` against a board that
answers ``IQ`` and against a seed board (``--seed-protocol``: three rounds of ``IQ`` and its
``PG`` fence), beside one ``PG`` round trip on the same link, each the median of the
repetitions.

``python -m benchmarks.identity`` (21 repetitions a case; ``--quick``: 3).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from typing import Any

from benchmarks._common import (
    EMULATOR_READY_TIMEOUT_S,
    common_parser,
    environment_line,
    print_table,
    report_header,
    summarize,
    write_results,
)
from fpgalink.aio import open_link
from tests.support.serving import start_serve

NAME = "identity"
REPEATS = 21
QUICK_REPEATS = 3
#: (case, fpgaemu serve's options)
CASES = (("answers IQ", ()), ("seed protocol", ("--seed-protocol",)))


async def _case(options: tuple[str, ...], repeats: int) -> dict[str, Any]:
    served = await asyncio.to_thread(start_serve, "--pty", *options,
                                     ready_timeout=EMULATOR_READY_TIMEOUT_S)
    try:
        async with open_link(served.url) as link:
            await link.get_param("TsTimerPeriod")  # the board heard, the link settled
            asked, fence = [], []
            for _ in range(repeats):
                start = time.perf_counter()
                identity = await link.identification.identify(allow_mismatch=True)
                asked.append(time.perf_counter() - start)
                start = time.perf_counter()
                await link.get_param("TsTimerPeriod")
                fence.append(time.perf_counter() - start)
    finally:
        await served.stopped(signal.SIGINT)
        served.discard()
    return {"identify_s": summarize(asked), "pg_round_trip_s": summarize(fence),
            "answered": identity is not None}


def main(argv: list[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, f"{QUICK_REPEATS} repetitions a case")
    args = parser.parse_args(argv)
    repeats = QUICK_REPEATS if args.quick else REPEATS
    report = report_header(NAME, ["pyserial"])
    report["config"] = {"quick": args.quick, "repeats": repeats, "baud": 1_000_000}
    results = {case: asyncio.run(_case(options, repeats)) for case, options in CASES}
    report["results"] = results
    print(environment_line(report))
    print_table(
        ["board", "identify ms", "PG round trip ms", "ratio"],
        [[case, f"{r['identify_s']['median'] * 1000:.2f}",
          f"{r['pg_round_trip_s']['median'] * 1000:.2f}",
          f"{r['identify_s']['median'] / r['pg_round_trip_s']['median']:.1f}"]
         for case, r in results.items()])
    print(f"wrote {write_results(NAME, report, args.output)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
