"""The compiled build (mypyc) against pure Python, from the same source: a board of each
build, each in a process of its own (:mod:`tests.support.twin`), driven through the same
random scenario — host traffic of every kind at random cycles (references, enables,
parameter sets and gets, bad values, garbage), line and board faults, parameter changes
(timer period, controller, encoder, CRC), reads at random cycles — must agree on every wire
byte and its cycle and, state against state, on every register, RAM byte, counter, float (to
the bit) and pending event (:mod:`tests.support.boardstate`); so must the golden trace on
both firmwares and the robot on both bodies. The comparison is checked against itself: a
few ulps in one mode of one wheel's plant, in the pure build's source, are caught."""

from __future__ import annotations

import math
import os
import shutil
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fpgaemu import build_board, ms
from fpgalink.protocol import encode_frame
from tests.fpgaemu.test_golden_trace import GOLDEN_SHA256, scenario
from tests.support.boardstate import board_state, first_difference
from tests.support.twin import ROOT, Twin

pytestmark = pytest.mark.timeout(600)

FAULTS = [
    [], [], [], [],  # mostly clean: the regular millisecond
    ["rx-ber=0.002"], ["tx-drop=0.01"], ["rx-noise=0.01:3"], ["wheel-stuck=A:0.01:0.02"],
    ["restart=0.025"], ["tm-loss=0.01:0.01"], ["babble=0.015:0.003"],
    ["drop-frames=RV:3"], ["rx-stuck=0.02:0.0005"], ["tx-cut=0.01:0.002"],
]


def _counted(msg_id: bytes, counter: int, body: bytes) -> bytes:
    return msg_id + b"%05d" % (counter % 100_000) + b"{" + bytes((len(body),)) + body + b"}"


def _param(param_id: int, channel: int, value: float) -> bytes:
    int_params = {1, 2, 4, 5, 6, 7, 11}
    if param_id in int_params:
        return bytes((param_id, channel, 1)) + struct.pack("<i", int(value))
    return bytes((param_id, channel, 2)) + struct.pack("<f", value)


finite = st.floats(-120.0, 120.0, allow_nan=False, width=32)
reference = st.one_of(finite, finite, finite, st.sampled_from([math.nan, math.inf, 0.0]))

message = st.one_of(
    st.tuples(st.just("RV"), reference, reference),
    st.just(("RE",)), st.just(("RE",)), st.just(("RD",)),
    st.tuples(st.just("PS"), st.sampled_from([1, 2, 2, 4, 5, 6, 7, 8, 9, 10, 11]),
              st.sampled_from([0, 1, 2]), st.sampled_from([0, 1, 2, 3, -1, 400.0, 0.05, 2.5,
                                                            32760, 100, 1e9])),
    st.tuples(st.just("PG"), st.integers(1, 12), st.sampled_from([0, 1, 2])),
    st.tuples(st.just("junk"), st.binary(min_size=1, max_size=12)),
)


def _wire(item: tuple[Any, ...], counter: int) -> bytes:
    kind = item[0]
    if kind == "RV":
        return encode_frame(_counted(b"RV", counter, struct.pack("<ff", item[1], item[2])))
    if kind in ("RE", "RD"):
        return encode_frame(kind.encode())
    if kind == "PS":
        return encode_frame(_counted(b"PS", counter, _param(item[1], item[2], item[3])))
    if kind == "PG":
        return encode_frame(_counted(b"PG", counter, bytes((item[1], item[2]))))
    data: bytes = item[1]
    return data


#: (cycles to run, messages, written one host write each (else as one), read the state)
step = st.tuples(st.integers(0, ms(3)), st.lists(message, min_size=0, max_size=3),
                 st.booleans(), st.booleans())


def _require_compiled(twin: Twin) -> None:
    """Skip where there is no compiled build to compare (a pure install, a stale build) —
    a failure under ``FPGALINK_REQUIRE_COMPILED=1``, as ``make test`` sets."""
    if twin.build.startswith("compiled"):
        return
    if os.environ.get("FPGALINK_REQUIRE_COMPILED") == "1":
        pytest.fail("the compiled build must run here (FPGALINK_REQUIRE_COMPILED=1): "
                    f"the worker runs {twin.build}; `make compile` builds it")
    pytest.skip(f"no compiled build to compare with (this checkout runs {twin.build})")


@pytest.fixture(scope="module")
def twins() -> Iterator[tuple[Twin, Twin]]:
    compiled, pure = Twin(pure=False), Twin(pure=True)
    try:
        assert pure.build == "pure Python"
        yield compiled, pure
    finally:
        compiled.close()
        pure.close()


def same_state(twins: tuple[Twin, Twin], name: str | None = None) -> None:
    compiled, pure = (twin.call("state", name) for twin in twins)
    assert len(compiled) > 200, "the walk found almost nothing: not a board's state"
    difference = first_difference(compiled, pure)
    assert difference is None, f"compiled != pure at {difference}"


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    faults=st.sampled_from(FAULTS),
    noise=st.sampled_from([0.0, 0.0, 0.05]),
    gear=st.sampled_from(["high", "low"]),
    telemetry=st.booleans(),
    warm_ms=st.sampled_from([0, 120, 400]),
    steps=st.lists(step, min_size=1, max_size=14),
)
def test_the_compiled_board_is_the_pure_board(
        twins: tuple[Twin, Twin], faults: list[str], noise: float, gear: str,
        telemetry: bool, warm_ms: int, steps: list[Any]) -> None:
    _require_compiled(twins[0])
    options = {"faults": faults, "current_noise_a": noise, "gear": gear,
               "settings": {"GetDataPeriodical": int(telemetry)}}
    counter = 0
    # Enabled and driven from the start, so the regular millisecond is there, and (warmed
    # up) the wheels are turning: encoder edges, PID, moving plants.
    for twin in twins:
        twin.call("new_board", options)
        twin.call("host_write", None, encode_frame(b"RE"), 50)
        twin.call("host_write", None,
                  encode_frame(_counted(b"RV", 0, struct.pack("<ff", 40.0, -25.0))), ms(0.3))
        for at in range(100, warm_ms, 100):
            twin.call("host_write", None, encode_frame(b"RE"), ms(at))
        twin.call("run_until", ms(warm_ms))
    for delay, messages, separately, read_state in steps:
        at = twins[0].call("now") + delay
        writes = []
        for item in messages:
            counter += 1
            writes.append(_wire(item, counter))
        if not separately:
            writes = [b"".join(writes)]
        for twin in twins:
            now = twin.call("now")
            for wire in writes:
                if wire:
                    twin.call("host_write", None, wire, now + len(writes))
            twin.call("run_until", at)
        compiled, pure = (twin.call("read", None) for twin in twins)
        assert compiled == pure
        if read_state:
            # A read mid-run: the processor-side registers, then every block's state.
            assert twins[0].call("global_enable", None) == twins[1].call("global_enable", None)
            same_state(twins)
    for twin in twins:
        twin.call("run_until", twin.call("now") + ms(5))
    assert twins[0].call("read", None) == twins[1].call("read", None)
    same_state(twins)


def test_golden_trace_compiled_and_pure(twins: tuple[Twin, Twin], firmware_kind: str) -> None:
    """The golden trace on both builds and both firmwares (the C core's state lives in C
    memory: there the wire bytes and the logic's state are what is compared)."""
    _require_compiled(twins[0])
    (compiled, compiled_state), (pure, pure_state) = (
        twin.call("golden", firmware_kind) for twin in twins)
    assert compiled == pure == GOLDEN_SHA256
    assert first_difference(compiled_state, pure_state) is None
    assert len(scenario()) > 2000


@settings(max_examples=8, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.sampled_from(["kinematic", "kinematic", "mujoco"]),
       command=st.tuples(finite, finite), seconds=st.integers(20, 120))
def test_the_compiled_robot_is_the_pure_robot(twins: tuple[Twin, Twin], body: str,
                                              command: tuple[float, float],
                                              seconds: int) -> None:
    _require_compiled(twins[0])
    if body == "mujoco":
        pytest.importorskip("mujoco")
    for twin in twins:
        twin.call("new_robot", {"body": body, "settings": {"GetDataPeriodical": 1}})
        for name in ("L", "R"):
            twin.call("host_write", name, encode_frame(b"RE"), 50)
            twin.call("host_write", name,
                      encode_frame(_counted(b"RV", 0, struct.pack("<ff", *command))), ms(0.3))
        twin.call("run_until", ms(seconds))
    for name in ("L", "R"):
        assert twins[0].call("read", name) == twins[1].call("read", name)
        same_state(twins, name)
    assert twins[0].call("truth") == twins[1].call("truth")


def test_the_state_walk_sees_a_one_ulp_difference() -> None:
    """The comparison's own check, in this process: one float's last bit, one RAM byte, one
    pending event."""
    a, b = build_board(), build_board()
    for board in (a, b):
        board.run_until(ms(3))
    assert first_difference(board_state(a), board_state(b)) is None
    wheel = b.peripherals["motors"].wheels[1]  # type: ignore[attr-defined]
    wheel.angle_deg = math.nextafter(wheel.angle_deg, 1.0)
    assert "angle_deg" in (first_difference(board_state(a), board_state(b)) or "")
    wheel.angle_deg = a.peripherals["motors"].wheels[1].angle_deg  # type: ignore[attr-defined]
    b.blk_mem_gen_rx.write_byte(17, 1)
    assert "_mem" in (first_difference(board_state(a), board_state(b)) or "")
    b.blk_mem_gen_rx.write_byte(17, 0)
    b.schedule(ms(9), lambda _cycle: None)
    assert "_heap" in (first_difference(board_state(a), board_state(b)) or "")


#: A few ulps in the third mode of every wheel's plant: its pole, as the model is built.
PLANT = "src/fpgaemu/motor.py"
UNMUTATED = "        self._s = list(model.poles)\n"
MUTATED = UNMUTATED + "        self._s[2] *= 1.0 + 4 * 2.0**-52\n"


def test_a_few_ulps_in_one_plant_mode_are_caught(twins: tuple[Twin, Twin],
                                                 tmp_path: Path) -> None:
    """The pure build's source with one plant mode's pole a few ulps off, against the
    compiled build: the state walk finds it in the wheel's floats."""
    _require_compiled(twins[0])
    shutil.copytree(ROOT / "src", tmp_path / "src",
                    ignore=shutil.ignore_patterns("*.so", "*.pyd", "_compiled.txt",
                                                  "__pycache__"))
    plant = tmp_path / PLANT
    text = plant.read_text(encoding="utf-8")
    assert text.count(UNMUTATED) == 1
    plant.write_text(text.replace(UNMUTATED, MUTATED), encoding="utf-8")
    mutated = Twin(pure=True, src=tmp_path / "src")
    try:
        pair = (twins[0], mutated)
        for twin in pair:
            twin.call("new_board", {"settings": {"GetDataPeriodical": 1}})
            twin.call("host_write", None, encode_frame(b"RE"), 50)
            twin.call("host_write", None,
                      encode_frame(_counted(b"RV", 0, struct.pack("<ff", 40.0, -25.0))),
                      ms(0.3))
            twin.call("run_until", ms(200))
        difference = first_difference(twins[0].call("state", None),
                                      mutated.call("state", None))
        # Where the wheel's motion shows first: its plant, or the current it draws.
        assert difference is not None and ("motors" in difference
                                           or "current_a" in difference), difference
    finally:
        mutated.close()


def _board_bytes(telemetry_ms: int) -> list[tuple[int, int]]:
    """What a board sends a host that enables it, sets a parameter and streams telemetry
    for ``telemetry_ms``: each byte with the cycle its stop bit ended."""
    board = build_board(settings={"GetDataPeriodical": 1})
    board.host_write(encode_frame(b"RE"), 50)
    board.host_write(encode_frame(_counted(b"PS", 0, _param(8, 1, 2.5))), ms(0.2))
    board.run_until(ms(telemetry_ms))
    sent: list[tuple[int, int]] = board.read_host_bytes_timed()
    return sent


#: the board's own bytes, made once (the same for every example: the mutations differ)
_SENT = _board_bytes(40)


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    cuts=st.lists(st.integers(1, 400), min_size=1, max_size=60),
    damage=st.lists(st.tuples(st.integers(0, len(_SENT) - 1), st.binary(max_size=6),
                              st.integers(0, 2)), max_size=8),
    timers=st.lists(st.floats(0.0, 0.06), max_size=6),
)
def test_the_compiled_host_is_the_pure_host(
        twins: tuple[Twin, Twin], cuts: list[int], damage: list[tuple[int, bytes, int]],
        timers: list[float]) -> None:
    """A ``Connection`` of each build fed the same bytes at the same times — a real board's
    telemetry and answers, cut into reads of random sizes, with bytes replaced, dropped or
    inserted — reports the same events, writes the same bytes, asks for the same timers
    and counts the same."""
    _require_compiled(twins[0])
    data = bytearray(b for b, _ in _SENT)
    for index, junk, how in sorted(damage, reverse=True):
        if how == 0:  # replaced
            data[index:index + len(junk)] = junk
        elif how == 1:  # dropped
            del data[index:index + len(junk) + 1]
        else:  # inserted
            data[index:index] = junk
    # Each byte arrives when the board's byte at its place did (damage shifts a few).
    sent_at = [cycle / 100e6 for _, cycle in _SENT]
    at = [sent_at[min(i, len(sent_at) - 1)] for i in range(len(data))]
    script: list[tuple[Any, ...]] = [("start", 0.0), ("enable", 0.0),
                                     ("set", 0.001, "Kp_Wheel_PidA", 2.5),
                                     ("references", 0.002, 40.0, -25.0)]
    start = 0
    for size in cuts:
        if start >= len(data):
            break
        end = min(len(data), start + size)
        script.append(("receive", at[min(end, len(at)) - 1], bytes(data[start:end])))
        start = end
    if start < len(data):
        script.append(("receive", at[-1], bytes(data[start:])))
    for when in timers:
        script.append(("timer", at[-1] + when))
    compiled, pure = (twin.call("host", script) for twin in twins)
    reported = [event for events, _, _ in compiled[:-1] for event in events]
    assert sum(event.startswith("Telemetry(") for event in reported) > 10, \
        "hardly any telemetry reported: the comparison compares nothing"
    assert compiled == pure
