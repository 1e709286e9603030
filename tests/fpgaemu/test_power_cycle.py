"""A board that restarts (a brown-out, a watchdog reset of the MicroBlaze, a re-flashed
bitstream): every block and the software back to power-up, the wheels and the robot's body
going on; and the telemetry-only loss. Both on demand (``Board.power_cycle``,
``schedule_power_cycle``) and from ``--fault`` specs."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

from fpgaemu import build_board, ms
from fpgaemu.board import Board
from fpgaemu.faults import parse_faults
from fpgaemu.robot import EmulatedRobot
from fpgaemu.timeline import CLOCK_HZ
from fpgalink import Connection
from fpgalink.events import (
    BoardRestarted,
    BoardResynced,
    RequestDone,
    TelemetryResumed,
    TelemetryStale,
)
from fpgalink.protocol import Alive, ParamAck, References, Telemetry, encode_frame, lookup
from tests.fpgaemu.test_golden_trace import ps
from tests.support.emulated import Cable


class Host:
    """The host's side of one board's link, run 1 ms at a time with its heartbeat: what it
    queued written, the board run, what arrived read and the timer fired."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.cable = Cable(board, Connection())
        self.link = self.cable.conn
        self.events: list[tuple[float, Any]] = []

    def run_to(self, seconds: float) -> None:
        board, cable = self.board, self.cable
        step = round(board.now / ms(1))
        while board.now < round(seconds * CLOCK_HZ):
            step += 1
            cable.flush()
            board.run_until(ms(step))
            now = step / 1000
            self.events += [(now, event) for event in cable.receive() + cable.fire_timer()]

    def telemetry(self, since: float = 0.0) -> list[Telemetry]:
        return [e for t, e in self.events if isinstance(e, Telemetry) and t >= since]


def driven(faults: list[str] | None = None, firmware: str = "python") -> Host:
    """Telemetry on, Kp_Wheel_PidA set, enabled and driving both wheels."""
    host = Host(build_board(faults=faults, firmware=firmware))
    link = host.link
    link.enable(0.0)
    link.set_param(lookup("GetDataPeriodical"), 0, 1, 0.0)
    link.set_param(lookup("Kp_Wheel_Pid"), 1, 400.0, 0.0)
    link.send(References(60.0, -40.0), 0.0)
    return host


def test_a_power_cycle_puts_the_board_back_to_power_up_while_the_wheels_go_on(
        firmware_kind: str) -> None:
    host = driven(firmware=firmware_kind)
    host.run_to(1.0)
    board = host.board
    before = host.telemetry()[-1]
    assert before.a.flags & 1 and before.a.position > 100
    assert before.counter is not None and before.counter > 900
    wheel = board.peripherals["motors"].wheels[1]  # type: ignore[attr-defined]
    angle, speed = wheel.angle_deg, wheel.speed_dps
    assert speed > 30

    board.power_cycle()
    firmware: Any = board.peripherals["firmware"]
    assert board.power_cycles == 1 and board.powered_at == ms(1000)
    assert not board.global_enable
    assert firmware.value("GetDataPeriodical") == 0  # telemetry off at power-up
    assert firmware.value("Kp_Wheel_Pid", "A") == lookup("Kp_Wheel_Pid").default
    assert board.channels[1].encoder.position == 0  # the counter starts again...
    assert wheel.angle_deg == angle and wheel.speed_dps == speed  # ...the wheel goes on

    # A host that does not know (raw bytes: no connection of its own to notice) goes on:
    # its RE enables the restarted board, which has its references cleared and its
    # telemetry off, and says E 300 ms after power-up.
    out = b""
    for k in range(1, 11):
        board.host_write(encode_frame(b"RE"))
        board.run_until(ms(1000 + 100 * k))
        out += board.read_host_bytes()
    assert out.count(b"SEP") == 3 and b"STM" not in out
    assert board.global_enable
    assert firmware.channel(1).reference == 0.0
    assert abs(wheel.speed_dps) < 5.0  # so its PID brings the wheel to rest
    assert board.channels[1].encoder.position > 0  # the wheel coasted on, counted afresh

    # The restarted board's clock and counter start again: t_us from 0, counter 00000.
    board.host_write(ps(0, 2, 0, 1, 1))  # GetDataPeriodical = 1
    board.run_until(ms(2100))
    link = Connection()
    link.receive_data(board.read_host_bytes(), 2.1)
    replies = list(link.events())
    (ack,) = [e for e in replies if isinstance(e, ParamAck)]
    assert ack.counter == 0
    first = next(e for e in replies if isinstance(e, Telemetry))
    assert first.counter == 1 and first.t_us < 1_200_000 < before.t_us + 1_000_000


def test_bytes_sent_before_the_cut_reach_the_host_and_the_hosts_pending_bytes_are_lost(
) -> None:
    board = build_board()
    link = Connection()
    link.set_param(lookup("GetDataPeriodical"), 0, 1, 0.0)
    board.host_write(link.data_to_send())
    board.run_until(ms(10))
    board.host_write(b"S" + b"x" * 200 + b"P")  # 2 ms of host bytes on the line
    board.run_until(ms(10) + ms(1) // 2)
    board.power_cycle()
    assert board.power_cycle_rx_lost > 100
    data = board.read_host_bytes()  # the PA and the TMs completed before the cut
    link.receive_data(data, 0.011)
    events = list(link.events())
    assert any(isinstance(e, RequestDone) for e in events)
    assert sum(isinstance(e, Telemetry) for e in events) >= 8


def test_restart_faults_from_specs_and_power_cycles_on_schedule(firmware_kind: str) -> None:
    assert parse_faults(["restart=0.5", "restart@1.25"]).restarts == [ms(500), ms(1250)]
    for bad in ("restart=-1", "restart=nan", "restart=inf", "restart@1=2", "restart=",
                "tm-loss=1", "tm-loss=nan:1"):
        with pytest.raises(ValueError, match="bad fault spec"):
            parse_faults([bad])
    board = build_board(faults=["restart=0.5", "restart@1.25"], firmware=firmware_kind)
    first = board.next_deadline()
    assert first is not None and first <= ms(300)
    board.run_until(ms(2000))
    assert board.power_cycles == 2 and board.powered_at == ms(1250)
    # Scheduled for the future only; not again when the faults re-attach after each one.
    board.run_until(ms(4000))
    assert board.power_cycles == 2
    with pytest.raises(ValueError):
        board.schedule_power_cycle(ms(100))


def test_a_quiet_board_wakes_for_its_restart() -> None:
    board = build_board(faults=["restart=0.45"])
    deadlines = []
    while board.now < ms(1000):
        deadline = board.next_deadline()
        assert deadline is not None
        deadlines.append(deadline)
        board.run_until(deadline)
    assert ms(450) in deadlines and board.power_cycles == 1


def test_tm_loss_loses_only_telemetry_in_its_window(firmware_kind: str) -> None:
    host = driven(["tm-loss=0.2:0.3"], firmware_kind)
    host.run_to(1.0)
    times = [tm.t_us for tm in host.telemetry()]
    assert not [t for t in times if 200_000 < t < 499_000]
    assert len(times) > 600
    faults: Any = host.board.peripherals["faults"]
    assert 295 <= faults.tm_lost <= 301
    # The rest passes: the host's connection found its telemetry stale, asked the board
    # (PG answered by PA within the window), heard its E, and saw telemetry come back.
    in_window = [e for t, e in host.events if 0.2 < t < 0.5]
    assert any(isinstance(e, TelemetryStale) for e in in_window)
    assert any(isinstance(e, RequestDone) and e.param.name == "GetDataPeriodical"
               for e in in_window)
    assert any(isinstance(e, Alive) for e in in_window)
    assert any(isinstance(e, TelemetryResumed) for t, e in host.events if 0.5 <= t < 0.51)


def test_a_robot_board_restart_leaves_the_body_moving_continuously() -> None:
    robot = EmulatedRobot(faults={"L": ["restart=0.6"]})
    hosts = {name: Connection() for name in robot.boards}
    for conn in hosts.values():
        conn.enable(0.0)
        conn.send(References(50.0, 50.0), 0.0)
    poses = []
    for step in range(1, 1201):
        for name, board in robot.boards.items():
            board.host_write(hosts[name].data_to_send())
        robot.run_until(ms(step))
        for name, board in robot.boards.items():
            conn = hosts[name]
            conn.receive_data(board.read_host_bytes(), step / 1000)
            timer = conn.get_timer()
            if timer is not None and timer <= step / 1000:
                conn.handle_timer(step / 1000)
            list(conn.events())
        poses.append(robot.truth().pose)
    assert robot.boards["L"].power_cycles == 1 and robot.boards["R"].power_cycles == 0
    steps = [math.hypot(b.x - a.x, b.y - a.y) for a, b in itertools.pairwise(poses)]
    assert max(steps) < 0.001  # never a jump: at most 1 mm in a millisecond
    assert poses[-1].x > 0.05


def test_a_restart_on_the_crc_wire_is_found_and_the_crc_set_again(firmware_kind: str
                                                                  ) -> None:
    # The restarted board is back on the plain wire and takes the host's CRC'd frames for
    # malformed ones; the host asks it for WireCrc (understood in either form), finds it 0,
    # and sets everything again, the CRC first.
    host = driven(["restart=0.5"], firmware_kind)
    host.link.set_param(lookup("WireCrc"), 0, 1, 0.0)
    host.run_to(1.5)
    events = [e for _, e in host.events]
    restarts = [e for e in events if isinstance(e, BoardRestarted)]
    assert len(restarts) == 1
    assert [e for e in events if isinstance(e, BoardResynced)] == [BoardResynced(3)]
    firmware: Any = host.board.peripherals["firmware"]
    assert firmware.value("WireCrc") == 1 and firmware.value("GetDataPeriodical") == 1
    assert firmware.value("Kp_Wheel_Pid", "A") == pytest.approx(400.0)
    assert host.link.wire_crc.on
    after = [t for t, e in host.events if isinstance(e, Telemetry) and t > 0.9]
    assert len(after) > 500  # the stream came back, checked by its CRC


def test_a_restarted_board_on_the_physics_body_no_longer_drives_and_counts_its_wheels(
        ) -> None:
    # Issue 37.13. L power-cycles at 0.5 s while both boards drive their wheels at 50
    # deg/s; its host keeps asking (the link stops enabling a restarted board, so L stays
    # disabled). The physics must then feel L's power-up PWM (0: the wheels coast and the
    # worm gears hold them), and L's new counters must follow those same wheels. (The
    # physics kept driving them at the duty they had when the power went, and L counted
    # wheels that never turned: odometry saw half the robot's motion.)
    robot = EmulatedRobot(body="mujoco", surface="gravel", faults={"L": ["restart=0.5"]})
    assert robot.physics is not None
    hosts = {name: Connection() for name in robot.boards}
    for conn in hosts.values():
        conn.enable(0.0)
        conn.set_param(lookup("GetDataPeriodical"), 0, 1, 0.0)
        conn.send(References(50.0, 50.0), 0.0)
    front_left = robot.physics.drives[[w.name for w in robot.description.wheels].index("FL")]
    at_restart = 0.0
    after: list[tuple[float, int]] = []  # (the wheel's angle, L's count), after the restart
    for step in range(1, 1501):
        now = step / 1000
        for name, board in robot.boards.items():
            board.host_write(hosts[name].data_to_send())
        robot.run_until(ms(step))
        if step == 500:
            at_restart = front_left.angle_deg
        for name, board in robot.boards.items():
            conn = hosts[name]
            conn.receive_data(board.read_host_bytes(), now)
            timer = conn.get_timer()
            if timer is not None and timer <= now:
                conn.handle_timer(now)
            for event in conn.events():
                if name == "L" and isinstance(event, Telemetry) and now > 0.55:
                    after.append((front_left.angle_deg, event.a.position))
    assert robot.boards["L"].power_cycles == 1
    assert robot.wheel("FL") is front_left  # the board's drive is the one the physics moves
    assert front_left.duty == 0 and not robot.boards["L"].global_enable
    assert abs(front_left.speed_dps) < 15.0  # coasting to a stop, not driven on at 50
    assert front_left.angle_deg - at_restart > 3.0  # it did turn after the restart
    per_degree = robot.boards["L"].channels[1].encoder.counts_per_turn / 360.0
    assert len(after) > 500
    for angle, count in after:  # a sample leaves the board up to a tick after its count
        assert count == pytest.approx((angle - at_restart) * per_degree, abs=3), (angle, count)
