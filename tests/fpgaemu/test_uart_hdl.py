"""The emulator's UART against LiteX's (tests/support/hdl_uart.py: migen → Verilog → Icarus):
the identical bit-slot waveforms — clean, and every fault kind the line model lays out (bit
flips, low stop bits, high start bits, breaks, cuts, noise) — give the same bytes, the same
framing errors, at the same cycles up to one documented constant: the emulator delivers a
byte at the end of its stop bit, LiteX raises ``valid`` 46 cycles earlier (at 1 MBd).
And the transmitter: with ``byte_gap=2`` the emulator's back-to-back bytes are spaced as
LiteX's (1,002 cycles).

The level-triggered receiver (``uart_rx=level``) against OpenTitan's ``uart_rx`` the same
way: the same bytes and framing errors, and the cycle of each ``rx_valid`` is the one the
emulator's receiver puts after its stop sample, exactly. The two modes agree on clean
traffic and on data faults and part after low stop bits, breaks and lost start bits.

CI runs a few hundred random waveforms; ``FPGALINK_LONG=1`` runs thousands. Without
Icarus Verilog or litex the tests skip, unless ``FPGALINK_REQUIRE_HDL=1`` (set by
``make test``), where that is a failure."""

from __future__ import annotations

import itertools
import os
import random
from pathlib import Path

import pytest

from fpgaemu.timeline import Timeline
from fpgaemu.uart import (
    BITS_PER_BYTE,
    LEVEL_SYNC_CYCLES,
    LevelReceiver,
    SlotReceiver,
    UartWrite,
    litex_sample_points,
)
from tests.support.hdl_uart import PREROLL, Event, HdlUart, why_unavailable

LONG = os.environ.get("FPGALINK_LONG") == "1"
RANDOM_WAVEFORMS = 3000 if LONG else 300

_missing = why_unavailable()
if _missing is not None and os.environ.get("FPGALINK_REQUIRE_HDL") == "1":
    raise RuntimeError(f"the HDL cross-check must run here: {_missing}")
pytestmark = [pytest.mark.skipif(_missing is not None, reason=_missing or ""),
              pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def hdl(tmp_path_factory: pytest.TempPathFactory) -> HdlUart:
    return HdlUart(tmp_path_factory.mktemp("hdl"))


@pytest.fixture(scope="module")
def hdl_level(tmp_path_factory: pytest.TempPathFactory) -> HdlUart:
    return HdlUart(tmp_path_factory.mktemp("hdl_level"), level=True)


def byte_slots(value: int) -> list[int]:
    return [0, *((value >> k) & 1 for k in range(8)), 1]


def frames(data: bytes, *, stop_low: set[int] = frozenset(),  # type: ignore[assignment]
           start_high: set[int] = frozenset()) -> list[int]:  # type: ignore[assignment]
    slots: list[int] = []
    for index, value in enumerate(data):
        bits = byte_slots(value)
        if index in stop_low:
            bits[9] = 0
        if index in start_high:
            bits[0] = 1
        slots += bits
    return slots


def random_waveform(rng: random.Random) -> list[int]:
    """Bursts of bytes with flipped data bits, low stop bits, high start bits, breaks of
    1–40 slots (stuck line), cut stretches (idle), noise bytes, idle gaps."""
    slots = [1] * rng.randrange(1, 6)
    for _ in range(rng.randrange(1, 9)):
        kind = rng.random()
        if kind < 0.12:
            slots += [0] * rng.randrange(1, 40)
        elif kind < 0.2:
            slots += [1] * rng.randrange(1, 12)
        else:
            bits = byte_slots(rng.randrange(256))
            if rng.random() < 0.25:
                bits[9] = 0
            if rng.random() < 0.15:
                bits[0] = 1
            if rng.random() < 0.2:
                bits[rng.randrange(1, 9)] ^= 1
            slots += bits
    return slots + [1] * rng.randrange(0, 13)


def emulated(slots: list[int], cycles_per_bit: int = 100) -> list[Event]:
    """The emulator's receiver on ``slots``, its cycles moved onto LiteX's ``valid``."""
    receiver = SlotReceiver(cycles_per_bit)
    samples, _ = litex_sample_points(cycles_per_bit)
    offset = BITS_PER_BYTE * cycles_per_bit - (samples[-1] + 2)  # 46 at 100 cycles/bit
    errors: list[int] = []
    receiver.on_framing_error = errors.append
    receiver.add(0, slots)
    end = len(slots) * cycles_per_bit
    events = [("byte", v, c - offset) for v, c in receiver.decide(end)]
    events += [("framing_error", -1, c - offset) for c in errors]
    # LiteX reports only what completes inside the simulated slots
    return sorted((e for e in events if e[2] < end), key=lambda e: e[2])


#: The reference's 16× divider starts at reset, this many cycles before slot 0.
LEVEL_ORIGIN = PREROLL - 1


def emulated_level(slots: list[int], cycles_per_bit: int = 100) -> list[Event]:
    """The emulator's level receiver on ``slots``, each byte placed at the cycle OpenTitan
    raises ``rx_valid`` for it: the cycle after its stop sample."""
    receiver = LevelReceiver(cycles_per_bit)
    errors: list[int] = []
    receiver.on_framing_error = errors.append
    origin = LEVEL_ORIGIN
    receiver.add(origin, slots)
    end = len(slots) * cycles_per_bit
    decided = [("byte", v, c) for v, c in receiver.decide(origin + end + 20 * cycles_per_bit)]
    decided += [("framing_error", -1, c) for c in errors]
    events: list[Event] = []
    for kind, value, done in decided:
        start = done - BITS_PER_BYTE * cycles_per_bit + LEVEL_SYNC_CYCLES
        valid = receiver._sample_cycles(start)[-1] + 1 - origin
        if valid < end:
            events.append((kind, value, valid))
    return sorted(events, key=lambda e: e[2])


def comparable(events: list[Event]) -> list[Event]:
    return [(kind, value if kind == "byte" else -1, cycle) for kind, value, cycle in events]


CHARACTERISATION = {
    "clean back to back": [1] * 4 + frames(bytes([0x55, 0xA3, 0x00, 0xFF])) + [1] * 3,
    "stop low, then 41 42 back to back": [1] * 4 + frames(b"\x00AB", stop_low={0}) + [1] * 3,
    "stop low, 4 idle, 41 42": [1] * 4 + frames(b"\x00", stop_low={0}) + [1] * 4
    + frames(b"AB") + [1] * 3,
    "stop low mid burst": [1] * 4 + frames(b"A\x00B", stop_low={1}) + [1] * 3,
    "start high mid burst": [1] * 4 + frames(b"ABCD", start_high={1}) + [1] * 3,
    "break 30 slots then idle": [1] * 4 + [0] * 30 + [1] * 20,
    "break then 41": [1] * 4 + [0] * 30 + [1] * 4 + frames(b"A") + [1] * 3,
    "break directly followed by 41": [1] * 4 + [0] * 30 + [1] + frames(b"A") + [1] * 3,
}


@pytest.mark.parametrize("name", list(CHARACTERISATION))
def test_characteristic_waveforms_match_litex(hdl: HdlUart, name: str) -> None:
    slots = CHARACTERISATION[name]
    (reference,) = hdl.receive([slots])
    assert emulated(slots) == comparable(reference)


def test_the_documented_example(hdl: HdlUart) -> None:
    # 00 41 42 with the first stop bit low: LiteX drops 0x00, then (no falling edge at
    # 0x41's start) locks onto edges inside the data.
    slots = [1] * 4 + frames(b"\x00AB", stop_low={0}) + [1] * 12
    (reference,) = hdl.receive([slots])
    assert [(k, v) for k, v, _ in reference] == [("framing_error", 0), ("framing_error", 0x50),
                                                ("byte", 0xE8)]
    assert emulated(slots) == comparable(reference)


def test_random_waveforms_match_litex(hdl: HdlUart) -> None:
    rng = random.Random(20_261_122)
    waveforms = [random_waveform(rng) for _ in range(RANDOM_WAVEFORMS)]
    references = hdl.receive(waveforms)
    mismatches = [(w, r) for w, r in zip(waveforms, references, strict=True)
                  if emulated(w) != comparable(r)]
    assert not mismatches, f"{len(mismatches)} of {len(waveforms)} differ, first: " \
        f"{''.join(map(str, mismatches[0][0]))}"


def test_other_rates_match_litex(tmp_path: Path) -> None:
    rng = random.Random(7)
    for cycles_per_bit in (16, 87, 868):  # 6.25 MBd, ~1.15 MBd, 115200 Bd
        hdl = HdlUart(tmp_path, cycles_per_bit)
        waveforms = [random_waveform(rng) for _ in range(30)]
        for slots, reference in zip(waveforms, hdl.receive(waveforms), strict=True):
            assert emulated(slots, cycles_per_bit) == comparable(reference), cycles_per_bit


def test_back_to_back_transmit_spacing_with_litexs_gap(hdl: HdlUart) -> None:
    data = bytes([0x00, 0xFF, 0x55, 0x01, 0x80])
    starts = hdl.transmit_starts(data)
    assert [b - a for a, b in itertools.pairwise(starts)] == [1002] * (len(data) - 1)
    line = UartWrite(Timeline(0), byte_gap=2)
    line.transmit(data, 0)
    line._timeline.run_until(20_000)
    ends = [cycle for _, cycle in line.read_completed_timed()]
    assert [b - a for a, b in itertools.pairwise(ends)] == [1002] * (len(data) - 1)
    # and the default, the seed's uartwrite as modelled: stop bits of exactly one bit
    plain = UartWrite(Timeline(0))
    plain.transmit(data, 0)
    plain._timeline.run_until(20_000)
    ends = [cycle for _, cycle in plain.read_completed_timed()]
    assert [b - a for a, b in itertools.pairwise(ends)] == [1000] * (len(data) - 1)


# --- the level-triggered receiver against OpenTitan's uart_rx -------------------------------


@pytest.mark.parametrize("name", list(CHARACTERISATION))
def test_characteristic_waveforms_match_opentitan(hdl_level: HdlUart, name: str) -> None:
    slots = CHARACTERISATION[name]
    (reference,) = hdl_level.receive([slots])
    assert emulated_level(slots) == comparable(reference)


def test_level_random_waveforms_match_opentitan(hdl_level: HdlUart) -> None:
    rng = random.Random(20_261_124)
    waveforms = [random_waveform(rng) for _ in range(RANDOM_WAVEFORMS)]
    references = hdl_level.receive(waveforms)
    mismatches = [(w, r) for w, r in zip(waveforms, references, strict=True)
                  if emulated_level(w) != comparable(r)]
    assert not mismatches, f"{len(mismatches)} of {len(waveforms)} differ, first: " \
        f"{''.join(map(str, mismatches[0][0]))}"


def test_level_other_rates_match_opentitan(tmp_path: Path) -> None:
    rng = random.Random(11)
    for cycles_per_bit in (16, 87, 868):
        hdl = HdlUart(tmp_path, cycles_per_bit, level=True)
        waveforms = [random_waveform(rng) for _ in range(30)]
        for slots, reference in zip(waveforms, hdl.receive(waveforms), strict=True):
            assert emulated_level(slots, cycles_per_bit) == comparable(reference), \
                cycles_per_bit


def decisions(receiver: SlotReceiver, slots: list[int]) -> list[tuple[str, int]]:
    """What a receiver makes of ``slots``: bytes and framing errors, in order."""
    errors: list[int] = []
    receiver.on_framing_error = errors.append
    receiver.add(0, slots)
    events = [(c, "byte", v) for v, c in receiver.decide(len(slots) * 100 + 2000)]
    events += [(c, "framing_error", -1) for c in errors]
    return [(kind, value) for _, kind, value in sorted(events)]


def test_the_modes_agree_on_clean_and_data_faults_and_part_after_stop_and_start_faults(
) -> None:
    rng = random.Random(3)
    for _ in range(200):  # clean traffic and flipped data bits: the same bytes
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8)))
        slots = [1] * 3 + frames(data) + [1] * 12
        for index in range(len(data)):
            if rng.random() < 0.3:
                slots[3 + index * 10 + rng.randrange(1, 9)] ^= 1
        assert decisions(SlotReceiver(100), slots) == decisions(LevelReceiver(100), slots)
    parting = {
        "low stop bit, next byte back to back": [1] * 3 + frames(b"\x00AB", stop_low={0}),
        "a break": [1] * 3 + [0] * 40 + [1] * 12,
        "a lost start bit mid burst": [1] * 3 + frames(b"ABCD", start_high={1}),
    }
    for name, waveform in parting.items():
        slots = waveform + [1] * 12
        edge = decisions(SlotReceiver(100), slots)
        level = decisions(LevelReceiver(100), slots)
        assert edge != level, name
    # A break: one framing error edge-triggered, one every byte time level-triggered.
    brk = [1] * 3 + [0] * 40 + [1] * 12
    assert decisions(SlotReceiver(100), brk).count(("framing_error", -1)) == 1
    assert decisions(LevelReceiver(100), brk).count(("framing_error", -1)) == 4
