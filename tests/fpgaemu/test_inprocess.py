"""``emu://`` in the host's own event loop (:mod:`fpgaemu.serving.inprocess`), on emulated
time (:class:`~fpgalink.aio.virtualtime.VirtualTimeLoop`), so every count is exact: a robot
whose two boards each have a transport wakes once per due deadline, not once per transport;
a transport whose reading is paused holds what its board sent and hands it over, none lost,
when reading resumes (a read per catch-up slice, not per message), and a robot none of
whose boards is read is not woken meanwhile."""

from __future__ import annotations

import asyncio
from typing import Any

from fpgaemu.serve import open_emulated_transport
from fpgalink.aio.virtualtime import run_virtual
from fpgalink.protocol import Enable, ParamSet, Telemetry
from tests.support.wire import received, sent

#: Both boards streaming: a TM every millisecond, enabled.
STREAM = (sent(ParamSet(1, 0, 1, 1)) + sent(ParamSet(2, 0, 1, 1)) + sent(Enable()))


class Host(asyncio.Protocol):
    def __init__(self) -> None:
        self.reads: list[bytes] = []

    def data_received(self, data: bytes) -> None:
        self.reads.append(data)

    def telemetry(self) -> list[Telemetry]:
        return [e for e in received(b"".join(self.reads)) if isinstance(e, Telemetry)]


async def _robot(run: str) -> tuple[list[Any], list[Host]]:
    transports, hosts = [], []
    for board in ("L", "R"):
        transport, host = await open_emulated_transport(
            f"emu://robot/{board}?body=kinematic&run={run}", 1_000_000, Host)
        assert isinstance(host, Host)
        transports.append(transport)
        hosts.append(host)
    return transports, hosts


async def _paused_robot(name: str) -> tuple[list[Any], list[Host]]:
    """A robot's two boards streaming for 0.1 s, then both transports paused (a host that
    reads in batches)."""
    transports, hosts = await _robot(name)
    for transport in transports:
        transport.write(STREAM)
    await asyncio.sleep(0.1)
    for transport in transports:
        transport.pause_reading()
        assert not transport.is_reading()
    return transports, hosts


def test_an_in_process_robot_wakes_once_per_due_deadline() -> None:
    async def main() -> tuple[int, list[int]]:
        transports, hosts = await _robot("wakes")
        try:
            # One far end for both boards: one pacer, run once per deadline for both.
            assert transports[0].pacer is transports[1].pacer
            for transport in transports:
                transport.write(STREAM)
            await asyncio.sleep(0.1)
            pacer = transports[0].pacer
            before = pacer.wakeups
            await asyncio.sleep(1.0)
            return pacer.wakeups - before, [len(h.telemetry()) for h in hosts]
        finally:
            for transport in transports:
                transport.close()

    wakeups, telemetry = run_virtual(main())
    # Both boards' ticks fall on the same cycles; each board's TM ends on its own: about
    # two wake-ups per emulated millisecond for the robot (each transport woke for all of
    # them, over four).
    assert wakeups <= 2_100, wakeups
    assert all(count >= 1_090 for count in telemetry), telemetry


def test_a_paused_reader_loses_nothing_and_an_unread_robot_is_not_woken() -> None:
    async def main() -> tuple[int, list[int], list[list[Telemetry]]]:
        transports, hosts = await _paused_robot("batched")
        try:
            reads = [len(h.reads) for h in hosts]
            pacer = transports[0].pacer
            before = pacer.wakeups
            await asyncio.sleep(0.5)
            woken = pacer.wakeups - before
            assert [len(h.reads) for h in hosts] == reads  # nothing handed out, paused
            for transport in transports:
                transport.resume_reading()
            # The robot catches up at once, in its slices of 10 ms: no emulated time passes
            # while it does (on this loop, a wake-up due now runs before the clock moves).
            await asyncio.sleep(0.0005)
            return woken, [len(h.reads) - n for h, n in zip(hosts, reads, strict=True)], [
                h.telemetry() for h in hosts]
        finally:
            for transport in transports:
                transport.close()

    woken, reads_after, telemetry = run_virtual(main())
    # Half a second unread: at most the pacer's safety wake-up, not ~1,000.
    assert woken <= 1, woken
    for samples in telemetry:
        counters = [t.counter or 0 for t in samples]
        # Nothing lost or repeated across the pause: one TM a millisecond, counted on.
        assert counters == list(range(counters[0], counters[0] + len(counters)))
        assert len(counters) >= 590
    # What the pause held came as the robot caught up: a read per slice, not per TM.
    assert all(1 <= n <= 60 for n in reads_after), reads_after
