"""The robot on ROS 2: one node, ``fpgalink``, over a started :class:`~fpgalink.robot.Robot`.
The node is ROS glue: its parameters (:mod:`.parameters`), its topics and what it publishes
(:mod:`.messages`); what drives the wheels — limits, ramps, the command timeout, the held
command, the enable's renewal — is the robot's command arbiter, and the stamps are the
robot's stamped sample sets (:mod:`fpgalink.robot.stamping`).

Threads: asyncio owns the main thread (the boards' links, the robot, the publishing loops);
rclpy's executor spins in one background thread. A subscription's callback hands its
message to the asyncio loop (``call_soon_threadsafe``); publishers are called from the
loop. Parameter sets are coroutines the executor awaits while the asyncio loop talks to
the board, so a set reports success only after the board's echo matched.

Topics (relative names, so ``--ros-args -r __ns:=/robot`` and remaps work): see
docs/ros2.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, String

from fpgalink.errors import FpgalinkError
from fpgalink.protocol import describe_identity, identity_metadata
from fpgalink.robot import GoalTimeout, Robot, RobotStopped
from fpgalink.robot.arbiter import Commanded, CommandNotice, Taken
from fpgalink.robot.feed import SetFeed
from fpgalink.robot.health import Status
from fpgalink.robot.recovery import BoardNotice
from fpgalink.robot.stamping import StampedSet
from fpgalink.robot.supervision import State, StopReason
from fpgalink.ros2 import messages
from fpgalink.ros2.bag import NodeBag
from fpgalink.ros2.parameters import BadOverride, BoardParameterService, NodeParameters

__all__ = ["IMU_RATE_HZ", "NODE_NAME", "BadOverride", "RosBridge", "spin_in_thread"]

NODE_NAME = "fpgalink"
DIAGNOSTICS_PERIOD_S = 1.0
#: ``imu/data`` from an emulated body's IMU: its rate, and its frame (the seed's URDF link).
IMU_RATE_HZ = 50.0
IMU_FRAME = "ImuALink"
#: A warning repeated within this is counted, not printed (a flood of bad cmd_vel).
WARNING_PERIOD_S = 2.0
CMD_VEL_TYPES = {False: "geometry_msgs/msg/Twist", True: "geometry_msgs/msg/TwistStamped"}
#: As robot_state_publisher publishes ``robot_description`` and tf2_ros's static broadcaster
#: ``/tf_static``: kept for every subscriber that comes later.
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)


def spin_in_thread(node: Node) -> tuple[SingleThreadedExecutor, threading.Thread]:
    """rclpy's executor in a daemon thread (asyncio keeps the main one)."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin() -> None:
        with contextlib.suppress(rclpy.executors.ExternalShutdownException):
            executor.spin()

    thread = threading.Thread(target=spin, name="rclpy-spin", daemon=True)
    thread.start()
    return executor, thread


class RosBridge:
    """The node and what it does. Build it on the asyncio loop after the robot started,
    then ``await bridge.run()`` until cancelled. ``overrides``: the ``-p`` names given on
    the command line (one the node has not is warned about)."""

    def __init__(self, robot: Robot, node: Node, loop: asyncio.AbstractEventLoop,
                 executor: Any = None, bag: NodeBag | None = None,
                 managed: bool = False, overrides: Iterable[str] = ()) -> None:
        self.robot = robot
        self.bag = bag
        #: a managed node (``--lifecycle``) publishes and takes commands only while active
        self.active = not managed
        self.node = node
        self.loop = loop
        self.executor = executor
        self.log = node.get_logger()
        self.overrides = set(overrides)
        #: warnings by kind: when one was last printed, and how many since were not
        self._warned: dict[str, tuple[float, int]] = {}
        self._goal: asyncio.Task[None] | None = None
        self._sets: SetFeed | None = None
        self._set_stamps: dict[str, int] = {}  #: each board's stamp of the last set
        self._tasks: list[asyncio.Task[Any]] = []
        self._removers: list[Callable[[], None]] = []
        self.published = {"joint_states": 0, "odom": 0, "diagnostics": 0, "tf": 0}
        # Who the boards are: carried in /diagnostics and the bag, said once the node is up.
        if bag is not None:
            bag.set_metadata(identity_metadata(
                {name: robot.boards.identity(name) for name in robot.description.boards}))
        self.params = NodeParameters(robot, node, self._parameters_changed)
        try:
            self._create_publishers(managed)
            self._create_subscriptions()
            self.graph = _GraphChecks(node, self.cmd_vel_sub.topic_name,
                                      CMD_VEL_TYPES[bool(self.params["use_stamped_vel"])])
        except BaseException:
            self.params.withdraw()
            raise

    def _create_publishers(self, managed: bool) -> None:
        params, robot = self.params, self.robot
        # Reliable as joint_state_broadcaster's (robot_state_publisher and most consumers
        # subscribe reliable, which never matches a best-effort publisher); sensor-data QoS
        # on request.
        self.joint_pub = self._publisher(JointState, "joint_states", (
            qos_profile_sensor_data if params["joint_states_best_effort"]
            else QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)))
        self.odom_pub = self._publisher(Odometry, "odom", 10)
        # Absolute, as diagnostic_updater publishes it (one /diagnostics for the whole
        # graph, the statuses named after the node).
        self.diag_pub = self._publisher(DiagnosticArray, "/diagnostics", 10)
        emulated = robot.truth()
        self.truth_pub = self._publisher(Odometry, "truth", 10) if emulated else None
        self.tf_type = _tf_message_type()
        # /tf as tf2_ros's broadcaster publishes it (absolute, reliable, depth 100).
        self.tf_pub = None if self.tf_type is None else self._publisher(
            self.tf_type, "/tf", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        if self.tf_type is None and params["publish_odom_tf"]:
            self.log.warning("publish_odom_tf: tf2_msgs is not installed (Jazzy has no wheel "
                             "of it; `fpgalink-ros2 --install-tf2` builds it): running without /tf "
                             "and /tf_static")
        self.description_pub = self._publisher(String, "robot_description", LATCHED)
        self.tf_static_pub = None
        if self.tf_type is not None and params["publish_static_tf"]:
            self.tf_static_pub = self._publisher(self.tf_type, "/tf_static", LATCHED)
        if not managed:
            self.publish_latched()
        self.clock_pub = None
        if params.publish_clock:
            self.published["clock"] = 0
            self.clock_pub = self.node.create_publisher(Clock, "/clock", QoSProfile(
                depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.cmd_vel_out_pub = (self._publisher(TwistStamped, "cmd_vel_out", 10)
                                if params["publish_limited_velocity"] else None)
        self.imu_pub = None
        if emulated is not None and emulated.get("imu") is not None:
            self.published["imu"] = 0
            self.imu_pub = self._publisher(Imu, "imu/data", qos_profile_sensor_data)

    def _create_subscriptions(self) -> None:
        node, stamped = self.node, bool(self.params["use_stamped_vel"])
        self.cmd_vel_sub = node.create_subscription(
            TwistStamped if stamped else Twist, "cmd_vel",
            self._threadsafe(self._on_cmd_vel, "cmd_vel"), 10)
        node.create_subscription(JointState, "wheel_refs",
                                 self._threadsafe(self._on_wheel_refs, "wheel_refs"), 10)
        node.create_subscription(PoseStamped, "goal_pose",
                                 self._threadsafe(self._on_goal, "goal_pose"), 10)
        node.create_subscription(Bool, "enable", self._threadsafe(self._on_enable, "enable"), 10)

    def withdraw(self) -> None:
        """What this bridge added to the node that the node's own lists do not show (its
        check of parameter sets): a managed node's cleanup."""
        self.params.withdraw()

    # --- parameters -----------------------------------------------------------------------

    def serve_parameters(self) -> None:
        """Answer the parameter services (the node was made with
        ``start_parameter_services=False``), board parameters confirmed by the board."""
        BoardParameterService(self.node, lambda parameter: self.params.set_parameter(
            parameter, self.loop, self.executor))
        # Said once every parameter was taken: a start refused for a bad -p is one line.
        for name in self.robot.description.boards:
            identity, known = self.robot.boards.identity(name)
            self.log.info(f"board {name}: {describe_identity(identity, known)}")

    async def declare_board_parameters(self) -> None:
        await self.params.declare_board_parameters(self.overrides)

    def _parameters_changed(self) -> None:
        if self._sets is not None:
            self._sets.min_period = self.params.publish_period

    def frame(self, name: str) -> str:
        return self.params.prefix + name

    def publish_latched(self) -> None:
        """robot_description and /tf_static, once (a managed node's when it is activated)."""
        self.description_pub.publish(String(data=self.params.urdf))
        if self.tf_static_pub is not None and self.tf_type is not None:
            self.tf_static_pub.publish(self.tf_type(transforms=messages.static_transforms(
                self.params.fixed_joints, self.params.prefix,
                self.node.get_clock().now().to_msg())))

    # --- subscriptions (messages arrive on the executor's thread) ------------------------

    def _threadsafe(self, handler: Callable[[Any], None], topic: str) -> Callable[[Any], None]:
        resolved = self.node.resolve_topic_name(topic)

        def record_and_handle(message: Any) -> None:
            if not self.active:  # a managed node, not activated: no commands
                return
            if self.bag is not None:
                self._record(resolved, message)  # as received, whatever the node makes of it
            handler(message)

        def forward(message: Any) -> None:
            self.loop.call_soon_threadsafe(record_and_handle, message)
        return forward

    def _publisher(self, kind: Any, topic: str, qos: Any) -> Any:
        publisher = self.node.create_publisher(kind, topic, qos)
        return publisher if self.bag is None else _RecordedPublisher(publisher, self._record)

    def _record(self, topic: str, message: Any) -> None:
        if self.bag is None:
            return
        stopped = self.bag.write(topic, message, self.node.get_clock().now().nanoseconds)
        if stopped is not None:
            self.log.error(stopped)

    def _on_cmd_vel(self, message: Twist | TwistStamped) -> None:
        twist = message.twist if isinstance(message, TwistStamped) else message
        v, omega = float(twist.linear.x), float(twist.angular.z)
        if not (math.isfinite(v) and math.isfinite(omega)):
            self._throttled_warning("non-finite", f"cmd_vel ignored: not finite ({v}, {omega})")
            return
        self._cancel_goal()
        self._take(lambda: self.robot.teleop.velocity(v, omega))

    def _on_wheel_refs(self, message: JointState) -> None:
        names = list(message.name)
        values = list(message.velocity) or list(message.effort)
        torque = not message.velocity and bool(message.effort)
        if len(values) != len(names) or not names:
            self.log.warning("wheel_refs ignored: give one velocity (rad/s) or effort (N·m) "
                             "per named joint")
            return
        joints = tuple(self.params.joint_names.values())
        unknown = sorted(set(names) - set(joints))
        if unknown or not all(math.isfinite(v) for v in values):
            self.log.warning(f"wheel_refs ignored: joints {joints}, finite values "
                             f"(got {names}, {values})")
            return
        wanted = dict(zip(names, values, strict=True))
        references = {wheel: value if torque else math.degrees(value)
                      for wheel, joint in self.params.joint_names.items()
                      if (value := wanted.get(joint)) is not None}
        self._cancel_goal()
        self._take(lambda: self.robot.teleop.wheels(references))

    def _take(self, command: Callable[[], Commanded]) -> None:
        """Give the robot a teleop's command; say what became of it."""
        try:
            done = command()
        except FpgalinkError as exc:
            self.log.warning(f"command ignored: {exc}")
            return
        if done.taken is Taken.HELD:
            # The enable, on its own topic, may come just after the command it goes with:
            # held, and sent if the robot is enabled within cmd_vel_timeout.
            self._throttled_warning("not enabled", f"command held: {done.reason} (publish "
                                    "true on enable within cmd_vel_timeout to send it)")
        elif done.taken is Taken.REFUSED:
            self._throttled_warning("refused", f"command ignored: {done.reason}")
        elif done.command is not None:
            self._publish_driven(done.command, None)

    def _throttled_warning(self, kind: str, text: str) -> None:
        """At most one warning of a kind per :data:`WARNING_PERIOD_S`, saying how many of
        that kind were not printed since the last."""
        now = time.monotonic()
        last, quiet = self._warned.get(kind, (-math.inf, 0))
        if now - last < WARNING_PERIOD_S:
            self._warned[kind] = (last, quiet + 1)
            return
        self._warned[kind] = (now, 0)
        self.log.warning(text + (f" ({quiet} more like it not shown)" if quiet else ""))

    def _on_enable(self, message: Bool) -> None:
        if message.data:
            try:
                self.robot.enable()  # a command held meanwhile is sent now (robot.teleop)
            except RobotStopped as exc:
                self._throttled_warning("refused", f"enable refused: {exc}")
        elif self.robot.state is State.ENABLED:
            self.robot.disable()

    def _on_goal(self, message: PoseStamped) -> None:
        frame = self.frame(str(self.params["odom_frame"]))
        if message.header.frame_id and message.header.frame_id != frame:
            self.log.warning(f"goal_pose in frame {message.header.frame_id!r} taken as "
                             f"{frame!r} (this node knows only its odometry)")
        p, q = message.pose.position, message.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        has_heading = not (q.x == q.y == q.z == 0.0 and q.w in (0.0, 1.0))
        self._cancel_goal()
        self._goal = asyncio.ensure_future(self._go_to(p.x, p.y, yaw if has_heading else None))

    async def _go_to(self, x: float, y: float, theta: float | None) -> None:
        base, limiter = self.robot.goto_settings, self.robot.arbiter.limiter
        settings = dataclasses.replace(
            base, position_tolerance=float(self.params["goal_tolerance"]),
            max_speed=min(base.max_speed, limiter.linear.max_velocity),
            max_turn_rate=min(base.max_turn_rate, limiter.angular.max_velocity))
        self.log.info(f"goal ({x:.2f}, {y:.2f}): going")
        try:
            pose = await self.robot.go_to(x, y, theta, timeout=120.0, settings=settings)
            self.log.info(f"goal reached: ({pose.x:.3f}, {pose.y:.3f})")
        except (GoalTimeout, RobotStopped) as exc:
            self.log.warning(f"goal abandoned: {exc}")
        except FpgalinkError as exc:
            self.log.error(f"goal failed: {exc}")

    def _cancel_goal(self) -> None:
        if self._goal is not None and not self._goal.done():
            self._goal.cancel()
        self._goal = None

    # --- running --------------------------------------------------------------------------

    async def run(self) -> None:
        """Publish and supervise until cancelled (again after each cancel: a managed node
        is activated, deactivated and activated again)."""
        # A new run's own tasks and listeners only: the last run's were cancelled and
        # removed in its finally (gathering them again would end this run at once).
        self._removers = [self.robot.on_notice(self._on_notice)]
        # A set of samples (one per board) goes out as soon as it is complete, never
        # faster than joint_state_rate.
        self._sets = self.robot.sample_sets(self.params.publish_period, self._ros_time)
        self._tasks = [asyncio.ensure_future(self._follow(self._sets)),
                       asyncio.ensure_future(self._diagnostics_loop()),
                       asyncio.ensure_future(self._supervision_log())]
        if self.imu_pub is not None:
            self._tasks.append(asyncio.ensure_future(self._imu_loop()))
        try:
            await asyncio.gather(*self._tasks)
        finally:
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            for remove in self._removers:
                remove()
            self._sets.close()
            self._sets = None
            self._cancel_goal()

    def _ros_time(self, received: float) -> int:
        """When a sample arrived (the loop's clock) on the ROS clock, ns; 0 while the ROS
        clock has no time (use_sim_time before the first /clock)."""
        now = self.node.get_clock().now().nanoseconds
        return 0 if now == 0 else now - round((self.loop.time() - received) * 1e9)

    def _on_notice(self, notice: BoardNotice | CommandNotice) -> None:
        if isinstance(notice, CommandNotice):
            if notice.command is not None:
                self._publish_driven(notice.command, None)
            if notice.fault:
                self.log.warning(notice.text)
        elif notice.fault:
            self.log.error(notice.describe())
            self._publish_diagnostics()  # now, not at the next second
        elif notice.kind != "closed":
            self.log.info(notice.describe())

    async def _follow(self, sets: SetFeed) -> None:
        async for stamped in sets:
            if self.clock_pub is not None:
                # One tick per set: the emulated time the samples were taken in, at
                # joint_state_rate; use_sim_time nodes (this one too) run on it.
                self._publish_clock()
            if stamped.clocked:  # else use_sim_time before the first /clock: no time yet
                self._publish_set(stamped)

    def _publish_set(self, stamped: StampedSet) -> None:
        """joint_states stamped with the first board's sample time on the ROS clock; odom
        (and /tf, truth) with the odometry the set completed, at its own stamp; what a ramp
        drove meanwhile on cmd_vel_out, each at its step."""
        states = self.robot.joint_states(stamped.samples)
        if states is None:
            return
        self._set_stamps = dict(stamped.stamps)
        self.joint_pub.publish(messages.joint_state_message(
            states, self.params.joint_names, stamped.stamp))
        self.published["joint_states"] += 1
        odom = messages.odometry_message(
            stamped.odometry, stamped.odometry_stamp,
            self.frame(str(self.params["odom_frame"])),
            self.frame(str(self.params["base_frame"])),
            self.params["pose_covariance_diagonal"], self.params["twist_covariance_diagonal"])
        self.odom_pub.publish(odom)
        self.published["odom"] += 1
        if self.tf_pub is not None and self.tf_type is not None \
                and self.params["publish_odom_tf"]:
            self.tf_pub.publish(self.tf_type(transforms=[messages.transform_of(odom)]))
            self.published["tf"] += 1
        truth = self.robot.truth()
        if truth is not None and self.truth_pub is not None:
            self.truth_pub.publish(messages.truth_message(truth, odom))
        for stamp_ns, command in stamped.driven:
            self._publish_driven(command, stamp_ns)

    def _publish_driven(self, command: Any, stamp_ns: int | None) -> None:
        """What the wheels were asked, after the limits (diff_drive_controller's
        publish_limited_velocity), stamped now or at its control step's samples."""
        if self.cmd_vel_out_pub is not None:
            stamp = self.node.get_clock().now().to_msg() if stamp_ns is None \
                else messages.time_msg(stamp_ns)
            self.cmd_vel_out_pub.publish(messages.limited_velocity_message(
                command, stamp, self.frame(str(self.params["base_frame"]))))

    def _publish_clock(self) -> None:
        truth = self.robot.truth()
        if truth is None or self.clock_pub is None:
            return
        self.clock_pub.publish(messages.clock_message(float(truth["t"])))
        self.published["clock"] += 1

    async def _supervision_log(self) -> None:
        async for event in self.robot.events():
            if event.recovered:
                self.log.info(event.describe())
            elif event.reason is None:
                self.log.info("robot enabled")
            elif event.reason is StopReason.REQUESTED:
                self.log.info("robot disabled")
            else:
                self.log.warning(f"robot {event.describe()}")
            self._publish_diagnostics()  # a change of state is said at once

    async def _imu_loop(self) -> None:
        """sensor_msgs/Imu at :data:`IMU_RATE_HZ` from the emulated body's IMU."""
        period = 1.0 / IMU_RATE_HZ
        due = self.loop.time()
        while True:
            # On a schedule, not a sleep after each message (which drifts by the time each
            # takes); a schedule missed by a whole period is taken up from now, not in a burst.
            due += period
            if due < self.loop.time() - period:
                due = self.loop.time()
            await asyncio.sleep(max(0.0, due - self.loop.time()))
            truth = self.robot.truth()
            reading = truth.get("imu") if truth is not None else None
            if reading is None or self.imu_pub is None:
                continue
            self.imu_pub.publish(messages.imu_message(
                reading, self.frame(IMU_FRAME), self.node.get_clock().now().to_msg()))
            self.published["imu"] += 1

    async def _diagnostics_loop(self) -> None:
        while True:
            await asyncio.sleep(DIAGNOSTICS_PERIOD_S)
            self._publish_diagnostics()
            self.graph.check()

    def _publish_diagnostics(self) -> None:
        self.diag_pub.publish(self.diagnostics(self.loop.time()))
        self.published["diagnostics"] += 1

    def diagnostics(self, now: float) -> DiagnosticArray:
        array = DiagnosticArray()
        ros_now = self.node.get_clock().now()
        array.header.stamp = ros_now.to_msg()
        array.status = [messages.diagnostic_status(
            self._with_sample_age(status, ros_now.nanoseconds), self.node.get_name())
            for status in self.robot.health(now)]
        return array

    def _with_sample_age(self, status: Status, now_ns: int) -> Status:
        """A board's status with how old, on the ROS clock, the board time of its sample in
        the last published set is: what joint_states and odom lag the boards by. A loaded
        node falls behind the telemetry long before the telemetry counts as stopped (50
        periods without a sample), and this says so; empty before the first set."""
        board = status.name.removeprefix("board ")
        if not status.name.startswith("board ") or board not in self.robot.description.boards:
            return status
        stamp = self._set_stamps.get(board)
        age = "" if stamp is None else f"{(now_ns - stamp) / 1e6:.1f} ms"
        return dataclasses.replace(status, values=(*status.values, ("latest sample age", age)))


class _GraphChecks:
    """What the node learns from the ROS graph and says once: a publisher of the other
    Twist type on ``cmd_vel`` (``ours`` is the type the node takes), another node of its
    name."""

    def __init__(self, node: Node, topic: str, ours: str) -> None:
        self.node, self.topic, self.ours = node, topic, ours
        self._wrong_cmd_vel_types: set[str] = set()
        self._unnamed_checks: dict[str, int] = {}
        self._clash_said = False

    def check(self) -> None:
        self._cmd_vel_publishers()
        self._name_clash()

    def _name_clash(self) -> None:
        """Another node of this name in this namespace: its parameters, services and
        diagnostics would be mistaken for this one's. Said once."""
        if self._clash_said:
            return
        me = (self.node.get_name(), self.node.get_namespace())
        if self.node.get_node_names_and_namespaces().count(me) > 1:
            self._clash_said = True
            self.node.get_logger().warning(
                f"another node is named {me[1].rstrip('/')}/{me[0]}: its parameters, "
                "services and diagnostics will be mistaken for this one's (rename one: "
                "-r __node:=NAME)")

    def _cmd_vel_publishers(self) -> None:
        """A publisher of the other Twist type on cmd_vel never matches this subscription:
        its commands would vanish without a word. Said once per type."""
        ours, topic = self.ours, self.topic
        for info in self.node.get_publishers_info_by_topic(topic):
            kind = info.topic_type
            if kind == ours or kind in self._wrong_cmd_vel_types:
                continue
            unknown = info.node_name.startswith("_NODE_NAME_UNKNOWN")
            if unknown and self._unnamed_checks.get(kind, 0) < 3:
                # Discovery gives the endpoint before its node's name: a moment more.
                self._unnamed_checks[kind] = self._unnamed_checks.get(kind, 0) + 1
                continue
            who = ("a publisher (no ROS node name)" if unknown
                   else f"{info.node_namespace.rstrip('/')}/{info.node_name}")
            self._wrong_cmd_vel_types.add(kind)
            self.node.get_logger().error(
                f"{topic}: {who} publishes {kind}, this node takes {ours}: those commands "
                f"do not arrive (set "
                f"use_stamped_vel:={'false' if ours.endswith('Stamped') else 'true'})")


class _RecordedPublisher:
    """A publisher whose messages also go into the bag (``--bag``)."""

    def __init__(self, publisher: Any, record: Callable[[str, Any], None]) -> None:
        self._publisher = publisher
        self._record = record

    def publish(self, message: Any) -> None:
        self._publisher.publish(message)
        self._record(self._publisher.topic_name, message)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._publisher, name)


def _tf_message_type() -> Any:
    """tf2_msgs/msg/TFMessage, or ``None`` where tf2_msgs is not installed (ROS 2 Jazzy has
    no PyPI wheel of it: ``fpgalink-ros2 --install-tf2`` builds it from the rosidl wheels)."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage
