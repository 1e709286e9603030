"""End to end under trouble: the watchdog lapsing, parameter frames lost or refused, the
serving process killed (the cable pulled) and restarted, a client vanishing mid-session."""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from fpgalink import BoardLost, Connection, Telemetry
from fpgalink.aio import Link, LinkState, Subscription, open_link
from fpgalink.events import (
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    PortLost,
    PortRestored,
    StatusEvent,
)
from fpgalink.protocol import Disable, Enable, ParamGet, ParamNack, ParamSet, ParamType
from tests.support.served import (
    PATIENCE,
    T_US_MODULUS,
    connect_when_free,
    next_event,
    open_when_free,
    stream,
    wait_for_sample,
    wait_until,
)
from tests.support.serving import Served, serve, start_serve

pytestmark = pytest.mark.timeout(30)

#: Telemetry on from power-up, 1 ms period, so no request is needed to see the board.
STREAMING = ("--set", "TsTimerPeriod=1", "--set", "GetDataPeriodical=1")
WATCHDOG_US = 300_000
PERIOD_US = 1_000


def board_delta(later: Telemetry, earlier: Telemetry) -> int:
    """Board microseconds from ``earlier`` to ``later`` (``t_us`` wraps at 2³²)."""
    return (later.t_us - earlier.t_us) % T_US_MODULUS


def both_enabled(sample: Telemetry) -> bool:
    return sample.a.enabled and sample.b.enabled


def both_disabled(sample: Telemetry) -> bool:
    return not sample.a.enabled and not sample.b.enabled


# --- watchdog --------------------------------------------------------------------------------


async def test_watchdog_lapses_300ms_after_the_last_re_and_re_enables() -> None:
    async with serve("--pty", *STREAMING) as server, open_link(server.url) as link:
        samples = link.telemetry(maxsize=8192)
        first = await wait_for_sample(samples, lambda s: True, PATIENCE, "any flags")
        assert both_disabled(first) and first.a.pwm == first.b.pwm == 0
        # One RE and no heartbeat after it: link.send() writes exactly the frame given.
        assert link.send(Enable()) == b"SREP"
        link.set_references(40.0, -40.0)
        # Walk the stream: the last disabled sample before RE, the first enabled one, the
        # first disabled one after it.
        before = first
        high: Telemetry | None = None
        moving = 0

        async def until_lapse() -> Telemetry:
            nonlocal before, high, moving
            async for sample in samples:
                if high is None:
                    if both_enabled(sample):
                        high = sample
                    else:
                        before = sample
                    continue
                if not both_disabled(sample):
                    assert both_enabled(sample), "A and B share one global_enable"
                    moving += sample.a.pwm != 0 and sample.b.pwm != 0
                    continue
                return sample
            raise AssertionError("stream ended")

        low = await asyncio.wait_for(until_lapse(), PATIENCE)
        assert high is not None
        assert moving > 0, "the controllers never drove the PWM while enabled"
        # The RE's STOP came after `before`'s tick and by `high`'s tick; the watchdog fires
        # 300 ms after it and the next tick reports it.
        assert board_delta(low, before) > WATCHDOG_US
        assert board_delta(low, high) <= WATCHDOG_US + PERIOD_US
        for channel in (low.a, low.b):
            assert channel.pwm == 0 and channel.reference == 0.0
        # Resume: RE again and enable comes back, with the stale references cleared.
        link.send(Enable())
        again = await wait_for_sample(samples, both_enabled, PATIENCE, "enable back")
        assert again.a.reference == again.b.reference == 0.0
        link.send(Disable())
        off = await wait_for_sample(samples, both_disabled, PATIENCE, "RD taking effect")
        assert off.a.pwm == off.b.pwm == 0
        assert link.stats.lost == 0 or link.stats.decode_errors > 0  # a pty may drop, counted


# --- parameter retry and refusal -------------------------------------------------------------


@pytest.mark.parametrize("where", ["tcp", "emu"])
async def test_dropped_ps_succeeds_on_the_second_try(where: str) -> None:
    async with serve("--tcp", "127.0.0.1:0", "--fault", "drop-frames=PS:1") as server:
        url = server.url if where == "tcp" else "emu://?fault=drop-frames=PS:1"
        async with open_link(url, request_timeout=0.05) as link:
            assert await link.set_param("MaxControlSignalB", 1000) == 1000
            assert link.stats.retries == 1
            assert await link.get_param("MaxControlSignalB") == 1000
            assert await link.set_param("MaxControlSignalB", 2000) == 2000
            assert link.stats.retries == 1  # only the first PS was lost


async def test_refusals_name_the_reason() -> None:
    async with serve("--tcp", "127.0.0.1:0") as server, open_link(server.url) as link:
        # The host validates exactly as the board does, so refusals are provoked past the
        # host's validation, straight onto the wire. (ParameterRefused from set_param on a
        # PN: tests/fpgalink/aio/test_link.py, against a scripted board.)
        nacks: list[ParamNack] = []
        remove = link.add_listener(lambda e: nacks.append(e) if type(e) is ParamNack else None)
        INT, FLOAT = int(ParamType.INT), int(ParamType.FLOAT)
        cases: list[tuple[ParamSet | ParamGet, int, str]] = [
            (ParamSet(5, 1, INT, 40_000), 3, "value out of range"),
            (ParamSet(1, 1, INT, 5), 2, "bad channel"),
            (ParamGet(3, 0), 2, "bad channel"),
            (ParamSet(42, 0, INT, 0), 1, "unknown parameter id"),
            (ParamSet(1, 0, FLOAT, 5.0), 4, "wrong value type"),
        ]
        for count, (message, code, reason) in enumerate(cases, 1):
            link.send(message)
            await wait_until(lambda n=count: len(nacks) == n,  # type: ignore[misc]
                             PATIENCE, f"PN for {message}")
            nack = nacks[-1]
            assert (nack.error, nack.reason) == (code, reason), message
            assert nack.param_id == message.param_id and nack.channel == message.channel
        remove()
        # Nothing refused was applied.
        assert await link.get_param("MaxControlSignalA") == 32760
        assert await link.get_param("TsTimerPeriod") == 1


# --- unplug ----------------------------------------------------------------------------------


async def _unplug_with_a_request_pending(
    link: Link, server: Served, loop: asyncio.AbstractEventLoop,
    kinds: tuple[type[StatusEvent], ...]
) -> tuple[AsyncIterator[StatusEvent], Subscription[Telemetry]]:
    """Stream enabled with a PS pending (the board never answers it), kill the serve
    process, and check the link reports one of ``kinds`` and fails the request (the request
    fails by the port's loss or the board's silence, not by its own, longer timeout).
    Returns the event watch and the telemetry subscription."""
    events = link.watch()
    link.enable()
    samples = link.telemetry(maxsize=8192)
    await wait_for_sample(samples, both_enabled, PATIENCE, "enable")
    pending = asyncio.ensure_future(link.set_param("TsTimerPeriod", 2))
    await wait_until(lambda: link.connection.pending_requests == 1, PATIENCE, "the PS")
    server.send_signal(signal.SIGKILL)
    await next_event(events, kinds, PATIENCE)
    with pytest.raises(BoardLost):
        await asyncio.wait_for(pending, PATIENCE)
    return events, samples


async def test_tcp_serve_killed_then_restarted_on_the_same_port() -> None:
    loop = asyncio.get_running_loop()
    # The first board never answers PS, so a request is pending when the cable goes.
    server = await asyncio.to_thread(start_serve, "--tcp", "127.0.0.1:0", "--fault",
                                     "drop-frames=PS:1000", *STREAMING)
    url = server.url
    port = url.rsplit(":", 1)[1]
    restarted = None
    try:
        async with open_link(url, request_timeout=2.0, request_tries=5,
                             reconnect_backoff=(0.05, 0.2)) as link:
            events, samples = await _unplug_with_a_request_pending(
                link, server, loop, (PortLost, BoardSilent))
            assert link.state is LinkState.RECONNECTING
            with pytest.raises(BoardLost, match="disconnected"):
                await link.get_param("TsTimerPeriod")
            assert await server.exited(5.0) != 0

            restarted = await asyncio.to_thread(start_serve, "--tcp", f"127.0.0.1:{port}",
                                                *STREAMING)
            assert restarted.url == url
            await next_event(events, (PortRestored,), 5.0)
            assert link.state is LinkState.CONNECTED  # type: ignore[comparison-overlap]
            samples.close()
            # The new server is a new board: the link reports it restarted (on the
            # reconnected port), and did not enable it by itself.
            restart = await next_event(events, (BoardRestarted,), PATIENCE)
            assert "reconnected port" in restart.detail
            await next_event(events, (BoardResynced,), PATIENCE)
            assert not link.enabled
            # The probe that asked the board heard again is answered before this read, so
            # no answer takes a counter inside the stretch whose counters are checked.
            assert await link.get_param("TsTimerPeriod") == 1
            # Telemetry flows again; enabled again by the caller, the new board runs.
            link.enable()
            result = await stream(link, 500)
            result.check_accounting(PERIOD_US)
            assert result.missing == 0  # over TCP nothing is lost, however slow the host
            assert all(both_enabled(s) for s in result.samples[-100:])
            assert await link.set_param("TsTimerPeriod", 1) == 1
            assert link.stats.reconnects == 1 and link.stats.port_losses == 1
    finally:
        await server.stopped()
        if restarted is not None:
            await restarted.stopped()


async def test_pty_vanishing_is_reported_and_retried(tmp_path: Path) -> None:
    loop = asyncio.get_running_loop()
    # Everything the loop's exception handler receives: nothing may escape the link.
    loop_errors: list[dict[str, Any]] = []
    previous_handler = loop.get_exception_handler()
    loop.set_exception_handler(lambda _loop, context: loop_errors.append(context))
    try:
        await _pty_vanishing(loop, tmp_path / "board")
    finally:
        loop.set_exception_handler(previous_handler)
    # The serial transport reports a failed read/write on the vanished pty by closing
    # (connection_lost), not through the handler (pyserial-asyncio's did, as a "serial
    # transport" error: still let through, should it come back); anything else is not.
    unexpected = [c for c in loop_errors if "serial transport" not in str(c.get("message"))]
    assert unexpected == [], unexpected


async def _pty_vanishing(loop: asyncio.AbstractEventLoop, link_path: Path) -> None:
    # Opened through serve's --link, which is removed once it is open: the device's name
    # goes with it, as udev's by-id link does. A serve killed with SIGKILL cannot remove it,
    # and the pty number it points at may be given to another process (a test running
    # beside this one) before the link retries: the link then reconnected to that board.
    async with serve("--pty", "--link", str(link_path), "--fault", "drop-frames=PS:1000",
                     *STREAMING) as server:
        path = str(link_path)
        assert os.path.realpath(path) == os.path.realpath(server.url)
        async with open_link(path, request_timeout=2.0,
                             reconnect_backoff=(0.02, 0.05)) as link:
            link_path.unlink()
            _events, _samples = await _unplug_with_a_request_pending(
                link, server, loop, (PortLost,))
            # Several reconnect attempts (backoff 20 → 50 ms) fail on the missing device;
            # the link keeps trying and stays usable.
            observe_until = loop.time() + 0.4
            await wait_until(lambda: loop.time() >= observe_until, PATIENCE, "the retry window")
            assert link.state is LinkState.RECONNECTING
            assert link.stats.reconnects == 0 and link.stats.port_losses == 1
            with pytest.raises(BoardLost):
                await link.set_param("TsTimerPeriod", 1)
        assert link.state is LinkState.CLOSED  # type: ignore[comparison-overlap]


# --- a client goes away, another comes ---------------------------------------------------------


async def test_reconnect_to_the_running_board_finds_it_disabled_after_a_lapse() -> None:
    # What is timed is timed on the board's clock (t_us of its own samples), never by when
    # the host got around to connecting: the earlier version took the new session's first
    # sample as the moment enable fell and failed whenever connecting took a while.
    async with serve("--tcp", "127.0.0.1:0", *STREAMING) as server:
        host, port = server.url.removeprefix("socket://").rsplit(":", 1)
        # A first session: enabled with heartbeat, sets a parameter, closes (sends RD).
        async with open_link(server.url) as link:
            link.enable()
            assert await link.set_param("Kp_Wheel_PidA", 4.25) == 4.25
            first_session = await wait_for_sample(link.telemetry(), both_enabled, PATIENCE,
                                                  "enable")
        # A raw client: once the board shows itself disabled (the first session's RD), one RE,
        # then silence, watching the board until its watchdog lapses.
        reader, writer = await connect_when_free(host, int(port))
        decoder = Connection(baud=None)
        loop = asyncio.get_running_loop()

        async def sample(predicate: Callable[[Telemetry], bool]) -> Telemetry:
            while data := await reader.read(4096):
                decoder.receive_data(data, loop.time())
                for event in decoder.events():
                    if type(event) is Telemetry and predicate(event):
                        return event
            raise AssertionError("connection closed")

        await asyncio.wait_for(sample(both_disabled), PATIENCE)
        writer.write(b"SREP")
        await writer.drain()
        first_high = await asyncio.wait_for(sample(both_enabled), PATIENCE)
        first_low = await asyncio.wait_for(sample(both_disabled), PATIENCE)
        # The RE's stop bit lies in the period before the first enabled sample; the lapse
        # is 300 ms after it, seen at the next sample.
        lapse = board_delta(first_low, first_high)
        assert WATCHDOG_US - PERIOD_US <= lapse <= WATCHDOG_US + PERIOD_US
        assert decoder.stats.lost == 0
        writer.close()  # vanishes without RD
        await writer.wait_closed()
        # A new session on the same running board finds it still running, disabled.
        async with await open_when_free(server.url) as link:
            samples = link.telemetry(maxsize=8192)
            seen = await wait_for_sample(samples, lambda s: True, 5.0, "any sample")
            assert 0 < board_delta(seen, first_session) < 60 * 1_000_000
            assert board_delta(seen, first_low) > 0
            assert both_disabled(seen) and seen.a.pwm == seen.b.pwm == 0
            assert await link.get_param("Kp_Wheel_PidA") == 4.25
            assert link.stats.lost == 0
