"""Every TM the board sent is delivered, or counted lost, and the numbers add up exactly.

"Lost" and "damaged" are not separate piles on the host: a frame the line damaged so that
it no longer decodes is a decode error (aborted frame, overflow or Malformed) *and*, since
its counter never arrives, part of a counter gap. So the exact identity is over counters:

    leading + (counted arrivals − duplicates) + stats.lost + trailing == messages sent

with ``leading`` the counters before the first one the host saw and ``trailing`` those after
the last (still on the wire when the run stops). Decode errors are reported beside it: each
is one of the lost, never an extra. A frame damaged so that it still decodes — bit errors
in a binary field; the protocol has no checksum — is delivered with wrong values; those are
measured against what the firmware really sent (``test_bit_errors_*``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest

from fpgaemu.firmware import Firmware
from fpgalink import Telemetry
from fpgalink.events import CounterDuplicate, CounterGap, CounterLate
from tests.support.emulated import STREAMING, Cable, body_of, content_of, scale

pytestmark = pytest.mark.timeout(120)

MODULUS = 100_000

#: Byte-level faults on both lines, a 200 ms break and a 300 ms cut on the board's line, a
#: 100 ms cut on the host's (so the enable watchdog lapses once and recovers).
BYTE_MIX = [
    "tx-drop=2e-4", "tx-dup=2e-4", "tx-noise=2e-4:6",
    "rx-drop=1e-3", "rx-dup=1e-3", "rx-noise=1e-3:6", "rx-ber=1e-4",
    "tx-stuck=10:0.2", "tx-cut=20:0.3", "rx-cut=30:0.4",
]


@dataclass
class Accounting:
    sent: int
    leading: int
    arrivals: int
    duplicates: int
    lost: int
    trailing: int
    decode_errors: int
    telemetry_events: int
    intact: int
    wrong_values: int
    wrong_counter: int

    @property
    def accounted(self) -> int:
        return self.leading + self.arrivals - self.duplicates + self.lost + self.trailing


def run_accounting(faults: list[str], seconds: float, seed: int) -> Accounting:
    rig = Cable.linked(seed=seed, faults=faults, settings=STREAMING, record_tm=True)
    delivered: list[Telemetry] = []
    first: list[int] = []

    def on_event(event: Any) -> None:
        if type(event) is Telemetry:
            delivered.append(event)
        counter = getattr(event, "counter", None)
        if counter is not None and not first and not isinstance(
            event, CounterGap | CounterDuplicate | CounterLate
        ):
            first.append(counter)

    rig.conn.enable(rig.now_s)
    rig.write(rig.conn.data_to_send())
    rig.serve(seconds, on_event)

    sent = rig.sent_tm
    # Nothing but TMs carries a counter here (no parameter traffic), so the board's own
    # counter and the firmware's TM count must both match what the hook recorded.
    firmware = rig.firmware
    assert isinstance(firmware, Firmware)  # Cable.linked builds the Python model
    assert firmware.stats.telemetry_sent == len(sent)
    assert firmware._counter.value == len(sent) % MODULUS
    tracker = rig.conn.counter_tracker
    assert tracker.expected is not None
    trailing = (max(sent) + 1 - tracker.expected) % MODULUS
    by_body = {body_of(content): counter for counter, content in sent.items()}
    intact = wrong_values = wrong_counter = 0
    for message in delivered:
        content = content_of(message)
        assert message.counter is not None
        if sent.get(message.counter) == content:
            intact += 1
        elif body_of(content) in by_body:
            wrong_counter += 1
        else:
            wrong_values += 1
    stats = rig.conn.stats
    return Accounting(
        sent=len(sent), leading=first[0], arrivals=tracker.received,
        duplicates=tracker.duplicates, lost=tracker.lost, trailing=trailing,
        decode_errors=stats.decode_errors, telemetry_events=len(delivered), intact=intact,
        wrong_values=wrong_values, wrong_counter=wrong_counter,
    )


@pytest.mark.parametrize("seed", [1, 2])
def test_byte_faults_every_tm_delivered_or_counted_lost_exactly(seed: int) -> None:
    seconds = scale(40, 60)
    a = run_accounting(BYTE_MIX, seconds, seed)
    print(f"\naccounting seed={seed} {seconds}s: {a}")
    assert a.sent >= seconds * 1000 - 1  # one TM per 1 ms tick, none refused by the queue
    assert a.accounted == a.sent
    assert a.intact + a.wrong_values + a.wrong_counter == a.telemetry_events == a.arrivals
    # A byte fault alone always breaks the frame's layout, but two in one frame can cancel
    # (a drop and a duplicate keep the length: ~1e-4 of frames at these rates), and a
    # break or cut that ends inside a byte rewrites its bits. Those few are delivered with
    # wrong values; without a checksum nothing on the host can tell.
    assert a.wrong_values + a.wrong_counter <= 10
    # The faults really happened, and each damaged frame is among the lost.
    assert a.lost > 0 and 0 < a.decode_errors <= a.lost


@pytest.mark.parametrize("ber", [1e-5, 1e-4])
def test_bit_errors_wrong_values_are_measured(ber: float) -> None:
    """Bit errors on the board's line: how many damaged TMs decode as valid with other
    values. There is no checksum, so any flip inside the 42-byte binary section that does
    not produce a framing byte is accepted; this test pins the rate so a change shows."""
    seconds = scale(20, 60)
    a = run_accounting([f"tx-ber={ber}"], seconds, seed=7)
    hit = a.sent - a.intact
    print(f"\nber={ber} {seconds}s: {a}; accepted-wrong rate "
          f"{(a.wrong_values + a.wrong_counter) / a.sent:.2e} per TM, "
          f"{(a.wrong_values + a.wrong_counter) / max(hit, 1):.0%} of damaged TMs")
    # Expected damaged frames: 550 bit slots per TM on the wire.
    expected_hit = a.sent * 550 * ber
    assert 0.5 * expected_hit < hit < 1.5 * expected_hit
    assert a.wrong_values + a.wrong_counter > 0
    # Every delivered TM is classified, every sent one is delivered intact or not.
    assert a.intact + a.wrong_values + a.wrong_counter == a.telemetry_events
    # A counter damaged into another valid counter is judged by the next one (the tracker
    # holds big jumps as suspect), so the counter identity stays exact under bit errors too.
    assert a.accounted == a.sent
    assert a.duplicates <= a.wrong_counter
