"""PacedBoard under CPU starvation: it falls behind the wall clock, catches up in bounded
slices without losing a byte, and reports the lag (how late a deadline was met); its
deadlines skip what changes nothing. Driven by a fake clock: no sleeping."""

from __future__ import annotations

from typing import Any

import pytest

from fpgaemu.build import build_board
from fpgaemu.serve import CATCH_UP_SLICE_S, RX_BACKLOG_BYTES, RX_RESUME_BYTES, PacedBoard
from fpgalink import Connection, Telemetry
from fpgalink.protocol import Enable, ParamSet
from tests.support.wire import sent


def test_starved_board_catches_up_without_losing_bytes_and_reports_lag() -> None:
    now = [100.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    host = Connection(baud=None)
    paced.host_write(sent(Enable(), host) + sent(ParamSet(2, 0, 1, 1), host))
    received = bytearray()

    def tick(dt: float) -> None:
        # What the serving loop does: ask for the next deadline, sleep (here: dt, however
        # late that is), advance.
        paced.next_wake()
        now[0] += dt
        received.extend(paced.advance())

    for _ in range(50):  # 50 ms served on time
        tick(0.001)
    assert paced.lag.lag_events == 0
    tick(0.4)  # the process was starved for 0.4 s
    assert paced.lag.lag_events == 1
    assert paced.lag.worst_lag_s >= 0.39
    # One call runs at most one slice, so the serving loop stays responsive.
    behind = (paced.target_cycle() - paced.board.now) / 100_000_000
    assert behind >= 0.4 - CATCH_UP_SLICE_S - 0.002
    while paced.target_cycle() - paced.board.now > 100_000:
        tick(0.0)
    for _ in range(50):
        tick(0.001)
    host.receive_data(bytes(received), now[0])
    counters = [e.counter for e in host.events()
                if isinstance(e, Telemetry) and e.counter is not None]
    # Every period's TM arrived, in order, none lost while catching up.
    assert len(counters) >= 495
    assert counters == list(range(counters[0], counters[0] + len(counters)))
    assert host.stats.lost == 0 and host.stats.decode_errors == 0


def test_the_line_says_how_much_it_takes_and_never_drops_what_it_took() -> None:
    # Backpressure, not loss: an endpoint reads no more than rx_room(); what it hands over
    # all goes onto the line, and the room comes back as the line carries it.
    now = [10.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    assert paced.rx_room() == RX_BACKLOG_BYTES
    assert paced.host_write(b"x" * RX_BACKLOG_BYTES) == RX_BACKLOG_BYTES
    assert paced.rx_room() == 0 and paced.rx_backlog() == RX_BACKLOG_BYTES
    # Handed more anyway, the board still takes every byte: nothing is ever dropped here.
    assert paced.host_write(b"y" * 100) == 100
    assert paced.board.uartread.stats.bytes_sent == RX_BACKLOG_BYTES + 100
    # 1 ms carries 100 bytes at 1 MBd.
    now[0] += 0.002
    paced.advance()
    assert paced.rx_room() in (99, 100)
    # The resume moment is when the backlog has drained to the low-water mark.
    now[0] = paced.rx_resume_at()
    assert paced.rx_backlog() == RX_RESUME_BYTES
    now[0] -= 20e-6  # two bytes earlier it has not
    assert paced.rx_backlog() > RX_RESUME_BYTES


def test_a_departed_hosts_bytes_are_discarded() -> None:
    now = [10.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    paced.host_write(b"z" * 4000)
    now[0] += 0.001
    paced.advance()
    lost = paced.host_gone()
    assert 3850 <= lost <= 3900  # ~100 bytes went out in that millisecond
    assert paced.board.uartread.stats.dropped_bytes == lost
    # The next host starts on an idle line.
    assert paced.host_write(b"w" * 10) == 10


def test_an_idle_board_has_no_deadline_for_its_quiescent_ticks() -> None:
    # Disabled, no telemetry, wheels still: the timer ticks change nothing, so the next
    # thing a host could see is the board's E, every 300 ms — not the next 1 ms tick.
    now = [10.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    start = now[0]
    wake = paced.next_wake()
    assert wake is not None and wake - now[0] == pytest.approx(0.3, abs=1e-6)
    wakeups, out = 0, b""
    while not out:  # wake only at the deadlines the board names
        wake = paced.next_wake()
        assert wake is not None
        now[0] = wake
        out = paced.advance()
        wakeups += 1
    assert out == b"SEP" and wakeups == 2  # E starts; its 3 bytes end 30 µs later
    assert now[0] - start == pytest.approx(0.30003, abs=1e-6)
    firmware: Any = paced.board.peripherals["firmware"]
    assert firmware.timing.periods == 300  # ticks all counted
    # Telemetry on: now every tick matters.
    paced.host_write(sent(ParamSet(2, 0, 1, 1), Connection(baud=None)))
    now[0] += 0.01
    paced.advance()
    wake = paced.next_wake()
    assert wake is not None and wake - now[0] <= 0.001


def test_skipping_quiescent_ticks_changes_nothing() -> None:
    """The reference model: the same traffic with every tick run in full."""
    from tests.fpgaemu.test_golden_trace import digest, trace

    fast, full = build_board(), build_board()
    firmware: Any = full.peripherals["firmware"]
    firmware.skip_quiescent_ticks = False
    assert digest(trace(fast)) == digest(trace(full))
    fast_firmware: Any = fast.peripherals["firmware"]
    assert fast_firmware.timing.periods == firmware.timing.periods


async def test_emu_transport_buffers_what_the_host_writes_and_pauses_the_protocol() -> None:
    # emu:// dropped what the host wrote beyond the 4 KiB backlog; now it keeps it, feeds the
    # line as it makes room, and tells the protocol to pause and resume as asyncio's
    # transports do.
    import asyncio

    from fpgaemu.serve import open_emulated_transport
    from fpgalink.protocol import ParamAck, ParamGet
    from tests.support.flood import noise
    from tests.support.wire import received

    class Host(asyncio.Protocol):
        def __init__(self) -> None:
            self.calls: list[str] = []
            self.wire = b""

        def pause_writing(self) -> None:
            self.calls.append("pause")

        def resume_writing(self) -> None:
            self.calls.append("resume")

        def data_received(self, data: bytes) -> None:
            self.wire += data

    transport, protocol = await open_emulated_transport("emu://", 1_000_000, Host)
    assert isinstance(protocol, Host) and isinstance(transport, asyncio.Transport)
    transport.set_write_buffer_limits(high=8192)
    assert transport.get_write_buffer_limits() == (2048, 8192)
    payload = noise(20_000) + sent(ParamGet(1, 0))
    for start in range(0, len(payload), 1000):
        transport.write(payload[start:start + 1000])
    assert protocol.calls == ["pause"]
    # Held in the transport beyond what the line takes (a little more may have gone out
    # while the writes were made: the line drains 100 bytes a millisecond).
    assert 8192 < transport.get_write_buffer_size() <= len(payload) - RX_BACKLOG_BYTES
    board: Any = transport.get_extra_info("board")
    try:
        async with asyncio.timeout(10):
            while not any(isinstance(e, ParamAck) for e in received(protocol.wire)):
                await asyncio.sleep(0.01)
    finally:
        transport.close()
    assert protocol.calls == ["pause", "resume"]
    assert transport.get_write_buffer_size() == 0
    assert board.uartread.stats.bytes_sent == len(payload)  # every byte, none dropped
    assert board.uartcommand.stats.noise_bytes == 20_000


def test_serve_link_to_a_live_pty_is_not_taken_over(tmp_path: Any) -> None:
    """``fpgaemu serve --link``: a symlink to a pty that is there may be another serve's or
    a router's: refused, the link untouched; a dangling one, or one to our own new pty, is
    replaced."""
    import os

    import pytest

    from fpgaemu.__main__ import ServeError, _make_link

    master, slave = os.openpty()
    try:
        live = os.ttyname(slave)
        link = tmp_path / "fpga0"
        link.symlink_to(live)
        with pytest.raises(ServeError, match="which exists"):
            _make_link(link, "/dev/pts/999999")
        assert os.readlink(link) == live
        _make_link(link, live)
        link.unlink()
        link.symlink_to(tmp_path / "gone")
        _make_link(link, live)
        assert os.readlink(link) == live
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(("links", "says"), [
    (["L={tmp}/a", "L={tmp}/b"], "board L has one pty, linked at {tmp}/a already"),
    (["{tmp}/a", "{tmp}/b"], "board L has one pty"),
    (["L="], "'L=': no path"),
])
def test_serve_refuses_a_link_it_would_not_make(links: list[str], says: str,
                                                  tmp_path: Any) -> None:
    """``fpgaemu serve --link`` takes the router's grammar (``fpgalink.ports``); a board's
    one pty has one link. A second link for a board was dropped without a word (only the
    last was made), and ``L=`` was taken for the working directory (exit 5); now each is
    one line, exit 2, before anything is served."""
    import subprocess
    import sys

    args = [a for link in links for a in ("--link", link.format(tmp=tmp_path))]
    done = subprocess.run([sys.executable, "-m", "fpgaemu", "serve", "--pty", *args],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("fpgaemu: error: --link") and done.stderr.count("\n") == 1
    assert says.format(tmp=tmp_path) in done.stderr
    assert not done.stdout and not list(tmp_path.iterdir())


async def test_an_unplugged_ptys_link_goes_with_it_and_comes_back_to_the_new_pty(
        tmp_path: Any) -> None:
    """While unplugged, the ``--link`` is gone (as udev's by-id link of a pulled USB-UART):
    the freed pty's number may be given to another program, whose pty a host reopening the
    link must not reach. Plugged in again, it points at the new pty; a link another took
    meanwhile is theirs and left alone."""
    import os

    from fpgaemu.serve import PtyEndpoint

    link = tmp_path / "fpga0"
    endpoint = PtyEndpoint(PacedBoard(build_board()))
    endpoint.start()
    try:
        link.symlink_to(endpoint.path)
        endpoint.link = link
        endpoint._unplug()
        assert not link.is_symlink()
        endpoint._replug()
        assert os.readlink(link) == endpoint.path and link.exists()
        # Taken while unplugged: another program's pty now at that name.
        endpoint._unplug()
        other_master, other_slave = os.openpty()
        try:
            link.symlink_to(os.ttyname(other_slave))
            endpoint._replug()
            assert os.readlink(link) == os.ttyname(other_slave)
        finally:
            os.close(other_master)
            os.close(other_slave)
        # A stale link (its pty gone) is replaced.
        endpoint._unplug()
        link.unlink()
        link.symlink_to(tmp_path / "gone")
        endpoint._replug()
        assert os.readlink(link) == endpoint.path
    finally:
        await endpoint.close()


def test_serve_measures_how_late_the_hosts_heartbeat_reached_it() -> None:
    # The host's RE 100 ms apart keep the board enabled and show no silence; one that comes
    # 350 ms after the last lets the watchdog lapse, and serve says both: the lapse, and the
    # 350 ms it read nothing from the host while the board was enabled.
    now = [50.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    host = Connection(baud=None)

    def run_for(seconds: float) -> None:
        end = now[0] + seconds
        while now[0] < end - 1e-9:
            paced.next_wake()
            now[0] = min(end, now[0] + 0.001)
            paced.advance()

    for _ in range(5):
        paced.host_write(sent(Enable(), host))
        run_for(0.1)
    assert paced.board.uartcommand.global_enable
    assert paced.heartbeat.watchdog_lapses == 0
    assert paced.heartbeat.longest_silence_s == pytest.approx(0.1)
    run_for(0.25)  # 350 ms since the last RE
    paced.host_write(sent(Enable(), host))
    assert paced.heartbeat.watchdog_lapses == 1
    assert paced.heartbeat.longest_silence_s == pytest.approx(0.35)
    # A host that leaves is not silent: the next one's first bytes count from nothing.
    run_for(0.1)
    paced.host_gone()
    run_for(2.0)
    paced.host_write(sent(Enable(), host))
    assert paced.heartbeat.longest_silence_s == pytest.approx(0.35)
