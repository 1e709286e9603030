"""A babbling host (random bytes at full line rate) and a garbage stream into the host's
decoder: nothing raises, the board's control loop keeps time, memory stays bounded."""

from __future__ import annotations

import random
import tracemalloc

import pytest

from fpgaemu.faults import Babbler
from fpgalink import Connection
from tests.support.emulated import STREAMING, Cable, scale

pytestmark = pytest.mark.timeout(120)


def test_babbling_host_never_breaks_the_board() -> None:
    seconds = scale(30, 60)
    # Babble over the whole run, at full line rate, with the host's heartbeat mixed in.
    rig = Cable.linked(seed=3, faults=[f"babble=0:{seconds}"], settings=STREAMING)
    babbler = rig.board.peripherals["faults"].babbler  # type: ignore[attr-defined]
    assert isinstance(babbler, Babbler)
    rig.conn.enable(rig.now_s)
    rig.write(rig.conn.data_to_send())
    tracemalloc.start()
    rig.serve(seconds / 6)
    early = tracemalloc.get_traced_memory()[0]
    rig.serve(seconds * 5 / 6)
    late, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    line = rig.board.uartread.stats
    fw = rig.firmware
    # The RX line was saturated: babble plus heartbeats fill ≥ 99 % of it.
    assert line.bytes_sent >= 0.99 * seconds * 100_000
    # The control loop ran every 1 ms tick and every TM left on time.
    assert fw.timing.periods == pytest.approx(seconds * 1000, abs=1)
    assert not fw.timing.missed
    assert fw.stats.telemetry_sent == fw.timing.periods
    cmd = rig.board.uartcommand.stats
    growth_per_s = (late - early) / (seconds * 5 / 6)
    print(f"\nbabble {seconds}s: {babbler.bytes_sent} random bytes, {cmd.frames} frames to "
          f"the CPU ({fw.stats.malformed} malformed, {fw.stats.unknown} unknown), "
          f"{cmd.errors} decoder errors, {cmd.overruns} overruns; worst TM slack "
          f"{fw.timing.worst_slack} cycles; memory {early / 1e3:.0f} kB → {late / 1e3:.0f} kB "
          f"(peak {peak / 1e3:.0f} kB, {growth_per_s:.0f} B/s)")
    # Bounded. The timing record is a histogram now, so what still grows is the host's
    # heartbeat queued behind babble that already fills 100 % of the line (the host offers
    # more than the wire carries; each queued write is ~70 B, 10 a second) and this test's
    # own log of writes: about 1.2 kB/s. A per-period leak would be ≥ 36 kB/s.
    assert growth_per_s < 5_000


def test_garbage_into_the_host_decoder_at_line_rate() -> None:
    seconds = scale(20, 60)
    rnd = random.Random(5)
    conn = Connection()
    conn.start(0.0)
    tracemalloc.start()
    early = 0
    for ms in range(seconds * 1000):
        # 100 bytes per ms is the full board→host line rate at 1 MBd.
        conn.receive_data(rnd.randbytes(100), ms / 1000)
        for _ in conn.events():
            pass
        conn.handle_timer(ms / 1000)
        if ms == 1000:
            early = tracemalloc.get_traced_memory()[0]
    late = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    s = conn.stats
    print(f"\nhost garbage {seconds}s: {s.bytes_received} bytes, {s.frames_received} frames, "
          f"{s.decode_errors} decode errors, {s.noise_bytes} noise bytes; memory "
          f"{early / 1e3:.0f} kB → {late / 1e3:.0f} kB")
    assert s.bytes_received == seconds * 100_000
    assert late - early < 200_000
