"""Coverage-guided fuzzing of the asyncio link's event handling: an in-memory transport fed
fuzzed bytes, in fuzzed chunks, with a parameter set and a get pending.

Run longer than CI does, from the repository root:

    .venv/bin/python -m tests.fuzz.fuzz_link -atheris_runs=0 -max_total_time=600

What must hold for any input: nothing escapes the receive path (an exception there would
drop the port); a set is confirmed only with exactly the value asked; every telemetry
sample decoded reaches the subscriber; the link closes cleanly afterwards.
"""

from __future__ import annotations

import asyncio
import sys

import atheris

with atheris.instrument_imports():
    from fpgalink import Connection, FpgalinkError
    from fpgalink.aio.link import Link
    from fpgalink.protocol import Event, Telemetry
    from fpgalink.testing import MemoryTransport

LOOP = asyncio.new_event_loop()
ASKED = 1000


async def exercise(data: bytes) -> None:
    selector, stream = data[0], data[1:]
    chunk = 1 + selector % 97
    transport = MemoryTransport()
    link = Link(Connection(request_timeout=0.001, request_tries=2), transport)
    await link.open()
    seen: list[Event] = []
    link.add_listener(seen.append)
    samples = link.telemetry(maxsize=100_000)
    link.enable()
    set_request = asyncio.ensure_future(link.set_param("MaxControlSignalA", ASKED))
    get_request = asyncio.ensure_future(link.get_param("TsTimerPeriod"))
    await asyncio.sleep(0)
    for i in range(0, len(stream), chunk):
        transport.feed(stream[i : i + chunk])
    for request in (set_request, get_request):
        try:
            value = await asyncio.wait_for(request, 1.0)
        except FpgalinkError:
            continue
        if request is set_request and value != ASKED:
            raise AssertionError(f"confirmed {value!r}, asked {ASKED}")
    decoded = sum(type(e) is Telemetry for e in seen)
    if len(samples) != decoded or link.stats.telemetry_received != decoded:
        raise AssertionError("a telemetry sample went missing between core and subscriber")
    await link.close()
    if not transport.is_closing():
        raise AssertionError("the transport was not closed")


def check(data: bytes) -> None:
    if data:
        LOOP.run_until_complete(exercise(data))


def main() -> None:
    atheris.Setup(sys.argv, check)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
