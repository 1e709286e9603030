"""The emulated robot's stepping: an idle robot (every board quiescent, every wheel exactly
at rest) crosses its quiet stretches in one step, with the same outcome as stepping each
millisecond with every timer tick run in full."""

from __future__ import annotations

from typing import Any

from fpgaemu.firmware import Firmware
from fpgaemu.robot import EmulatedRobot
from fpgaemu.timeline import CLOCK_HZ, ms, us
from fpgalink import Connection
from fpgalink.protocol import References


def _firmware(robot: EmulatedRobot, name: str) -> Firmware:
    firmware = robot.boards[name].peripherals["firmware"]
    assert isinstance(firmware, Firmware)
    return firmware


def idle_then_drive(skip_quiet: bool) -> tuple[EmulatedRobot, dict[str, Any], int]:
    """2 s idle from power-up, then enable and references arrive (mid-millisecond) and the
    robot drives for 0.5 s; returns the robot, what each board sent, and how many times the
    body was moved."""
    robot = EmulatedRobot(body="kinematic")
    for name in robot.boards:
        _firmware(robot, name).skip_quiescent_ticks = skip_quiet
    robot.run_until(ms(2000))
    for index, name in enumerate(robot.boards):
        at = ms(2000) + us(137 + 50 * index)
        conn = Connection()
        conn.start(at / CLOCK_HZ)
        conn.enable(at / CLOCK_HZ)
        conn.send(References(40.0, 40.0 - 20 * index), at / CLOCK_HZ)
        robot.boards[name].host_write(conn.data_to_send(), at)
    sent = {}
    robot.run_until(ms(2200))
    for board in robot.boards.values():  # the watchdog would lapse: re-enable
        conn = Connection()
        conn.start(0.0)
        conn.enable(0.0)
        board.host_write(conn.data_to_send(), ms(2200))
    robot.run_until(ms(2500))
    for name, board in robot.boards.items():
        sent[name] = board.read_host_bytes_timed()
    return robot, sent, robot.body.steps


def test_an_idle_robot_crosses_its_quiet_stretches_in_one_step_with_the_same_outcome(
) -> None:
    fast, fast_sent, fast_follows = idle_then_drive(skip_quiet=True)
    full, full_sent, full_follows = idle_then_drive(skip_quiet=False)
    assert full_follows >= 2500  # one body step per millisecond
    # Idle, the robot wakes only for the boards' alive messages (every 300 ms each).
    assert fast_follows < 500 + 60
    assert fast.body.pose == full.body.pose and fast.body.distance == full.body.distance > 0.01
    assert fast_sent == full_sent and all(fast_sent.values())
    for name in fast.boards:
        for code in (1, 2):
            a, b = fast.boards[name].channels[code], full.boards[name].channels[code]
            assert a.encoder.position == b.encoder.position != 0
        assert _firmware(fast, name).timing.periods == _firmware(full, name).timing.periods


def test_without_mujoco_the_default_body_is_kinematic_and_says_so_once(
        monkeypatch: Any, caplog: Any) -> None:
    from fpgaemu import physics
    from fpgaemu import robot as robot_module

    monkeypatch.setattr(physics, "why_unavailable", lambda: "MuJoCo is not installed")
    monkeypatch.setattr(robot_module, "_said_fallback", False)
    with caplog.at_level("WARNING", logger="fpgaemu"):
        first = EmulatedRobot()
        second = EmulatedRobot()
    assert first.body_kind == second.body_kind == "kinematic"
    said = [r.getMessage() for r in caplog.records if "kinematic" in r.getMessage()]
    assert said == ["the emulated robot's body is the kinematic one: MuJoCo is not installed"]


def test_the_serve_options_reach_every_board() -> None:
    from fpgaemu.__main__ import _paced_boards
    from fpgaemu.uart import LevelReceiver
    from fpgalink.protocol.robot import seed_robot

    paced = _paced_boards(["L", "R"], seed_robot(), 1_000_000, 0, "high", {},
                          {"L": [], "R": []}, body="kinematic", uart_rx="level", tx_gap=2)
    for side in paced.values():
        assert isinstance(side.board.uartread.receiver, LevelReceiver)
        assert side.board.uartwrite.byte_gap == 2
    boards = _paced_boards(["B1"], None, 1_000_000, 0, "high", {}, {"B1": []},
                           uart_rx="level", tx_gap=1)
    assert isinstance(boards["B1"].board.uartread.receiver, LevelReceiver)
    assert boards["B1"].board.uartwrite.byte_gap == 1
