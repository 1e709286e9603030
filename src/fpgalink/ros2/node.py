"""The robot on ROS 2: one node, ``fpgalink``, over a started :class:`~fpgalink.robot.Robot`.

Threads: asyncio owns the main thread (the boards' links, the robot, the publishing loops);
rclpy's executor spins in one background thread. A subscription's callback hands its
message to the asyncio loop (``call_soon_threadsafe``); publishers are called from the
loop. Parameter sets are coroutines the executor awaits while the asyncio loop talks to
the board, so a set reports success only after the board's echo matched.

Topics (relative names, so ``--ros-args -r __ns:=/robot`` and remaps work): see
docs/ros2.md. ROS parameters: the node's own (``joint_state_rate``, ``cmd_vel_timeout``,
``goal_tolerance``, ``odom_frame``, ``base_frame``, ``telemetry_timeout_periods``,
``require_enable``, ``enable_timeout``, ``use_stamped_vel``, ``publish_odom_tf``,
``joint_states_best_effort``, the kinematics and limits under diff_drive_controller's
names, ``robot_description``, ``publish_static_tf``, ``publish_clock``, …: the table in
docs/ros2.md) and every board parameter as
``BOARD.NAME`` or ``BOARD.NAME.CHANNEL`` (``L.TsTimerPeriod``, ``L.Kp_Wheel_Pid.A``).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import difflib
import functools
import math
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any

import rclpy
import rclpy.task
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TransformStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_service import ParameterService
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_parameters,
    qos_profile_sensor_data,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, String

from fpgalink.boardclock import BOARD_CLOCK_WRAP_US, BoardClock
from fpgalink.errors import FpgalinkError, ParameterError, ParameterRefused, ValueMismatch
from fpgalink.events import (
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    Closed,
    PortLost,
    StatusEvent,
    TelemetryStale,
    WatchdogLapsed,
    WireCrcMismatch,
)
from fpgalink.protocol import PARAMETERS, Param, ParamType, Telemetry
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B, Scope, channel_name
from fpgalink.protocol.urdf import FixedJoint, fixed_joints, robot_urdf
from fpgalink.robot import GoalTimeout, Robot, RobotStopped
from fpgalink.robot.health import Status
from fpgalink.robot.joints import SampleSets
from fpgalink.robot.limits import LIMIT_SIGNS, AxisLimits, SpeedLimiter, check_limit
from fpgalink.robot.supervision import State, StopReason
from fpgalink.ros2.bag import NodeBag

__all__ = ["NODE_NAME", "BadOverride", "RosBridge", "board_parameter_name", "spin_in_thread"]

NODE_NAME = "fpgalink"
DIAGNOSTICS_PERIOD_S = 1.0
#: Twist/JointState references older than this bring the wheels to rest (a parameter).
DEFAULT_CMD_TIMEOUT_S = 0.5
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
COVARIANCES = ("pose_covariance_diagonal", "twist_covariance_diagonal")
#: diff_drive_controller's limited axes, and the limits each has beside max_velocity (NaN:
#: not set; fpgalink.robot.limits says how the unset ones follow from the others).
AXES = {"linear.x": "m", "angular.z": "rad"}
LIMITS = {
    "min_velocity": "the lowest velocity, ≤ 0, {u}/s (NaN: −max_velocity); a command "
                    "beyond it is scaled keeping its curvature",
    "max_acceleration": "> 0, {u}/s²: speeding up in the positive direction (NaN: no "
                        "acceleration limit at all, whatever else is set)",
    "max_deceleration": "< 0, {u}/s²: slowing down while positive (NaN: "
                        "max_acceleration_reverse)",
    "max_acceleration_reverse": "< 0, {u}/s²: speeding up in the negative direction (NaN: "
                                "−max_acceleration)",
    "max_deceleration_reverse": "> 0, {u}/s²: slowing down while negative (NaN: "
                                "max_acceleration)",
    "min_acceleration": "< 0, {u}/s², Jazzy before 4.18 (later deprecated): the lowest "
                        "acceleration either way (NaN: not set)",
    "max_jerk": "> 0, {u}/s³ (NaN: no jerk limit)",
    "min_jerk": "< 0, {u}/s³ (NaN: −max_jerk)",
}
LIMIT_GROUPS = ("velocity", "acceleration", "jerk")
#: The longest control step the limiter takes (s): a stalled node (or a board clock that
#: started again) would otherwise make its whole stall one step.
MAX_CONTROL_STEP_S = 0.1


class BadOverride(Exception):
    """A board parameter's ``--ros-args -p`` value that the board (or the host's check of
    its range) does not take: a usage error."""


def board_parameter_name(board: str, param: Param, channel: int) -> str:
    """``L.TsTimerPeriod``, ``L.Kp_Wheel_Pid.A``."""
    if param.scope is Scope.BOARD:
        return f"{board}.{param.name}"
    return f"{board}.{param.name}.{channel_name(channel)}"


def _descriptor(param: Param, board: str) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(
        description=f"board {board}: {param.description}"
        + (f" ({param.unit})" if param.unit else ""),
        additional_constraints=f"{param.range_text}; confirmed by the board's echo",
    )
    if param.type is ParamType.INT:
        descriptor.type = ParameterType.PARAMETER_INTEGER
        if param.allowed is None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(param.minimum), to_value=int(param.maximum), step=1)]
    else:
        descriptor.type = ParameterType.PARAMETER_DOUBLE
        if math.isfinite(param.maximum):
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(param.minimum), to_value=float(param.maximum), step=0.0)]
    return descriptor


def _time_msg(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


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


def _rclpy_future(future: concurrent.futures.Future[Any],
                  executor: Any) -> rclpy.task.Future:
    """An rclpy future completed by ``future`` (from another thread), for ``await`` in an
    executor coroutine. The no-op done callback makes a completion wake the executor."""
    result = rclpy.task.Future(executor=executor)
    result.add_done_callback(lambda _done: None)

    def done(origin: concurrent.futures.Future[Any]) -> None:
        error = origin.exception()
        if error is not None:
            result.set_exception(error)
        else:
            result.set_result(origin.result())

    future.add_done_callback(done)
    return result


class _BoardParameterService(ParameterService):
    """rclpy's six parameter services, with ``set_parameters`` a coroutine that sets a
    board parameter on the board first and reports success only when the echo matched.
    All in a reentrant group, so reading parameters does not wait behind a pending set."""

    def __init__(self, node: Node, bridge: RosBridge) -> None:
        from rcl_interfaces.srv import (
            DescribeParameters,
            GetParameters,
            GetParameterTypes,
            ListParameters,
            SetParameters,
            SetParametersAtomically,
        )

        self._node_weak_ref = weakref.ref(node)
        self._bridge = bridge
        group = ReentrantCallbackGroup()
        for kind, suffix, callback in (
            (DescribeParameters, "describe_parameters", self._describe_parameters_callback),
            (GetParameters, "get_parameters", self._get_parameters_callback),
            (GetParameterTypes, "get_parameter_types", self._get_parameter_types_callback),
            (ListParameters, "list_parameters", self._list_parameters_callback),
            (SetParameters, "set_parameters", self._set_parameters_callback),
            (SetParametersAtomically, "set_parameters_atomically",
             self._set_parameters_atomically_callback),
        ):
            node.create_service(kind, f"{node.get_name()}/{suffix}", callback,
                                qos_profile=qos_profile_parameters, callback_group=group)

    async def _set_parameters_callback(self, request: Any, response: Any) -> Any:
        for message in request.parameters:
            try:  # an exception escaping here would stop the executor's thread
                parameter = Parameter.from_parameter_msg(message)
                result = await self._bridge.set_parameter(parameter)
            except Exception as exc:  # reported to the caller, never raised
                result = SetParametersResult(successful=False, reason=f"internal error: {exc}")
            response.results.append(result)
        return response

    def _set_parameters_atomically_callback(self, request: Any, response: Any) -> Any:
        response.result = SetParametersResult(
            successful=False, reason="set board parameters one at a time (set_parameters): "
            "each is confirmed by its board")
        return response


class RosBridge:
    """The node and what it does. Build it on the asyncio loop after the robot started,
    then ``await bridge.run()`` until cancelled."""

    def __init__(self, robot: Robot, node: Node, loop: asyncio.AbstractEventLoop,
                 executor: Any = None, bag: NodeBag | None = None,
                 managed: bool = False) -> None:
        self.robot = robot
        self.bag = bag
        #: a managed node (``--lifecycle``) publishes and takes commands only while active
        self.active = not managed
        self.node = node
        self.loop = loop
        self.executor = executor
        self.log = node.get_logger()
        self._board_params: dict[str, tuple[str, Param, int]] = {}
        self._clocks = {board: BoardClock() for board in robot.description.boards}
        self._last_odom_ns = 0
        self._set_stamps: dict[str, int] = {}  #: each board's stamp of the last set
        self._last_command_at: float | None = None
        self._command_is_zero = True
        #: a command that came while the robot was not enabled (the enable on its own
        #: topic may come after it): sent when the robot is enabled, if still fresh
        self._pending: tuple[Callable[[], object], bool, float] | None = None
        #: warnings by kind: when one was last printed, and how many since were not
        self._warned: dict[str, tuple[float, int]] = {}
        self._wrong_cmd_vel_types: set[str] = set()
        self._unnamed_checks: dict[str, int] = {}
        self._name_clash_said = False
        self._goal: asyncio.Task[None] | None = None
        #: diff_drive_controller's acceleration and jerk limits on cmd_vel: the command the
        #: limiter leads the robot to, one control step (a set of samples) at a time, and
        #: what the robot drove and why it last stopped when that began (either changed:
        #: another command or a stop took over)
        self._limiter = SpeedLimiter()
        self._ramp: tuple[float, float] | None = None
        self._ramp_owner: object = None
        self._ramp_stop: object = None
        self._wheel_refs_drove = False  #: since the last ramp began
        self._step_t_us: int | None = None  #: the first board's sample time at the last step
        self._file_limits = (robot.description.max_linear_speed,
                             robot.description.max_angular_speed_rad)
        self._said: set[str] = set()  #: warnings given once
        self._tasks: list[asyncio.Task[Any]] = []
        self._removers: list[Callable[[], None]] = []
        self.published = {"joint_states": 0, "odom": 0, "diagnostics": 0, "tf": 0}
        # Before declaring: rclpy runs this on each declared value (a -p too) and on sets.
        node.add_on_set_parameters_callback(self._check_parameters)
        self._declare_node_parameters()
        self._read_node_parameters()
        self._joint_names = self._declare_wheel_names()
        self._prefix = self._frame_prefix()
        self.urdf = self._declare_robot_description()
        self._sets = SampleSets(robot.description.boards, self._publish_period)
        # Reliable as joint_state_broadcaster's (robot_state_publisher and most consumers
        # subscribe reliable, which never matches a best-effort publisher); sensor-data QoS
        # on request.
        joint_qos: QoSProfile = (qos_profile_sensor_data if self._value("joint_states_best_effort")
                                 else QoSProfile(depth=10,
                                                 reliability=ReliabilityPolicy.RELIABLE))
        self.joint_pub = self._publisher(JointState, "joint_states", joint_qos)
        self.odom_pub = self._publisher(Odometry, "odom", 10)
        # Absolute, as diagnostic_updater publishes it (one /diagnostics for the whole
        # graph, the statuses named after the node).
        self.diag_pub = self._publisher(DiagnosticArray, "/diagnostics", 10)
        self.truth_pub = (self._publisher(Odometry, "truth", 10)
                          if robot.truth() is not None else None)
        self.tf_type = _tf_message_type()
        # /tf as tf2_ros's broadcaster publishes it (absolute, reliable, depth 100).
        self.tf_pub = None if self.tf_type is None else self._publisher(
            self.tf_type, "/tf", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        if self.tf_type is None and self._value("publish_odom_tf"):
            self.log.warning("publish_odom_tf: tf2_msgs is not installed (Jazzy has no wheel "
                             "of it; `make tf2-msgs` generates it): running without /tf "
                             "and /tf_static")
        self.description_pub = self._publisher(String, "robot_description", LATCHED)
        self.tf_static_pub = None
        if self.tf_type is not None and node.get_parameter("publish_static_tf").value:
            self.tf_static_pub = self._publisher(self.tf_type, "/tf_static", LATCHED)
        if not managed:
            self.publish_latched()
        self.clock_pub = self._clock_publisher()
        self.cmd_vel_out_pub = (
            self._publisher(TwistStamped, "cmd_vel_out", 10)
            if node.get_parameter("publish_limited_velocity").value else None)
        stamped = bool(self._value("use_stamped_vel"))
        self.cmd_vel_sub = node.create_subscription(
            TwistStamped if stamped else Twist, "cmd_vel",
            self._threadsafe(self._on_cmd_vel, "cmd_vel"), 10)
        self.imu_pub = self._imu_publisher()
        node.create_subscription(JointState, "wheel_refs",
                                 self._threadsafe(self._on_wheel_refs, "wheel_refs"), 10)
        node.create_subscription(PoseStamped, "goal_pose",
                                 self._threadsafe(self._on_goal, "goal_pose"), 10)
        node.create_subscription(Bool, "enable", self._threadsafe(self._on_enable, "enable"), 10)

    # --- parameters -----------------------------------------------------------------------

    def serve_parameters(self) -> None:
        """Answer the parameter services (the node was made with
        ``start_parameter_services=False``), board parameters confirmed by the board."""
        _BoardParameterService(self.node, self)

    def _declare_node_parameters(self) -> None:
        node = self.node

        def double(name: str, default: float, low: float, high: float, text: str) -> None:
            node.declare_parameter(name, default, ParameterDescriptor(
                type=ParameterType.PARAMETER_DOUBLE, description=text,
                floating_point_range=[FloatingPointRange(from_value=low, to_value=high,
                                                         step=0.0)]))

        double("joint_state_rate", 100.0, 1.0, 1000.0,
               "joint_states and odom per second, Hz (at most the telemetry rate)")
        double("cmd_vel_timeout", DEFAULT_CMD_TIMEOUT_S, 0.05, 10.0,
               "a cmd_vel or wheel_refs older than this brings the wheels to rest, s")
        double("goal_tolerance", 0.05, 0.005, 10.0, "goal_pose reached within this, m")
        node.declare_parameter("telemetry_timeout_periods", 50, ParameterDescriptor(
            type=ParameterType.PARAMETER_INTEGER,
            description="a board's telemetry missing for this many timer periods is a fault: "
                        "the robot stops until it comes again (50: 50 ms at 1 kHz)",
            integer_range=[IntegerRange(from_value=2, to_value=100_000, step=1)]))
        model = self.robot.kinematics
        double("wheel_radius", model.wheel_radius, 0.005, 5.0,
               "wheel radius, m (default: the robot file's)")
        double("wheel_separation", model.track, 0.05, 20.0,
               "between the left and right wheels' centres, m (default: the robot file's)")
        double("wheel_separation_multiplier", model.chi, 1.0, 20.0,
               "the skid-steer factor χ: the effective track is χ × wheel_separation; it "
               "differs per surface (default: the robot file's for its surface)")
        for side in ("left", "right"):
            double(f"{side}_wheel_radius_multiplier", 1.0, 0.5, 2.0,
                   f"the {side} wheels' rolling radius over wheel_radius (worn or "
                   "differently inflated wheels): drive and odometry use it")
        double("enable_timeout", DEFAULT_CMD_TIMEOUT_S, 0.05, 10.0,
               "with require_enable: true on enable at least this often keeps the robot "
               "enabled (the seed's /globalEnable deadman), s")
        node.declare_parameter("require_enable", True, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL,
            description="true: the robot drives only while true arrives on enable (the "
                        "deadman); false: cmd_vel enables it, cmd_vel_timeout brings the "
                        "wheels to rest (as diff_drive_controller)"))
        node.declare_parameter("joint_states_best_effort", False, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="joint_states with sensor-data QoS (best effort) instead of reliable"))
        node.declare_parameter("publish_odom_tf", True, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL,
            description="publish odom_frame -> base_frame on /tf with each odom"))
        node.declare_parameter("use_stamped_vel", False, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="cmd_vel is geometry_msgs/TwistStamped (true, diff_drive_controller's "
                        "Jazzy default) or Twist (false, Nav2's and teleop's default)"))
        for name, default in (("odom_frame", "odom"), ("base_frame", "base_link")):
            node.declare_parameter(name, default, ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING, description=f"frame id: {name}"))
        node.declare_parameter("tf_frame_prefix_enable", True, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="prefix every frame id this node publishes (as diff_drive_controller)"))
        node.declare_parameter("tf_frame_prefix", "", ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True,
            description="the prefix; empty: the node's namespace (/bot: bot/odom)"))
        node.declare_parameter("publish_static_tf", True, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="the URDF's fixed joints on /tf_static, as robot_state_publisher "
                        "(false where one runs)"))
        node.declare_parameter("publish_limited_velocity", False, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="publish each cmd_vel as driven, after the limits, on cmd_vel_out"))
        node.declare_parameter("pose_covariance_diagonal", Parameter.Type.DOUBLE_ARRAY,
                               ParameterDescriptor(
            description="odom's pose covariance diagonal (x, y, z, roll, pitch, yaw); unset: "
                        "computed from the odometry's motion model"))
        node.declare_parameter("twist_covariance_diagonal", [0.0] * 6, ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE_ARRAY,
            description="odom's twist covariance diagonal (vx, vy, vz, wx, wy, wz)"))
        description = self.robot.description
        double("linear.x.max_velocity", description.max_linear_speed, 0.001,
               description.max_linear_speed,
               "the robot's speed limit, m/s, at most the robot file's; a command beyond a "
               "limit is scaled keeping its curvature")
        double("angular.z.max_velocity", description.max_angular_speed_rad, 0.001,
               description.max_angular_speed_rad,
               "the robot's turn rate limit, rad/s, at most the robot file's")
        for axis, unit in AXES.items():
            for group in LIMIT_GROUPS:
                node.declare_parameter(f"{axis}.has_{group}_limits", True, ParameterDescriptor(
                    type=ParameterType.PARAMETER_BOOL,
                    description=f"deprecated in Jazzy (set the limits to NaN instead): false "
                                f"ignores {axis}'s {group} limits" + (
                                    " (max_velocity is then the robot file's)"
                                    if group == "velocity" else "")))
            for name, text in LIMITS.items():
                # No floating_point_range: NaN (not set) is outside any; _check_parameters.
                node.declare_parameter(f"{axis}.{name}", math.nan, ParameterDescriptor(
                    type=ParameterType.PARAMETER_DOUBLE, description=text.format(u=unit),
                    additional_constraints="a finite number of its sign, or NaN: not set "
                                           "(diff_drive_controller's defaults, docs/ros2.md)"))

    def _value(self, name: str) -> Any:
        return self._node_values[name]

    def _parameter_value(self, name: str) -> Any:
        """Its value; ``None`` for one declared by type and not given (unset: computed)."""
        try:
            return self.node.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """What a descriptor cannot say: six finite covariances ≥ 0; a limit of its sign,
        or NaN."""
        for parameter in parameters:
            axis, _, limit = parameter.name.rpartition(".")
            value = parameter.value
            if axis in AXES and limit in LIMIT_SIGNS and limit != "max_velocity" \
                    and isinstance(value, float):
                reason = check_limit(limit, value)
                if reason is not None:
                    return SetParametersResult(successful=False, reason=f"{axis}.{reason}")
            if parameter.name in COVARIANCES and parameter.value is not None:
                values = list(parameter.value)
                if len(values) != 6 or not all(math.isfinite(v) and v >= 0 for v in values):
                    return SetParametersResult(successful=False, reason=(
                        f"{parameter.name} takes six finite numbers ≥ 0 (x, y, z, roll, "
                        f"pitch, yaw), got {values}"))
        return SetParametersResult(successful=True)

    def _declare_wheel_names(self) -> dict[str, str]:
        """``left_wheel_names``/``right_wheel_names`` (read-only, as diff_drive_controller
        takes them): the description's wheel → the name joint_states, wheel_refs and the
        URDF give it."""
        wheels = self.robot.description.wheels
        names: dict[str, str] = {}
        for side, left in (("left", True), ("right", False)):
            ours = [w.name for w in wheels if w.left is left]
            name = f"{side}_wheel_names"
            given = self.node.declare_parameter(name, ours, ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
                description=f"the {side} wheels' joint names, front to back (default: the "
                            "robot file's)")).value
            if len(given) != len(ours) or not all(str(g).strip() for g in given):
                raise BadOverride(f"{name}: {len(ours)} non-empty names, front to back "
                                  f"(the robot's {', '.join(ours)}), got {list(given)}")
            names.update(zip(ours, (str(g) for g in given), strict=True))
        if len(set(names.values())) != len(names):
            raise BadOverride(f"left_wheel_names, right_wheel_names: each wheel a name of "
                              f"its own, got {list(names.values())}")
        return names

    def _frame_prefix(self) -> str:
        """diff_drive_controller's rule: the given prefix, else the namespace; never a
        leading ``/``, always a trailing one (``/bot`` → ``bot/``, ``/`` → none)."""
        if not self.node.get_parameter("tf_frame_prefix_enable").value:
            return ""
        prefix = str(self.node.get_parameter("tf_frame_prefix").value) \
            or self.node.get_namespace()
        if not prefix.endswith("/"):
            prefix += "/"
        return prefix.lstrip("/")

    def frame(self, name: str) -> str:
        return self._prefix + name

    def _declare_robot_description(self) -> str:
        """The robot's URDF (its wheels under this node's joint names), or one given with
        ``-p robot_description:=…``: a read-only parameter and the latched topic, as
        robot_state_publisher has it."""
        urdf = robot_urdf(self.robot.description, self._joint_names)
        given = str(self.node.declare_parameter("robot_description", urdf, ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True,
            description="the robot's URDF (default: generated from the robot file, its "
                        "wheels' joints named as in joint_states)")).value)
        try:
            self._fixed_joints: list[FixedJoint] = fixed_joints(given)
        except ValueError as exc:
            raise BadOverride(f"robot_description: {exc}") from None
        return given

    def publish_latched(self) -> None:
        """robot_description and /tf_static, once (a managed node's when it is activated)."""
        self.description_pub.publish(String(data=self.urdf))
        if self.tf_static_pub is not None:
            self.tf_static_pub.publish(self._static_transforms())

    def _clock_publisher(self) -> Any:
        """``/clock`` from the emulated robot's own time (``publish_clock``, only where the
        robot is emulated in this process: a real robot has no time but the host's)."""
        emulated = self.robot.truth() is not None
        wanted = bool(self.node.declare_parameter("publish_clock", emulated, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True,
            description="publish /clock from the emulated robot's time (default: true for "
                        "the emulated robot in this process; refused for real ports)")).value)
        if wanted and not emulated:
            raise BadOverride("publish_clock: only the emulated robot in this process has a "
                              "time of its own (no --port)")
        if not wanted:
            return None
        self.published["clock"] = 0
        return self.node.create_publisher(Clock, "/clock", QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE))

    def _publish_clock(self) -> None:
        truth = self.robot.truth()
        if truth is None or self.clock_pub is None:
            return
        self.clock_pub.publish(Clock(clock=_time_msg(round(float(truth["t"]) * 1e9))))
        self.published["clock"] += 1

    def _static_transforms(self) -> Any:
        """The URDF's fixed joints, as robot_state_publisher puts them on /tf_static."""
        assert self.tf_type is not None
        stamp = self.node.get_clock().now().to_msg()
        transforms = []
        for joint in self._fixed_joints:
            transform = TransformStamped()
            transform.header.stamp = stamp
            transform.header.frame_id = self.frame(joint.parent)
            transform.child_frame_id = self.frame(joint.child)
            (transform.transform.translation.x, transform.transform.translation.y,
             transform.transform.translation.z) = joint.xyz
            q = transform.transform.rotation
            q.x, q.y, q.z, q.w = _quaternion(*joint.rpy)
            transforms.append(transform)
        return self.tf_type(transforms=transforms)

    def _read_node_parameters(self) -> None:
        """Cache the node's own parameters (read per message at up to 1 kHz)."""
        self._node_values = {name: self._parameter_value(name) for name in (
            "joint_state_rate", "cmd_vel_timeout", "goal_tolerance", "odom_frame",
            "base_frame", "telemetry_timeout_periods", "enable_timeout", "require_enable",
            "use_stamped_vel", "publish_odom_tf", "joint_states_best_effort", "wheel_radius",
            "wheel_separation", "wheel_separation_multiplier", "pose_covariance_diagonal",
            "twist_covariance_diagonal", "linear.x.max_velocity", "angular.z.max_velocity",
            "left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
            *(f"{axis}.{name}" for axis in AXES for name in LIMITS),
            *(f"{axis}.has_{group}_limits" for axis in AXES for group in LIMIT_GROUPS))}
        values = self._node_values
        self._limiter.linear, self._limiter.angular = (
            self._axis_limits(axis, file_limit)
            for axis, file_limit in zip(AXES, self._file_limits, strict=True))
        limits = (self._limiter.linear.max_velocity,
                  math.degrees(self._limiter.angular.max_velocity))
        description = self.robot.description
        if limits != (description.max_linear_speed, description.max_angular_speed):
            # robot.drive reads them from its description on every command.
            self.robot.description = dataclasses.replace(
                description, max_linear_speed=limits[0], max_angular_speed=limits[1])
        model = self.robot.kinematics
        wanted = (float(values["wheel_radius"]), float(values["wheel_separation"]),
                  float(values["wheel_separation_multiplier"]),
                  float(values["left_wheel_radius_multiplier"]),
                  float(values["right_wheel_radius_multiplier"]))
        if wanted != (model.wheel_radius, model.track, model.chi, model.left_radius_multiplier,
                      model.right_radius_multiplier):
            # Drive and odometry with them from now on (ranges checked by the descriptors).
            self.robot.set_kinematics(wheel_radius=wanted[0], track=wanted[1], chi=wanted[2],
                                      left_radius_multiplier=wanted[3],
                                      right_radius_multiplier=wanted[4])
        self.robot.supervisor.deadman_s = float(self._node_values["enable_timeout"])
        self._publish_period = 1.0 / float(self._node_values["joint_state_rate"])
        for link in self.robot.links.values():
            link.connection.settings = dataclasses.replace(
                link.connection.settings,
                stale_periods=int(self._node_values["telemetry_timeout_periods"]))
        if hasattr(self, "_sets"):
            self._sets.min_period = self._publish_period

    def _axis_limits(self, axis: str, file_limit: float) -> AxisLimits:
        """An axis's limits from its parameters: ``max_velocity`` is always there (the
        robot file's without ``has_velocity_limits``); the ``has_*_limits`` of older
        configurations (deprecated in Jazzy) drop the others, as there, said once."""
        values = self._node_values
        wanted = {name: float(values[f"{axis}.{name}"]) for name in LIMITS}
        wanted["max_velocity"] = float(values[f"{axis}.max_velocity"])
        for group, names in (("velocity", ("min_velocity",)),
                             ("acceleration", ("max_acceleration", "max_deceleration",
                                               "max_acceleration_reverse",
                                               "max_deceleration_reverse",
                                               "min_acceleration")),
                             ("jerk", ("max_jerk", "min_jerk"))):
            if not values[f"{axis}.has_{group}_limits"]:
                self._say_once(f"{axis}.has_{group}_limits", f"{axis}.has_{group}_limits: "
                               "deprecated in Jazzy (set the limits to NaN instead): "
                               f"{axis}'s {group} limits ignored")
                wanted.update(dict.fromkeys(names, math.nan))
                if group == "velocity":
                    wanted["max_velocity"] = file_limit
        if not math.isnan(wanted["min_acceleration"]):
            self._say_once(f"{axis}.min_acceleration", f"{axis}.min_acceleration: Jazzy "
                           "before 4.18's name, deprecated there since: taken as the "
                           "default of max_deceleration and max_acceleration_reverse")
        unused = [name for name, needs in (
            ("max_deceleration", "max_acceleration"),
            ("max_acceleration_reverse", "max_acceleration"),
            ("max_deceleration_reverse", "max_acceleration"),
            ("min_acceleration", "max_acceleration"), ("min_jerk", "max_jerk"))
            if not math.isnan(wanted[name]) and math.isnan(wanted[needs])]
        for name in unused:
            self._say_once(f"{axis}.{name} unused", f"{axis}.{name}: no effect without "
                           f"{axis}.{'max_jerk' if 'jerk' in name else 'max_acceleration'} "
                           "(as in diff_drive_controller)")
        return AxisLimits(**wanted)

    def _say_once(self, key: str, text: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.log.warning(text)

    async def declare_board_parameters(self) -> None:
        """Every board parameter as a ROS parameter, its value read from the board; a value
        given with ``--ros-args -p`` is set on the board (and must be confirmed). Each is
        this node's configuration from then on: held by the board's link, set again if the
        board restarts, so a ROS parameter never silently differs from its board."""
        for board, link in self.robot.links.items():
            values = await link.read_params(hold=True)
            for param in PARAMETERS:
                channels = (0,) if param.scope is Scope.BOARD else (CHANNEL_A, CHANNEL_B)
                for channel in channels:
                    name = board_parameter_name(board, param, channel)
                    on_board = values[(param.id, channel)]
                    self._board_params[name] = (board, param, channel)
                    declared = self.node.declare_parameter(
                        name, on_board, _descriptor(param, board)).value
                    if declared != on_board:  # an override from the command line
                        try:
                            confirmed = await link.set_param(param.id, declared,
                                                             channel or None)
                        except (ParameterError, ParameterRefused, ValueMismatch) as exc:
                            # The value given is wrong (a board not answering is not).
                            raise BadOverride(f"{name}: {exc}") from None
                        self.node.set_parameters([Parameter(name, value=confirmed)])
        self._warn_unknown_overrides()

    def _warn_unknown_overrides(self) -> None:
        """A ``-p NAME:=VALUE`` for a parameter this node does not have is not silently
        ignored: one warning per name, with the nearest names it has."""
        overrides = getattr(self.node, "_parameter_overrides", {})  # rclpy keeps them here
        for name in sorted(set(overrides) - {p for p in self.node._parameters}):
            near = difflib.get_close_matches(name, list(self.node._parameters), n=3)
            self.log.warning(f"-p {name}: this node has no such parameter: ignored"
                             + (f" (did you mean {', '.join(near)}?)" if near else ""))

    async def set_parameter(self, parameter: Parameter) -> SetParametersResult:
        """One parameter from a ``set_parameters`` call (on the executor's thread)."""
        name = parameter.name
        target = self._board_params.get(name)
        if target is None:
            if not self.node.has_parameter(name):
                return SetParametersResult(successful=False,
                                           reason=f"no parameter {name!r}")
            result = self.node.set_parameters([parameter])[0]
            self.loop.call_soon_threadsafe(self._read_node_parameters)
            return result
        board, param, channel = target
        value = parameter.value
        if param.name == "GetDataPeriodical" and value != 1:
            return SetParametersResult(successful=False, reason=(
                f"{name}: this node runs on the boards' telemetry; it stays 1"))
        if isinstance(value, bool) or not isinstance(value, int | float):
            return SetParametersResult(successful=False, reason=(
                f"{name} takes a {param.type.name.lower()} ({param.range_text}), "
                f"got {value!r}"))
        future = asyncio.run_coroutine_threadsafe(
            self._set_on_board(board, param, channel, value), self.loop)
        reason, confirmed = await _rclpy_future(future, self.executor)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
        committed = Parameter(name, value=confirmed if param.type is ParamType.INT
                              else float(confirmed))
        return self.node.set_parameters([committed])[0]

    async def _set_on_board(self, board: str, param: Param, channel: int,
                            value: int | float) -> tuple[str | None, int | float]:
        try:
            confirmed = await self.robot.links[board].set_param(param.id, value,
                                                                channel or None)
        except FpgalinkError as exc:
            return f"board {board}: {exc}", value
        return None, confirmed

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
        self._command(functools.partial(self._drive, v, omega), v == 0.0 and omega == 0.0)

    def _drive(self, v: float, omega: float) -> None:
        v, omega = self._limiter.target(v, omega)  # min_velocity, keeping the curvature
        if not self._limiter.rate_limited:
            self._ramp = None
            self._publish_driven(self.robot.drive(v, omega))
            return
        if self.robot.state is not State.ENABLED:
            stop = self.robot.supervisor.last_stop
            raise RobotStopped("the robot is not enabled" + (
                f" ({stop.describe()})" if stop else ""), stop)
        if self._ramp is None or not self._ramp_holds():
            # From what the robot drives now (another command may have driven it): its body
            # command, or after wheel_refs (no body command) the speeds measured.
            driven = self.robot.command
            if self._wheel_refs_drove:
                state = self.robot.odometry_state
                now = (state.v, state.omega)
            else:
                now = (driven.v, driven.omega) if driven is not None else (0.0, 0.0)
            self._wheel_refs_drove = False
            if now != self._limiter.last:
                self._limiter.reset(*now)
            self._ramp_owner, self._ramp_stop = driven, self.robot.supervisor.last_stop
        self._ramp = (v, omega)  # followed at each control step (_control_step)

    def _ramp_holds(self) -> bool:
        """Nothing took the robot over since the limiter last drove it: no other command,
        no stop."""
        return (self.robot.command is self._ramp_owner
                and self.robot.supervisor.last_stop is self._ramp_stop
                and self.robot.state is State.ENABLED)

    def _control_step(self, samples: dict[str, Telemetry], stamp_ns: int | None) -> None:
        """One step of the limiter towards the cmd_vel it follows, once per set of samples
        (at joint_state_rate, as diff_drive_controller steps at its controller manager's
        update_rate), its time step on the first board's clock (the time the stamps are
        on; the emulator's own for an emulated robot); what it drove said on cmd_vel_out
        stamped as the set's joint_states (``stamp_ns``)."""
        t_us = samples[self.robot.description.boards[0]].t_us
        last, self._step_t_us = self._step_t_us, t_us
        if self._ramp is None:
            self._limiter.reset(*self._limiter.last)  # held: no acceleration left over
            return
        if not self._ramp_holds():
            self._ramp = None  # a stop or another command: the next cmd_vel starts afresh
            return
        if last is None:
            return
        dt = min(((t_us - last) % BOARD_CLOCK_WRAP_US) / 1e6,
                 max(MAX_CONTROL_STEP_S, 1.5 * self._publish_period))
        before = self._limiter.last
        v, omega = self._limiter.step(*self._ramp, dt)
        if (v, omega) != before:  # else the boards have it already
            try:
                command = self.robot.drive(v, omega)
            except FpgalinkError as exc:
                self._ramp = None
                self._throttled_warning("ramp", f"command ignored: {exc}")
                return
            # The robot's own limits (its wheels' top speed) may have scaled it.
            self._limiter.follow(command.v, command.omega)
            self._ramp_owner = command
            self._publish_driven(command, stamp_ns)
        if self._ramp == self._limiter.last == (0.0, 0.0):
            self._ramp = None  # at rest: the next cmd_vel starts from here

    def _publish_driven(self, command: Any, stamp_ns: int | None = None) -> None:
        if self.cmd_vel_out_pub is not None:
            # What the wheels were asked, after the limits (diff_drive_controller's
            # publish_limited_velocity), stamped now or at its control step's samples.
            out = TwistStamped()
            out.header.stamp = self.node.get_clock().now().to_msg() if stamp_ns is None \
                else _time_msg(stamp_ns)
            out.header.frame_id = self.frame(str(self._value("base_frame")))
            out.twist.linear.x, out.twist.angular.z = command.v, command.omega
            self.cmd_vel_out_pub.publish(out)

    def _on_wheel_refs(self, message: JointState) -> None:
        names = list(message.name)
        values = list(message.velocity) or list(message.effort)
        torque = not message.velocity and bool(message.effort)
        if len(values) != len(names) or not names:
            self.log.warning("wheel_refs ignored: give one velocity (rad/s) or effort (N·m) "
                             "per named joint")
            return
        joints = tuple(self._joint_names.values())
        unknown = sorted(set(names) - set(joints))
        if unknown or not all(math.isfinite(v) for v in values):
            self.log.warning(f"wheel_refs ignored: joints {joints}, finite values "
                             f"(got {names}, {values})")
            return
        wanted = dict(zip(names, values, strict=True))
        description = self.robot.description
        references: dict[str, list[float]] = {b: [0.0, 0.0] for b in description.boards}
        for wheel in description.wheels:
            value = wanted.get(self._joint_names[wheel.name], 0.0) * wheel.forward
            references[wheel.board][wheel.channel - 1] = value if torque else \
                math.degrees(value)

        def send() -> None:
            if self.robot.state is not State.ENABLED:
                raise RobotStopped("the robot is not enabled")
            for board, (ref_a, ref_b) in references.items():
                self.robot.links[board].set_references(ref_a, ref_b)
            self._wheel_refs_drove = True

        self._cancel_goal()
        self._ramp = None
        self._command(send, all(v == 0.0 for v in values))

    def _command(self, send: Callable[[], object], zero: bool) -> None:
        if not self._value("require_enable") and self.robot.state is not State.ENABLED:
            # Without the deadman a command is the request to drive.
            try:
                self.robot.enable()
            except RobotStopped as exc:
                self._throttled_warning("refused", f"command ignored: {exc}")
                return
        try:
            send()
        except RobotStopped as exc:
            # The enable, on its own topic, may come just after the command it goes with:
            # held, and sent if the robot is enabled within cmd_vel_timeout.
            self._pending = (send, zero, self.loop.time())
            self._throttled_warning("not enabled", f"command held: {exc} (publish true on "
                                    f"enable within cmd_vel_timeout to send it)")
            return
        except FpgalinkError as exc:
            self.log.warning(f"command ignored: {exc}")
            return
        self._pending = None
        self._last_command_at = self.loop.time()
        self._command_is_zero = zero

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
            was = self.robot.state
            try:
                self.robot.enable()
            except RobotStopped as exc:
                self._throttled_warning("refused", f"enable refused: {exc}")
                return
            pending, self._pending = self._pending, None
            if (was is not State.ENABLED and pending is not None
                    and self.loop.time() - pending[2] <= float(self._value("cmd_vel_timeout"))):
                self._command(pending[0], pending[1])
        elif self.robot.state is State.ENABLED:
            self._pending = None
            self.robot.disable()

    def _on_goal(self, message: PoseStamped) -> None:
        frame = self.frame(str(self._value("odom_frame")))
        if message.header.frame_id and message.header.frame_id != frame:
            self.log.warning(f"goal_pose in frame {message.header.frame_id!r} taken as "
                             f"{frame!r} (this node knows only its odometry)")
        p, q = message.pose.position, message.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        has_heading = not (q.x == q.y == q.z == 0.0 and q.w in (0.0, 1.0))
        self._cancel_goal()
        self._ramp = None
        self._goal = asyncio.ensure_future(self._go_to(p.x, p.y, yaw if has_heading else None))

    async def _go_to(self, x: float, y: float, theta: float | None) -> None:
        base = self.robot.goto_settings
        settings = dataclasses.replace(
            base, position_tolerance=float(self._value("goal_tolerance")),
            max_speed=min(base.max_speed, self._limiter.linear.max_velocity),
            max_turn_rate=min(base.max_turn_rate, self._limiter.angular.max_velocity))
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
        self._tasks, self._removers = [], []
        for board, link in self.robot.links.items():
            self._removers.append(link.on_event(functools.partial(self._log_link_event, board)))
            self._tasks.append(asyncio.ensure_future(self._follow(board, link)))
        self._tasks += [asyncio.ensure_future(self._diagnostics_loop()),
                        asyncio.ensure_future(self._command_watchdog()),
                        asyncio.ensure_future(self._enable_keeper()),
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
            self._cancel_goal()
            self._ramp = None

    def _log_link_event(self, board: str, event: StatusEvent) -> None:
        detail = event.describe()
        text = f"board {board}: {event.name.replace('_', ' ')}" + (
            f" ({detail})" if detail else "")
        if isinstance(event, BoardRestarted):
            # Its clock starts again: the mapping starts afresh (not a wrap, not a jump
            # back), the drift estimate kept.
            self._clocks[board].restart()
        if isinstance(event, _FAULTS) or (isinstance(event, BoardResynced)
                                          and "failed" in detail):
            self.log.error(text)
            self._publish_diagnostics()  # now, not at the next second
        elif not isinstance(event, Closed):
            self.log.info(text)

    async def _follow(self, board: str, link: Any) -> None:
        # A set of samples (one per board) goes out as soon as it is complete, never
        # faster than joint_state_rate (fpgalink.robot.joints.SampleSets).
        async for sample in link.telemetry(maxsize=4096):
            complete = self._sets.add(board, sample, self.loop.time())
            if complete is not None:
                if self.clock_pub is not None:
                    # One tick per set: the emulated time the samples were taken in, at
                    # joint_state_rate; use_sim_time nodes (this one too) run on it.
                    self._publish_clock()
                stamp_ns = self._publish_joints(complete)
                if stamp_ns is not None:
                    self._publish_odometry(self._odometry_stamp(complete, stamp_ns))
                self._control_step(complete, stamp_ns)

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

    def _publish_joints(self, samples: dict[str, Telemetry]) -> int | None:
        """joint_states from one set of samples, stamped with the first board's sample time
        on the ROS clock; returns the stamp (ns)."""
        states = self.robot.joint_states(samples)
        if states is None:
            return None
        now_ns = self.node.get_clock().now().nanoseconds
        if now_ns == 0:
            # use_sim_time before the first /clock: no time yet (ROS's convention), and
            # a board clock mapped onto it would start its estimate from nothing.
            return None
        self._set_stamps = {board: self._clocks[board].ns(samples[board].t_us, now_ns)
                            for board in self.robot.description.boards}
        stamp_ns = self._set_stamps[self.robot.description.boards[0]]
        message = JointState()
        message.header.stamp = _time_msg(stamp_ns)
        message.name = [self._joint_names.get(name, name) for name in states.names]
        message.position = list(states.position)
        message.velocity = list(states.velocity)
        message.effort = list(states.effort)
        self.joint_pub.publish(message)
        self.published["joint_states"] += 1
        return stamp_ns

    def _odometry_stamp(self, samples: dict[str, Telemetry], stamp_ns: int) -> int:
        """The stamp of the robot's odometry now: the robot follows the telemetry in its
        own tasks, which on a loaded host run ahead of this node's sets by tens of ms, and a
        pose stamped with the set's time ran ahead of its stamp (2 cm at 0.2 m/s measured,
        a jump to any consumer that interpolates). The odometry steps once every board has
        reported: its time is the earliest of the boards' latest samples, each mapped as
        its sample in ``samples`` was. Never earlier than the odom before it."""
        times = []
        for board, set_ns in self._set_stamps.items():
            latest = self.robot.latest.get(board)
            if latest is None:
                continue
            ahead_us = (latest.t_us - samples[board].t_us + BOARD_CLOCK_WRAP_US // 2) \
                % BOARD_CLOCK_WRAP_US - BOARD_CLOCK_WRAP_US // 2
            if abs(ahead_us) < 1_000_000:  # else a restart between them: not comparable
                times.append(set_ns + ahead_us * 1000)
        if times:
            stamp_ns = min(times)
        stamp_ns = max(stamp_ns, self._last_odom_ns + 1000)
        self._last_odom_ns = stamp_ns
        return stamp_ns

    def _publish_odometry(self, stamp_ns: int) -> None:
        """odom stamped at the robot's odometry's latest sample (:meth:`_odometry_stamp`)."""
        state = self.robot.odometry_state
        message = Odometry()
        message.header.stamp = _time_msg(stamp_ns)
        message.header.frame_id = self.frame(str(self._value("odom_frame")))
        message.child_frame_id = self.frame(str(self._value("base_frame")))
        _pose_into(message, state.pose.x, state.pose.y, state.pose.theta)
        message.twist.twist.linear.x = state.v
        message.twist.twist.angular.z = state.omega
        pose_diagonal = self._value("pose_covariance_diagonal")
        message.pose.covariance = state.covariance_6x6() if pose_diagonal is None \
            else _diagonal(pose_diagonal)
        message.twist.covariance = _diagonal(self._value("twist_covariance_diagonal"))
        self.odom_pub.publish(message)
        self.published["odom"] += 1
        if self.tf_pub is not None and self.tf_type is not None \
                and self._value("publish_odom_tf"):
            transform = TransformStamped()
            transform.header = message.header
            transform.child_frame_id = message.child_frame_id
            transform.transform.translation.x = message.pose.pose.position.x
            transform.transform.translation.y = message.pose.pose.position.y
            transform.transform.rotation = message.pose.pose.orientation
            self.tf_pub.publish(self.tf_type(transforms=[transform]))
            self.published["tf"] += 1
        truth = self.robot.truth()
        if truth is not None and self.truth_pub is not None:
            true = Odometry()
            true.header = message.header
            true.child_frame_id = message.child_frame_id
            _pose_into(true, truth["x"], truth["y"], truth["theta"])
            true.twist.twist.linear.x = float(truth["v"])
            true.twist.twist.angular.z = float(truth["omega"])
            self.truth_pub.publish(true)

    # --- the emulated body's IMU ---------------------------------------------------------

    def _imu_publisher(self) -> Any:
        """``imu/data`` when the robot's body is emulated in this process with an IMU (the
        physics body's truth carries one); ``None`` otherwise."""
        truth = self.robot.truth()
        if truth is None or truth.get("imu") is None:
            return None
        self.published["imu"] = 0
        return self._publisher(Imu, "imu/data", qos_profile_sensor_data)

    async def _imu_loop(self) -> None:
        """sensor_msgs/Imu at :data:`IMU_RATE_HZ`: angular velocity and linear acceleration
        (each the mean since the previous reading, with the emulated IMU's noise and bias,
        their variances on the diagonals); no orientation (covariance[0] = −1), as a
        6-axis IMU gives none."""
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
            message = Imu()
            message.header.stamp = self.node.get_clock().now().to_msg()
            message.header.frame_id = self.frame(IMU_FRAME)
            gyro, accel = reading["angular_velocity"], reading["linear_acceleration"]
            (message.angular_velocity.x, message.angular_velocity.y,
             message.angular_velocity.z) = (float(v) for v in gyro)
            (message.linear_acceleration.x, message.linear_acceleration.y,
             message.linear_acceleration.z) = (float(v) for v in accel)
            gyro_var = float(reading.get("angular_velocity_variance", 0.0))
            accel_var = float(reading.get("linear_acceleration_variance", 0.0))
            message.angular_velocity_covariance = [gyro_var, 0.0, 0.0, 0.0, gyro_var, 0.0,
                                                   0.0, 0.0, gyro_var]
            message.linear_acceleration_covariance = [accel_var, 0.0, 0.0, 0.0, accel_var,
                                                      0.0, 0.0, 0.0, accel_var]
            message.orientation_covariance = [-1.0] + [0.0] * 8
            self.imu_pub.publish(message)
            self.published["imu"] += 1

    async def _command_watchdog(self) -> None:
        while True:
            timeout = float(self._value("cmd_vel_timeout"))
            await asyncio.sleep(min(0.05, timeout / 4))
            at = self._last_command_at
            if (at is not None and not self._command_is_zero
                    and self.loop.time() - at > timeout
                    and (self._goal is None or self._goal.done())):
                self.log.warning(f"no cmd_vel or wheel_refs for {timeout:g} s: wheels to rest")
                if self._ramp is not None and self._limiter.rate_limited:
                    self._ramp = (0.0, 0.0)  # braking within the limits, as diff_drive_controller
                else:
                    with contextlib.suppress(FpgalinkError):
                        self.robot.stop()
                self._command_is_zero = True

    async def _diagnostics_loop(self) -> None:
        while True:
            await asyncio.sleep(DIAGNOSTICS_PERIOD_S)
            self._publish_diagnostics()
            self._check_cmd_vel_publishers()
            self._check_name_clash()

    async def _enable_keeper(self) -> None:
        """Without ``require_enable`` this node renews the enable itself while the robot is
        enabled (a fault still stops it; the next command asks again)."""
        while True:
            await asyncio.sleep(float(self._value("enable_timeout")) / 4)
            if not self._value("require_enable") and self.robot.state is State.ENABLED:
                with contextlib.suppress(RobotStopped):
                    self.robot.enable()

    def _check_name_clash(self) -> None:
        """Another node of this name in this namespace: its parameters, services and
        diagnostics would be mistaken for this one's. Said once."""
        if self._name_clash_said:
            return
        me = (self.node.get_name(), self.node.get_namespace())
        if self.node.get_node_names_and_namespaces().count(me) > 1:
            self._name_clash_said = True
            self.log.warning(f"another node is named {me[1].rstrip('/')}/{me[0]}: its "
                             "parameters, services and diagnostics will be mistaken for this "
                             "one's (rename one: -r __node:=NAME)")

    def _check_cmd_vel_publishers(self) -> None:
        """A publisher of the other Twist type on cmd_vel never matches this subscription:
        its commands would vanish without a word. Said once per type."""
        ours = CMD_VEL_TYPES[bool(self._value("use_stamped_vel"))]
        topic = self.cmd_vel_sub.topic_name
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
            self.log.error(
                f"{topic}: {who} publishes {kind}, this node takes {ours}: those commands "
                f"do not arrive (set "
                f"use_stamped_vel:={'false' if ours.endswith('Stamped') else 'true'})")

    def _publish_diagnostics(self) -> None:
        self.diag_pub.publish(self.diagnostics(self.loop.time()))
        self.published["diagnostics"] += 1

    def diagnostics(self, now: float) -> DiagnosticArray:
        array = DiagnosticArray()
        ros_now = self.node.get_clock().now()
        array.header.stamp = ros_now.to_msg()
        array.status = [diagnostic_status(self._with_sample_age(status, ros_now.nanoseconds),
                                          self.node.get_name())
                        for status in self.robot.health(now)]
        return array

    def _with_sample_age(self, status: Status, now_ns: int) -> Status:
        """A board's status with how old, on the ROS clock, the board time of its sample in
        the last published set is: what joint_states and odom lag the boards by. A loaded
        node falls behind the telemetry long before the telemetry counts as stopped (50
        periods without a sample), and this says so; empty before the first set."""
        board = status.name.removeprefix("board ")
        if not status.name.startswith("board ") or board not in self._clocks:
            return status
        stamp = self._set_stamps.get(board)
        age = "" if stamp is None else f"{(now_ns - stamp) / 1e6:.1f} ms"
        return dataclasses.replace(status, values=(*status.values, ("latest sample age", age)))


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


#: Status events that are faults: logged as errors, and diagnostics published at once.
_FAULTS = (BoardSilent, PortLost, BoardRestarted, WatchdogLapsed, TelemetryStale,
           WireCrcMismatch)


def _tf_message_type() -> Any:
    """tf2_msgs/msg/TFMessage, or ``None`` where tf2_msgs is not installed (ROS 2 Jazzy has
    no PyPI wheel of it: ``make tf2-msgs`` generates it from the rosidl wheels)."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


def diagnostic_status(status: Status, node_name: str = NODE_NAME) -> DiagnosticStatus:
    return DiagnosticStatus(level=bytes([status.level]), name=f"{node_name}: {status.name}",
                            message=status.message, hardware_id=status.hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in status.values])


def _pose_into(message: Odometry, x: float, y: float, theta: float) -> None:
    message.pose.pose.position.x = float(x)
    message.pose.pose.position.y = float(y)
    message.pose.pose.orientation.z = math.sin(theta / 2.0)
    message.pose.pose.orientation.w = math.cos(theta / 2.0)



def _diagonal(values: Any) -> list[float]:
    matrix = [0.0] * 36
    for index, value in enumerate(values):
        matrix[index * 7] = float(value)
    return matrix


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of URDF's fixed-axis roll, pitch, yaw."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)
