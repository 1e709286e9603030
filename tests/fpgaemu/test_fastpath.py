"""The fused paths (:mod:`fpgaemu.fastpath`) against the modules: two boards built alike,
one with the fused paths switched off, driven through the same random scenario — host
traffic of every kind at random cycles (references, enables, parameter sets and gets, bad
values, garbage), line and board faults, parameter changes that leave the regular pattern
(timer period, controller, encoder, CRC), reads at random cycles — must agree on every wire
byte and its cycle, and, state against state, on every register, RAM byte, counter, float
and pending event (:mod:`tests.support.boardstate`)."""

from __future__ import annotations

import math
import struct
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from fpgaemu import build_board, ms
from fpgaemu.board import Board
from fpgaemu.robot import EmulatedRobot
from fpgalink.protocol import encode_frame
from tests.fpgaemu.test_golden_trace import digest, scenario, trace
from tests.support.boardstate import board_state, first_difference, same_state

FAULTS = [
    [], [], [], [],  # mostly clean: the fused paths' own ground
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


def _pair(**options: Any) -> tuple[Board, Board]:
    return build_board(**options), build_board(**options, fused=False)


def _firmware(board: Board) -> Any:
    return board.peripherals["firmware"]


@settings(max_examples=60)
@given(
    faults=st.sampled_from(FAULTS),
    noise=st.sampled_from([0.0, 0.0, 0.05]),
    gear=st.sampled_from(["high", "low"]),
    telemetry=st.booleans(),
    warm_ms=st.sampled_from([0, 120, 400]),
    steps=st.lists(step, min_size=1, max_size=14),
)
def test_fused_board_is_the_modules_board(faults: list[str], noise: float, gear: str,
                                           telemetry: bool, warm_ms: int, steps: list[Any]
                                           ) -> None:
    options = {"faults": faults, "current_noise_a": noise, "gear": gear,
               "settings": {"GetDataPeriodical": int(telemetry)}}
    boards = _pair(**options)
    counter = 0
    # Enabled and driven from the start, so the regular pattern is there to be fused, and
    # (warmed up) the wheels are turning: encoder edges, PID, moving plants.
    for board in boards:
        board.host_write(encode_frame(b"RE"), 50)
        board.host_write(encode_frame(_counted(b"RV", 0, struct.pack("<ff", 40.0, -25.0))),
                         ms(0.3))
        for at in range(100, warm_ms, 100):
            board.host_write(encode_frame(b"RE"), ms(at))
        board.run_until(ms(warm_ms))
    for delay, messages, separately, read_state in steps:
        at = boards[0].now + delay
        writes = []
        for item in messages:
            counter += 1
            writes.append(_wire(item, counter))
        if not separately:
            writes = [b"".join(writes)]
        for board in boards:
            for wire in writes:
                if wire:
                    board.host_write(wire, board.now + len(writes))
            board.run_until(at)
        fused, modules = (board.read_host_bytes_timed() for board in boards)
        assert fused == modules
        if read_state:
            # A read mid-run: the processor-side registers, then every block's state.
            assert boards[0].global_enable == boards[1].global_enable
            same_state(*boards)
    for board in boards:
        board.run_until(board.now + ms(5))
    assert boards[0].read_host_bytes_timed() == boards[1].read_host_bytes_timed()
    same_state(*boards)


def test_fused_ticks_run_on_a_regular_board() -> None:
    """The comparison above is not vacuous: on clean traffic the fused tick does the
    ticks, and switched off it does none."""
    boards = _pair(settings={"GetDataPeriodical": 1})
    for board in boards:
        board.host_write(encode_frame(b"RE"), 50)
        board.host_write(encode_frame(_counted(b"RV", 0, struct.pack("<ff", 40.0, 30.0))),
                         ms(0.3))
        board.run_until(ms(300))
    assert _firmware(boards[0])._fused.fused == 300
    assert _firmware(boards[1])._fused is None
    same_state(*boards)
    assert _firmware(boards[0]).channels[1].speed > 10.0  # the wheels did turn


def test_the_state_walk_sees_a_one_ulp_difference() -> None:
    """The comparison's own check: one float's last bit, one RAM byte, one pending event."""
    a, b = _pair()
    for board in (a, b):
        board.run_until(ms(3))
    assert first_difference(board_state(a), board_state(b)) is None
    wheel = b.peripherals["motors"].wheels[1]  # type: ignore[attr-defined]
    wheel.angle_deg = math.nextafter(wheel.angle_deg, 1.0)
    assert "angle_deg" in (first_difference(board_state(a), board_state(b)) or "")
    wheel.angle_deg = a.peripherals["motors"].wheels[1].angle_deg  # type: ignore[attr-defined]
    b.blk_mem_gen_rx._mem[17] ^= 1
    assert "_mem" in (first_difference(board_state(a), board_state(b)) or "")
    b.blk_mem_gen_rx._mem[17] ^= 1
    b.schedule(ms(9), lambda _cycle: None)
    assert "_heap" in (first_difference(board_state(a), board_state(b)) or "")


def test_golden_trace_with_and_without_the_fused_paths(firmware_kind: str) -> None:
    """The golden trace on both firmwares: the C core has no fused tick of its own, but it
    takes its frames from the fused receive (its state lives in C memory, so here the wire
    bytes and the logic's state are what is compared)."""
    fused, modules = _pair(firmware=firmware_kind)
    assert digest(trace(fused)) == digest(trace(modules))
    same_state(fused, modules)
    assert len(scenario()) > 2000


@settings(max_examples=8)
@given(body=st.sampled_from(["kinematic", "kinematic", "mujoco"]),
       command=st.tuples(finite, finite), seconds=st.integers(20, 120))
def test_fused_robot_is_the_modules_robot(body: str, command: tuple[float, float],
                                          seconds: int) -> None:
    robots = [EmulatedRobot(body=body, settings={"GetDataPeriodical": 1}, fused=fused)
              for fused in (True, False)]
    for robot in robots:
        for board in robot.boards.values():
            board.host_write(encode_frame(b"RE"), 50)
            board.host_write(encode_frame(_counted(b"RV", 0, struct.pack("<ff", *command))),
                             ms(0.3))
        robot.run_until(ms(seconds))
    for name in robots[0].boards:
        a, b = robots[0].boards[name], robots[1].boards[name]
        assert a.read_host_bytes_timed() == b.read_host_bytes_timed()
        same_state(a, b)
    assert robots[0].truth() == robots[1].truth()
