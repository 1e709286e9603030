"""End to end over real transports: ``fpgaemu serve --pty``, ``--tcp`` and in-process
``emu://``, each driven through the public ``open_link`` API exactly as a user would."""

from __future__ import annotations

import asyncio
import re
from collections.abc import AsyncIterator
from typing import Any

import pytest

from fpgalink.aio import Link, open_link
from fpgalink.events import WatchdogLapsed
from fpgalink.protocol import ChannelTelemetry, encode_frame
from fpgalink.protocol.codec import encode_telemetry
from fpgalink.protocol.params import ParamType, float32, iter_addresses
from tests.support.served import (
    PATIENCE,
    stream,
    valid_value,
    wait_for_sample,
    wait_until,
)
from tests.support.serving import serve

#: Five seconds of 1 kHz telemetry, however long the machine takes to deliver them.
STREAM_SAMPLES = 5000
_STILL = ChannelTelemetry(0, 0.0, 0.0, 0, 0.0, 0)
#: A TM's fixed-size content framed, before escapes and CRC (which only add bytes).
TM_WIRE_BYTES_AT_LEAST = len(encode_frame(encode_telemetry(0, 0, _STILL, _STILL)))


@pytest.fixture(params=["pty", "tcp", "emu"])
async def board_url(request: pytest.FixtureRequest) -> AsyncIterator[str]:
    kind: str = request.param
    if kind == "emu":
        yield "emu://?seed=1"
        return
    args = ("--pty",) if kind == "pty" else ("--tcp", "127.0.0.1:0")
    async with serve(*args) as server:
        if kind == "tcp":
            assert server.url.startswith("socket://127.0.0.1:")
            assert not server.url.endswith(":0")
        else:
            assert server.url.startswith("/dev/")
        yield server.url


async def set_and_read_every_parameter(link: Link) -> None:
    for param, channel in iter_addresses():
        value = valid_value(param, channel)
        name = param.full_name(channel)
        expected = float32(value) if param.type is ParamType.FLOAT else value
        assert await link.set_param(name, value) == expected, name
        got = await link.get_param(name)
        assert got == expected, name
        assert type(got) is type(expected), name


async def stream_at_1ms_and_check(link: Link, lossless: bool,
                                  lapses: list[WatchdogLapsed]) -> None:
    """``lapses``: the link's watchdog lapses since it was enabled."""
    assert await link.set_param("TsTimerPeriod", 1) == 1
    assert await link.set_param("GetDataPeriodical", 1) == 1
    result = await stream(link, STREAM_SAMPLES)
    result.check_accounting(1000)
    if lossless:
        # In-process and TCP buffer what a starved host has not read yet: nothing is lost.
        # A pty is a device with a bounded buffer, like a USB-UART: a host starved for
        # longer than the serving side's backlog loses bytes, and the accounting above is
        # what must hold then.
        assert result.missing == 0
        assert link.stats.decode_errors == 0 and link.stats.noise_bytes == 0
    # The heartbeat kept the board enabled all along, unless the host was starved past the
    # board's watchdog (300 ms; on a loaded machine it can be): then the board disabled
    # itself and the link said so. A disabled sample is never silent.
    if not all(s.a.enabled and s.b.enabled for s in result.samples):
        assert lapses, "the board disabled without a WatchdogLapsed"
    assert await link.set_param("GetDataPeriodical", 0) == 0


@pytest.mark.timeout(120)
async def test_every_parameter_then_1khz_telemetry(board_url: str) -> None:
    async with open_link(board_url) as link:
        lapses: list[WatchdogLapsed] = []
        link.add_listener(lambda e: lapses.append(e) if isinstance(e, WatchdogLapsed) else None)
        link.enable()
        await set_and_read_every_parameter(link)
        # WireCrc was set to 1 on the way: the telemetry below carries the CRC, every frame
        # checked on arrival, none failing on a clean line.
        assert link.connection.wire_crc.on
        await stream_at_1ms_and_check(link, not board_url.startswith("/dev/"), lapses)
        assert link.stats.crc_failures == 0
        # A clean line loses nothing: a request resent (a loaded machine's serve answering
        # later than the request timeout) found its answer, nothing malformed on the way.
        assert link.stats.malformed_by_reason == {}
        assert link.stats.reconnects == 0 and link.stats.port_losses == 0


@pytest.mark.timeout(120)
async def test_two_boards_left_and_right_in_one_program() -> None:
    async with serve("--pty", "--boards", "2") as server:
        assert set(server.ready) == {"L", "R"}
        assert server.ready["L"] != server.ready["R"]
        async with open_link(server.ready["L"], name="L") as left, \
                open_link(server.ready["R"], name="R") as right:
            left.enable()
            right.enable()
            # Each board keeps its own values.
            assert await left.set_param("Kp_Wheel_PidA", 1.5) == 1.5
            assert await right.set_param("Kp_Wheel_PidA", 2.5) == 2.5
            assert await left.get_param("Kp_Wheel_PidA") == 1.5
            assert await right.get_param("Kp_Wheel_PidA") == 2.5
            for link in (left, right):
                assert await link.set_param("TsTimerPeriod", 1) == 1
                assert await link.set_param("GetDataPeriodical", 1) == 1
            # Both stream at 1 kHz at the same time, in one event loop.
            results = await asyncio.gather(stream(left, 1500), stream(right, 1500))
            for result in results:
                result.check_accounting(1000)



@pytest.mark.timeout(60)
async def test_references_faster_than_the_line_are_superseded_not_queued() -> None:
    # A host sending references faster than the line carries them once had its next one
    # applied 5 s late, silently. Now the link never hands the port more than the line
    # carries, newer references replace waiting ones, and the last one takes effect.
    async with open_link("emu://") as link:
        link.enable()
        assert await link.set_param("GetDataPeriodical", 1) == 1
        loop = asyncio.get_running_loop()
        started, sent_before = loop.time(), link.stats.bytes_sent
        for k in range(20_000):  # 20,000 × 21 wire bytes: 4.2 s of line time
            link.set_references(float(k % 50), 0.0)
            if k % 500 == 0:
                await asyncio.sleep(0)
        link.set_references(33.0, -12.0)
        elapsed = loop.time() - started
        # What went to the port fits the line in the time it took, plus the allowed delay.
        assert link.stats.bytes_sent - sent_before <= (elapsed + 0.01) * 100_000 + 200
        assert link.stats.references_superseded > 15_000
        samples = link.telemetry()
        await wait_for_sample(samples, lambda s: s.a.reference == 33.0 and s.b.reference == -12.0,
                              PATIENCE, "the last reference in force")


@pytest.mark.timeout(60)
async def test_batched_reads_lose_nothing_and_never_hold_back_a_request() -> None:
    # A 100 Hz consumer lets the link gather reads for 10 ms: fewer, larger reads; every TM
    # still arrives (counters without a gap), and a parameter request is answered while
    # batching. Facts that hold however loaded the machine is: a process starved past
    # serve's backlog (TX_BACKLOG_S, 1 s of line) has TMs dropped by serve, as a USB-UART's
    # buffer overflows, and serve counts them; the link must lose none of its own.
    async with serve("--pty") as server:
        async with open_link(server.url, read_latency=0.01, reconnect=False) as link:
            link.enable()
            assert await link.set_param("GetDataPeriodical", 1) == 1
            reads: list[int] = []
            original = link._on_data

            def counting(protocol: Any, data: bytes) -> None:
                reads.append(len(data))
                original(protocol, data)

            link._on_data = counting  # type: ignore[method-assign]
            received_before = link.stats.telemetry_received
            lost_before, damaged_before = link.stats.lost, link.stats.decode_errors
            await wait_until(lambda: link.stats.telemetry_received - received_before >= 1000,
                             PATIENCE * 2, "1000 TM")
            assert await link.set_param("Kp_Wheel_PidA", 4.5) == 4.5  # answered mid-batching
            received = link.stats.telemetry_received - received_before
            lost = link.stats.lost - lost_before
            damaged = link.stats.decode_errors - damaged_before
            # Batched: each read carried several frames (unbatched at 1 kHz: about one).
            assert received / len(reads) > 3, (received, len(reads))
            link.set_read_latency(None)
            assert await link.set_param("GetDataPeriodical", 0) == 0
        await server.stopped()  # its exit report says what it dropped
        report = server.log_text()
    said = re.search(r"dropped (\d+) TX bytes nobody read in time", report)
    dropped = int(said.group(1)) if said else 0
    if not dropped:
        assert lost == 0 and damaged == 0, (lost, damaged, report)
    # Every TM missing is one serve dropped: whole (54 wire bytes at least) or torn at the
    # edge of a drop (then a damaged frame).
    assert (lost - damaged) * TM_WIRE_BYTES_AT_LEAST <= dropped, (lost, damaged, dropped)
