"""What a live view shows: each board (telemetry, parameters, link events, statistics) and
the robot (odometry's pose and path, the emulator's truth in the same frame, the transforms
and URDF Foxglove's 3D panel draws the robot with, the command, supervision and health).
Topics and schemas are the recordings' where a recording has the topic
(``/board/NAME/telemetry``, ``/robot/odometry`` …), so one Foxglove layout
(``examples/foxglove/fpgalink.json``) opens a live view and a recording alike."""

from __future__ import annotations

import asyncio
import functools
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fpgalink.boardclock import BoardClock
from fpgalink.events import Event
from fpgalink.live.server import LiveServer
from fpgalink.protocol import ParamAck, ParamNack, Telemetry
from fpgalink.protocol.viewschemas import (
    FRAME_TRANSFORMS_SCHEMA,
    PARAMETERS_SCHEMA,
    POSE_IN_FRAME_SCHEMA,
    POSES_IN_FRAME_SCHEMA,
    STATUS_SCHEMA,
    STRING_SCHEMA,
    pose,
    stamp,
)
from fpgalink.recording import (
    COMMAND_SCHEMA,
    EVENT_SCHEMA,
    PARAM_SCHEMA,
    POSE_SCHEMA,
    STATS_FIELDS,
    STATS_SCHEMA,
    compact,
    json_safe,
    log_record,
    parameter_record,
    telemetry_row,
    telemetry_schema,
)

if TYPE_CHECKING:
    from fpgalink.aio.link import Stamped, Subscription
    from fpgalink.connection import LinkStats
    from fpgalink.robot.robot import Robot
    from fpgalink.robot.supervision import SupervisionEvent

__all__ = ["BoardFeed", "BoardTap", "RobotFeed", "telemetry_json"]

#: How often the slow topics go out: statistics, the parameter table, health, the URDF (a
#: client that subscribes later has it within this).
SLOW_S = 1.0
#: The robot's pose, truth and transforms.
POSE_S = 0.05
#: A path grows by a pose once the robot has moved this far or turned this much.
PATH_STEP_M = 0.01
PATH_STEP_RAD = math.radians(1.0)
#: The most poses a path keeps (the oldest go first): about 50 m of driving.
PATH_POSES = 5000
#: Telemetry waiting for the feed when it falls behind (the link drops the oldest, counted).
TELEMETRY_QUEUE = 4096


@dataclass(frozen=True)
class BoardTap:
    """What a live view reads of one board, whoever holds its link: a one-board command its
    own link, a robot its boards (:meth:`of_robot`)."""

    #: everything the board's connection reports, in order (a remover back)
    add_listener: Callable[[Callable[[Event], None]], Callable[[], None]]
    #: its telemetry, each sample with when it arrived
    stamped_telemetry: Callable[[int], Subscription[Stamped]]
    #: the link's statistics now
    stats: Callable[[], LinkStats]
    #: the parameters this host holds for it (name → value)
    held: Mapping[str, float]
    #: what its link notices, as (kind, detail) (a remover back)
    on_event: Callable[[Callable[[str, str], None]], Callable[[], None]]

    @classmethod
    def of_robot(cls, robot: Robot, board: str) -> BoardTap:
        """Board ``board`` of ``robot``, through the robot's own methods."""
        boards = robot.boards

        def on_event(callback: Callable[[str, str], None]) -> Callable[[], None]:
            def notice(seen: Any) -> None:
                if getattr(seen, "board", None) == board and hasattr(seen, "kind"):
                    callback(seen.kind, seen.detail)
            return robot.on_notice(notice)

        return cls(add_listener=functools.partial(boards.add_listener, board),
                   stamped_telemetry=functools.partial(boards.stamped_telemetry, board),
                   stats=functools.partial(boards.stats, board),
                   held=boards.held(board), on_event=on_event)


class BoardFeed:
    """One board's link on the live view: ``/board/NAME/telemetry`` (every sample),
    ``/params`` (every PA/PN), ``/parameters`` (the table: what this host set and the board
    confirmed, and every value the board confirmed since), ``/events`` (foxglove.Log,
    latched: its last messages go to a client that subscribes later), ``/stats``."""

    def __init__(self, server: LiveServer, name: str, tap: BoardTap) -> None:
        self.server = server
        self.name = name
        self.tap = tap
        self.values: dict[str, float] = dict(tap.held)
        self._prefix = f"/board/{name}"
        self._tasks: list[asyncio.Task[None]] = []
        self._removers: list[Callable[[], None]] = []
        self._received = 0

    def start(self) -> None:
        server, prefix = self.server, self._prefix
        server.channel(f"{prefix}/telemetry", telemetry_schema())
        server.channel(f"{prefix}/params", PARAM_SCHEMA)
        server.channel(f"{prefix}/parameters", PARAMETERS_SCHEMA)
        # A restart is logged once: a client that subscribes after it is still told of it.
        server.channel(f"{prefix}/events", EVENT_SCHEMA, latched=True)
        server.channel(f"{prefix}/stats", STATS_SCHEMA)
        self._removers += [self.tap.add_listener(self._on_message),
                           self.tap.on_event(self._on_link_event)]
        self._tasks += [asyncio.ensure_future(self._telemetry()),
                        asyncio.ensure_future(self._slow())]

    def _on_message(self, event: Event) -> None:
        if not isinstance(event, ParamAck | ParamNack):
            return
        now = time.time()
        record = parameter_record(event, now)
        if record is None:
            return
        if record["status"] == "in_force" and isinstance(record.get("value"), int | float):
            self.values[record["name"]] = record["value"]
        self.server.publish(f"{self._prefix}/params", record, now)

    def _on_link_event(self, kind: str, detail: str) -> None:
        now = time.time()
        self.server.publish(f"{self._prefix}/events", lambda: log_record(
            kind, detail, now, f"board {self.name}"), now)

    async def _telemetry(self) -> None:
        topic = f"{self._prefix}/telemetry"
        clock = BoardClock()
        to_epoch = time.time() - asyncio.get_running_loop().time()
        async for received, sample in self.tap.stamped_telemetry(TELEMETRY_QUEUE):
            self._received += 1
            if not self.server.wanted(topic):
                continue
            received += to_epoch
            stamp_s = clock.seconds(sample.t_us, received)
            data = telemetry_json(sample, stamp_s)
            if data is None:  # a value that is not finite: null, through the full path
                row = json_safe({k: compact(v) for k, v in telemetry_row(sample, 0.0).items()})
                row["timestamp"] = round(stamp_s, 6)
                self.server.publish(topic, row, received)
            else:
                self.server.publish_json(topic, data, received)

    async def _slow(self) -> None:
        last, counted = time.monotonic(), 0
        while True:
            await asyncio.sleep(SLOW_S)
            now = time.monotonic()
            rate = (self._received - counted) / max(now - last, 1e-9)
            last, counted = now, self._received
            stats = self.tap.stats()
            record: dict[str, Any] = {"timestamp": time.time(), "telemetry_rate": rate}
            record.update({name: getattr(stats, name) for name in STATS_FIELDS[1:]})
            self.server.publish(f"{self._prefix}/stats", record)
            self.server.publish(f"{self._prefix}/parameters", dict(self.values))

    async def close(self) -> None:
        for remove in self._removers:
            remove()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


def telemetry_json(sample: Telemetry, timestamp: float) -> bytes | None:
    """A sample as ``/board/NAME/telemetry`` has it (the recording's row: 7 significant
    digits of each float), formatted in one step — 2,000 a second on a two-board robot, in
    the control path's loop, where building a dict and encoding it cost about five times as
    much. ``None`` when a value is not finite (JSON has no NaN: the row's path writes null)."""
    a, b = sample.a, sample.b
    if not (math.isfinite(a.speed) and math.isfinite(a.current) and math.isfinite(a.reference)
            and math.isfinite(b.speed) and math.isfinite(b.current)
            and math.isfinite(b.reference)):
        return None
    counter = "null" if sample.counter is None else sample.counter
    return (f'{{"timestamp":{timestamp:.6f},"t_us":{sample.t_us},"counter":{counter},'
            f'"a_position":{a.position},"a_speed":{a.speed:.7g},"a_current":{a.current:.7g},'
            f'"a_pwm":{a.pwm},"a_ref":{a.reference:.7g},"a_flags":{a.flags},'
            f'"b_position":{b.position},"b_speed":{b.speed:.7g},"b_current":{b.current:.7g},'
            f'"b_pwm":{b.pwm},"b_ref":{b.reference:.7g},"b_flags":{b.flags}}}').encode()


class _Path:
    """A path as foxglove.PosesInFrame: a pose each time the robot moved a step."""

    def __init__(self) -> None:
        self.poses: list[tuple[float, float, float]] = []

    def add(self, x: float, y: float, theta: float) -> None:
        if self.poses:
            px, py, pt = self.poses[-1]
            turned = abs(math.remainder(theta - pt, math.tau))
            if math.hypot(x - px, y - py) < PATH_STEP_M and turned < PATH_STEP_RAD:
                return
        self.poses.append((x, y, theta))
        if len(self.poses) > PATH_POSES:
            del self.poses[: len(self.poses) - PATH_POSES]

    def record(self, at: float) -> dict[str, Any]:
        return {"timestamp": stamp(at), "frame_id": "odom",
                "poses": [pose(*p) for p in self.poses]}


class RobotFeed:
    """The robot on the live view, in the frame odometry counts in (``odom``: the pose at
    the command's start): ``/robot/odometry`` and ``/robot/truth`` (fpgalink.Pose2D, as
    recorded), ``/robot/pose``, ``/robot/truth_pose`` (foxglove.PoseInFrame),
    ``/robot/path``, ``/robot/truth_path`` (foxglove.PosesInFrame), ``/tf``
    (foxglove.FrameTransforms: odom → base_link, base_link → each wheel, turning),
    ``/robot_description`` (the URDF), ``/robot/command``, ``/robot/supervision``
    (foxglove.Log, latched), ``/robot/health``. ``truth`` gives the emulated body's pose in
    that frame (``None`` on hardware)."""

    def __init__(self, server: LiveServer, robot: Robot,
                 truth: Callable[[], dict[str, Any] | None] | None = None) -> None:
        self.server = server
        self.robot = robot
        self.truth = truth
        self.path = _Path()
        self.truth_path = _Path()
        self._tasks: list[asyncio.Task[None]] = []

    def start(self) -> None:
        from fpgalink.protocol.urdf import robot_urdf

        server = self.server
        for topic, schema in (
                ("/robot/odometry", POSE_SCHEMA), ("/robot/truth", POSE_SCHEMA),
                ("/robot/pose", POSE_IN_FRAME_SCHEMA), ("/robot/truth_pose", POSE_IN_FRAME_SCHEMA),
                ("/robot/path", POSES_IN_FRAME_SCHEMA),
                ("/robot/truth_path", POSES_IN_FRAME_SCHEMA), ("/tf", FRAME_TRANSFORMS_SCHEMA),
                ("/robot_description", STRING_SCHEMA), ("/robot/command", COMMAND_SCHEMA),
                ("/robot/health", STATUS_SCHEMA)):
            server.channel(topic, schema)
        # A stop is logged once: a client that subscribes after it is still told of it.
        server.channel("/robot/supervision", EVENT_SCHEMA, latched=True)
        self._urdf = robot_urdf(self.robot.description)
        self._tasks += [asyncio.ensure_future(self._poses()),
                        asyncio.ensure_future(self._slow()),
                        asyncio.ensure_future(self._supervision())]

    async def _poses(self) -> None:
        while True:
            self.publish_pose(time.time())
            await asyncio.sleep(POSE_S)

    def publish_pose(self, now: float) -> None:
        robot, server = self.robot, self.server
        state = robot.odometry_state
        p = state.pose
        self.path.add(p.x, p.y, p.theta)
        server.publish("/robot/odometry", {"t": now, "x": p.x, "y": p.y, "theta": p.theta,
                                           "v": state.v, "omega": state.omega}, now)
        server.publish("/robot/pose", lambda: {"timestamp": stamp(now), "frame_id": "odom",
                                               "pose": pose(p.x, p.y, p.theta)}, now)
        server.publish("/tf", lambda: self._transforms(now, p.x, p.y, p.theta), now)
        command = robot.command
        if command is not None:
            server.publish("/robot/command", {
                "v": command.v, "omega": command.omega, "left": command.left_dps,
                "right": command.right_dps, "scale": command.scale}, now)
        truth = self.truth() if self.truth is not None else None
        if truth is not None:
            self.truth_path.add(truth["x"], truth["y"], truth["theta"])
            server.publish("/robot/truth", {k: truth[k] for k in
                                            ("x", "y", "theta", "v", "omega")} | {"t": now},
                           now)
            server.publish("/robot/truth_pose", lambda: {
                "timestamp": stamp(now), "frame_id": "odom",
                "pose": pose(truth["x"], truth["y"], truth["theta"])}, now)

    def _transforms(self, now: float, x: float, y: float, theta: float) -> dict[str, Any]:
        at = stamp(now)
        body = pose(x, y, theta)
        transforms = [{"timestamp": at, "parent_frame_id": "odom",
                       "child_frame_id": "base_link", "translation": body["position"],
                       "rotation": body["orientation"]}]
        joints = self.robot.joint_states()
        angles = dict(zip(joints.names, joints.position, strict=True)) if joints else {}
        for wheel in self.robot.description.wheels:
            turn = angles.get(wheel.name, 0.0)  # about the axle (y): a quaternion about y
            transforms.append({
                "timestamp": at, "parent_frame_id": "base_link",
                "child_frame_id": f"{wheel.name}_link",
                "translation": {"x": wheel.x, "y": wheel.y, "z": 0.0},
                "rotation": {"x": 0.0, "y": math.sin(turn / 2), "z": 0.0,
                             "w": math.cos(turn / 2)}})
        return {"transforms": transforms}

    async def _slow(self) -> None:
        while True:
            now = time.time()
            self.server.publish("/robot_description", {"data": self._urdf}, now)
            self.server.publish("/robot/path", functools.partial(self.path.record, now), now)
            if self.truth_path.poses:
                self.server.publish("/robot/truth_path",
                                    functools.partial(self.truth_path.record, now), now)
            self.server.publish("/robot/health", self._health, now)
            await asyncio.sleep(SLOW_S)

    def _health(self) -> dict[str, Any]:
        return {"statuses": [{"name": s.name, "level": int(s.level), "message": s.message}
                             for s in self.robot.health()]}

    async def _supervision(self) -> None:
        async for event in self.robot.events():
            now = time.time()
            self.server.publish("/robot/supervision", _supervision_log(event, now), now)

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


def _supervision_log(event: SupervisionEvent, now: float) -> dict[str, Any]:
    stopped = event.reason is not None and not event.recovered and \
        event.reason.name != "REQUESTED"
    return log_record("supervision", event.describe(), now, "robot", 4 if stopped else 2)
