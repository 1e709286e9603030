"""The node's ROS parameters: its own (``joint_state_rate``, ``cmd_vel_timeout``, the
kinematics and limits under diff_drive_controller's names, …: the table in docs/ros2.md),
each applied to the robot — its command arbiter, its kinematics, its deadman — when set,
and every board parameter as ``BOARD.NAME`` or ``BOARD.NAME.CHANNEL``, confirmed by the
board's echo before a set succeeds."""

from __future__ import annotations

import asyncio
import concurrent.futures
import difflib
import math
import weakref
from collections.abc import Callable, Iterable
from typing import Any

import rclpy.task
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_service import ParameterService
from rclpy.qos import qos_profile_parameters

from fpgalink.errors import FpgalinkError, ParameterError, ParameterRefused, ValueMismatch
from fpgalink.protocol import PARAMETERS, Param, ParamType
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B, Scope, channel_name
from fpgalink.protocol.urdf import FixedJoint, fixed_joints, robot_urdf
from fpgalink.robot import Robot
from fpgalink.robot.limits import LIMIT_SIGNS, AxisLimits, check_limit

__all__ = ["AXES", "BadOverride", "NodeParameters", "board_parameter_name", "overrides_in"]

#: Twist/JointState references older than this bring the wheels to rest (a parameter).
DEFAULT_CMD_TIMEOUT_S = 0.5
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
LIMIT_GROUPS = {"velocity": ("min_velocity",),
                "acceleration": ("max_acceleration", "max_deceleration",
                                 "max_acceleration_reverse", "max_deceleration_reverse",
                                 "min_acceleration"),
                "jerk": ("max_jerk", "min_jerk")}
#: Limits that do nothing without another (as in diff_drive_controller).
NEEDS = {"max_deceleration": "max_acceleration", "max_acceleration_reverse": "max_acceleration",
         "max_deceleration_reverse": "max_acceleration", "min_acceleration": "max_acceleration",
         "min_jerk": "max_jerk"}


class BadOverride(Exception):
    """A ``--ros-args -p`` value that the node, its board (or the host's check of its
    range) does not take: a usage error."""


def board_parameter_name(board: str, param: Param, channel: int) -> str:
    """``L.TsTimerPeriod``, ``L.Kp_Wheel_Pid.A``."""
    if param.scope is Scope.BOARD:
        return f"{board}.{param.name}"
    return f"{board}.{param.name}.{channel_name(channel)}"


def overrides_in(argv: Iterable[str], node_name: str) -> set[str]:
    """The names ``-p NAME:=VALUE`` (``--param``, or ``-p NODE:NAME:=VALUE`` for this node)
    gives in the ROS arguments of ``argv``."""
    names: set[str] = set()
    ros, given = False, list(argv)
    for arg, value in zip(given, [*given[1:], ""], strict=True):
        if arg == "--ros-args":
            ros = True
        elif arg == "--":
            ros = False
        elif ros and arg in ("-p", "--param") and ":=" in value:
            target, _, name = value.split(":=", 1)[0].rpartition(":")
            if target in ("", node_name):
                names.add(name)
    return names


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


def _double(low: float, high: float, text: str) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE, description=text,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high, step=0.0)])


def _boolean(text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_BOOL, description=text,
                               read_only=read_only)


class NodeParameters:
    """Declares the node's parameters on ``node`` and applies them to ``robot`` (again on
    each set); ``on_change`` after each application. :meth:`withdraw` takes back its
    check of sets (a managed node's cleanup)."""

    def __init__(self, robot: Robot, node: Node, on_change: Callable[[], None]) -> None:
        self.robot = robot
        self.node = node
        self.log = node.get_logger()
        self._on_change = on_change
        self._said: set[str] = set()  #: warnings given once
        self._file_limits = (robot.description.max_linear_speed,
                             robot.description.max_angular_speed_rad)
        self.board_params: dict[str, tuple[str, Param, int]] = {}
        # Before declaring: rclpy runs this on each declared value (a -p too) and on sets.
        node.add_on_set_parameters_callback(self._check)
        self.values: dict[str, Any] = {}
        try:
            self._declare_node()
            self._declare_limits()
            self.apply()
            self.joint_names = self._declare_wheel_names()
            self.prefix = self._frame_prefix()
            self.urdf, self.fixed_joints = self._declare_robot_description()
            self.publish_clock = self._declare_publish_clock()
            self.foxglove = self._declare_foxglove()
        except BaseException:
            self.withdraw()
            raise

    def withdraw(self) -> None:
        self.node.remove_on_set_parameters_callback(self._check)

    def declare(self, name: str, default: Any, descriptor: ParameterDescriptor) -> Any:
        """Declared, and its value (one a configure before declared read-only, and could
        not withdraw, is taken as it is)."""
        if self.node.has_parameter(name):
            return self.node.get_parameter(name).value
        return self.node.declare_parameter(name, default, descriptor).value

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    @property
    def publish_period(self) -> float:
        return 1.0 / float(self.values["joint_state_rate"])

    # --- the node's own -----------------------------------------------------------------

    def _declare_node(self) -> None:
        declare, model = self.declare, self.robot.kinematics
        for name, default, low, high, text in (
                ("joint_state_rate", 100.0, 1.0, 1000.0,
                 "joint_states and odom per second, Hz (at most the telemetry rate)"),
                ("cmd_vel_timeout", DEFAULT_CMD_TIMEOUT_S, 0.05, 10.0,
                 "a cmd_vel or wheel_refs older than this brings the wheels to rest, s"),
                ("goal_tolerance", 0.05, 0.005, 10.0, "goal_pose reached within this, m"),
                ("wheel_radius", model.wheel_radius, 0.005, 5.0,
                 "wheel radius, m (default: the robot file's)"),
                ("wheel_separation", model.track, 0.05, 20.0,
                 "between the left and right wheels' centres, m (default: the robot "
                 "file's)"),
                ("wheel_separation_multiplier", model.chi, 1.0, 20.0,
                 "the skid-steer factor χ: the effective track is χ × wheel_separation; it "
                 "differs per surface (default: the robot file's for its surface)"),
                *((f"{side}_wheel_radius_multiplier", 1.0, 0.5, 2.0,
                   f"the {side} wheels' rolling radius over wheel_radius (worn or "
                   "differently inflated wheels): drive and odometry use it")
                  for side in ("left", "right")),
                ("enable_timeout", DEFAULT_CMD_TIMEOUT_S, 0.05, 10.0,
                 "with require_enable: true on enable at least this often keeps the robot "
                 "enabled (the seed's /globalEnable deadman), s")):
            declare(name, default, _double(low, high, text))
        declare("telemetry_timeout_periods", 50, ParameterDescriptor(
            type=ParameterType.PARAMETER_INTEGER,
            description="a board's telemetry missing for this many timer periods is a fault: "
                        "the robot stops until it comes again (50: 50 ms at 1 kHz)",
            integer_range=[IntegerRange(from_value=2, to_value=100_000, step=1)]))
        for name, flag, text, read_only in (
                ("require_enable", True, "true: the robot drives only while true arrives on "
                 "enable (the deadman); false: cmd_vel enables it, cmd_vel_timeout brings "
                 "the wheels to rest (as diff_drive_controller)", False),
                ("joint_states_best_effort", False, "joint_states with sensor-data QoS (best "
                 "effort) instead of reliable", True),
                ("publish_odom_tf", True, "publish odom_frame -> base_frame on /tf with each "
                 "odom", False),
                ("use_stamped_vel", False, "cmd_vel is geometry_msgs/TwistStamped (true, "
                 "diff_drive_controller's Jazzy default) or Twist (false, Nav2's and "
                 "teleop's default)", True),
                ("tf_frame_prefix_enable", True, "prefix every frame id this node publishes "
                 "(as diff_drive_controller)", True),
                ("publish_static_tf", True, "the URDF's fixed joints on /tf_static, as "
                 "robot_state_publisher (false where one runs)", True),
                ("publish_limited_velocity", False, "publish each cmd_vel as driven, after "
                 "the limits, on cmd_vel_out", True)):
            declare(name, flag, _boolean(text, read_only))
        for name, frame in (("odom_frame", "odom"), ("base_frame", "base_link")):
            declare(name, frame, ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING, description=f"frame id: {name}"))
        declare("tf_frame_prefix", "", ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True,
            description="the prefix; empty: the node's namespace (/bot: bot/odom)"))
        declare("pose_covariance_diagonal", Parameter.Type.DOUBLE_ARRAY, ParameterDescriptor(
            description="odom's pose covariance diagonal (x, y, z, roll, pitch, yaw); unset: "
                        "computed from the odometry's motion model"))
        declare("twist_covariance_diagonal", [0.0] * 6, ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE_ARRAY,
            description="odom's twist covariance diagonal (vx, vy, vz, wx, wy, wz)"))

    def _declare_limits(self) -> None:
        linear, angular = self._file_limits
        self.declare("linear.x.max_velocity", linear, _double(
            0.001, linear, "the robot's speed limit, m/s, at most the robot file's; a "
            "command beyond a limit is scaled keeping its curvature"))
        self.declare("angular.z.max_velocity", angular, _double(
            0.001, angular, "the robot's turn rate limit, rad/s, at most the robot file's"))
        for axis, unit in AXES.items():
            for group in LIMIT_GROUPS:
                self.declare(f"{axis}.has_{group}_limits", True, _boolean(
                    f"deprecated in Jazzy (set the limits to NaN instead): false ignores "
                    f"{axis}'s {group} limits" + (" (max_velocity is then the robot file's)"
                                                  if group == "velocity" else "")))
            for name, text in LIMITS.items():
                # No floating_point_range: NaN (not set) is outside any; _check takes it.
                self.declare(f"{axis}.{name}", math.nan, ParameterDescriptor(
                    type=ParameterType.PARAMETER_DOUBLE, description=text.format(u=unit),
                    additional_constraints="a finite number of its sign, or NaN: not set "
                                           "(diff_drive_controller's defaults, docs/ros2.md)"))

    def _value(self, name: str) -> Any:
        """Its value; ``None`` for one declared by type and not given (unset: computed)."""
        try:
            return self.node.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
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

    def apply(self) -> None:
        """Read the node's own parameters (cached: read per message at up to 1 kHz) and
        put them in force on the robot: its arbiter's limits, timeout, enable and control
        period, its kinematics, deadman and telemetry timeout."""
        names = [name for name in self.node.list_parameters([], 0).names
                 if name not in self.board_params]
        self.values = {name: self._value(name) for name in names}
        values, robot = self.values, self.robot
        robot.set_limits(*(self._axis_limits(axis, file_limit)
                           for axis, file_limit in zip(AXES, self._file_limits, strict=True)))
        model = robot.kinematics
        wanted = {"wheel_radius": float(values["wheel_radius"]),
                  "track": float(values["wheel_separation"]),
                  "chi": float(values["wheel_separation_multiplier"]),
                  "left_radius_multiplier": float(values["left_wheel_radius_multiplier"]),
                  "right_radius_multiplier": float(values["right_wheel_radius_multiplier"])}
        if any(getattr(model, key) != value for key, value in wanted.items()):
            # Drive and odometry with them from now on (ranges checked by the descriptors).
            robot.set_kinematics(**wanted)
        robot.supervisor.deadman_s = float(values["enable_timeout"])
        robot.boards.set_stale_periods(int(values["telemetry_timeout_periods"]))
        arbiter = robot.arbiter
        arbiter.command_timeout = float(values["cmd_vel_timeout"])
        arbiter.control_period = self.publish_period
        arbiter.auto_enable = not values["require_enable"]
        # Without the deadman this node renews the enable itself while the robot is
        # enabled (a fault still stops it; the next command asks again).
        robot.keep_enabled(None if values["require_enable"]
                           else float(values["enable_timeout"]) / 4)
        self._on_change()

    def _axis_limits(self, axis: str, file_limit: float) -> AxisLimits:
        """An axis's limits from its parameters: ``max_velocity`` is always there (the
        robot file's without ``has_velocity_limits``); the ``has_*_limits`` of older
        configurations (deprecated in Jazzy) drop the others, as there, said once."""
        values = self.values
        wanted = {name: float(values[f"{axis}.{name}"]) for name in LIMITS}
        wanted["max_velocity"] = float(values[f"{axis}.max_velocity"])
        for group, names in LIMIT_GROUPS.items():
            if not values[f"{axis}.has_{group}_limits"]:
                self.say_once(f"{axis}.has_{group}_limits", f"{axis}.has_{group}_limits: "
                              "deprecated in Jazzy (set the limits to NaN instead): "
                              f"{axis}'s {group} limits ignored")
                wanted.update(dict.fromkeys(names, math.nan))
                if group == "velocity":
                    wanted["max_velocity"] = file_limit
        if not math.isnan(wanted["min_acceleration"]):
            self.say_once(f"{axis}.min_acceleration", f"{axis}.min_acceleration: Jazzy "
                          "before 4.18's name, deprecated there since: taken as the "
                          "default of max_deceleration and max_acceleration_reverse")
        for name, needs in NEEDS.items():
            if not math.isnan(wanted[name]) and math.isnan(wanted[needs]):
                self.say_once(f"{axis}.{name} unused", f"{axis}.{name}: no effect without "
                              f"{axis}.{needs} (as in diff_drive_controller)")
        return AxisLimits(**wanted)

    def say_once(self, key: str, text: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.log.warning(text)

    def _declare_wheel_names(self) -> dict[str, str]:
        """``left_wheel_names``/``right_wheel_names`` (read-only, as diff_drive_controller
        takes them): the description's wheel → the name joint_states, wheel_refs and the
        URDF give it."""
        wheels = self.robot.description.wheels
        names: dict[str, str] = {}
        for side, left in (("left", True), ("right", False)):
            ours = [w.name for w in wheels if w.left is left]
            name = f"{side}_wheel_names"
            given = self.declare(name, ours, ParameterDescriptor(
                type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
                description=f"the {side} wheels' joint names, front to back (default: the "
                            "robot file's)"))
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
        if not self.values["tf_frame_prefix_enable"]:
            return ""
        prefix = str(self.values["tf_frame_prefix"]) or self.node.get_namespace()
        if not prefix.endswith("/"):
            prefix += "/"
        return prefix.lstrip("/")

    def _declare_robot_description(self) -> tuple[str, list[FixedJoint]]:
        """The robot's URDF (its wheels under this node's joint names), or one given with
        ``-p robot_description:=…``: a read-only parameter and the latched topic, as
        robot_state_publisher has it."""
        urdf = robot_urdf(self.robot.description, self.joint_names)
        given = str(self.declare("robot_description", urdf, ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True,
            description="the robot's URDF (default: generated from the robot file, its "
                        "wheels' joints named as in joint_states)")))
        try:
            return given, fixed_joints(given)
        except ValueError as exc:
            raise BadOverride(f"robot_description: {exc}") from None

    def _declare_publish_clock(self) -> bool:
        """``/clock`` from the emulated robot's own time: only where the robot is emulated
        in this process (a real robot has no time but the host's)."""
        emulated = self.robot.truth() is not None
        wanted = bool(self.declare("publish_clock", emulated, _boolean(
            "publish /clock from the emulated robot's time (default: true for the emulated "
            "robot in this process; refused for real ports)", read_only=True)))
        if wanted and not emulated:
            raise BadOverride("publish_clock: only the emulated robot in this process has a "
                              "time of its own (no --port)")
        return wanted

    def _declare_foxglove(self) -> str:
        """``foxglove`` (read-only): the ROS-less route to Foxglove as a node parameter, so a
        launch file or a parameters file can ask for it; ``--foxglove`` on the command line
        wins. Empty: no live view. A bare port is what ROS reads as an integer
        (``-p foxglove:=8765``), so either type is taken."""
        value = self.declare("foxglove", "", ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True, dynamic_typing=True,
            description="[HOST:]PORT of a live view for Foxglove without ROS, read at start "
                        "(as --foxglove; loopback unless HOST is given; the foxglove extra; "
                        "empty: none)"))
        if isinstance(value, bool) or not isinstance(value, int | str):
            raise BadOverride(f"foxglove: [HOST:]PORT, got {value!r}")
        return str(value).strip()

    # --- the boards' --------------------------------------------------------------------

    async def declare_board_parameters(self, overrides: set[str]) -> None:
        """Every board parameter as a ROS parameter, its value read from the board; a value
        given with ``--ros-args -p`` is set on the board (and must be confirmed). Each is
        this node's configuration from then on: held by the board's link, set again if the
        board restarts, so a ROS parameter never silently differs from its board.
        ``overrides``: the ``-p`` names given; one this node has not is warned about."""
        boards = self.robot.boards
        for board in self.robot.description.boards:
            values = await boards.read_parameters(board, hold=True)
            for param in PARAMETERS:
                channels = (0,) if param.scope is Scope.BOARD else (CHANNEL_A, CHANNEL_B)
                for channel in channels:
                    name = board_parameter_name(board, param, channel)
                    on_board = values[(param.id, channel)]
                    self.board_params[name] = (board, param, channel)
                    declared = self.declare(name, on_board, _descriptor(param, board))
                    if declared != on_board:  # an override from the command line
                        try:
                            confirmed = await boards.set_parameter(board, param.id, declared,
                                                                   channel or None)
                        except (ParameterError, ParameterRefused, ValueMismatch) as exc:
                            # The value given is wrong (a board not answering is not).
                            raise BadOverride(f"{name}: {exc}") from None
                        self.node.set_parameters([Parameter(name, value=confirmed)])
        self._warn_unknown(overrides)

    def _warn_unknown(self, overrides: set[str]) -> None:
        """A ``-p NAME:=VALUE`` for a parameter this node does not have is not silently
        ignored: one warning per name, with the nearest names it has."""
        have = list(self.node.list_parameters([], 0).names)
        for name in sorted(overrides - set(have)):
            near = difflib.get_close_matches(name, have, n=3)
            self.log.warning(f"-p {name}: this node has no such parameter: ignored"
                             + (f" (did you mean {', '.join(near)}?)" if near else ""))

    async def set_parameter(self, parameter: Parameter, loop: asyncio.AbstractEventLoop,
                            executor: Any) -> SetParametersResult:
        """One parameter from a ``set_parameters`` call (on the executor's thread): a board
        parameter is set on its board first (on ``loop``) and succeeds only when its echo
        matched; the node's own are put in force on the robot."""
        name = parameter.name
        target = self.board_params.get(name)
        if target is None:
            if not self.node.has_parameter(name):
                return SetParametersResult(successful=False,
                                           reason=f"no parameter {name!r}")
            result = self.node.set_parameters([parameter])[0]
            loop.call_soon_threadsafe(self.apply)
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
            self._set_on_board(board, param, channel, value), loop)
        reason, confirmed = await _rclpy_future(future, executor)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
        committed = Parameter(name, value=confirmed if param.type is ParamType.INT
                              else float(confirmed))
        return self.node.set_parameters([committed])[0]

    async def _set_on_board(self, board: str, param: Param, channel: int,
                            value: int | float) -> tuple[str | None, int | float]:
        try:
            confirmed = await self.robot.boards.set_parameter(board, param.id, value,
                                                              channel or None)
        except FpgalinkError as exc:
            return f"board {board}: {exc}", value
        return None, confirmed


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


class BoardParameterService(ParameterService):
    """rclpy's six parameter services, with ``set_parameters`` a coroutine that sets a
    board parameter on the board first and reports success only when the echo matched.
    All in a reentrant group, so reading parameters does not wait behind a pending set."""

    def __init__(self, node: Node, set_parameter: Callable[[Parameter], Any]) -> None:
        from rcl_interfaces.srv import (
            DescribeParameters,
            GetParameters,
            GetParameterTypes,
            ListParameters,
            SetParameters,
            SetParametersAtomically,
        )

        # As rclpy's ParameterService keeps its node (its other callbacks read it).
        self._node_weak_ref = weakref.ref(node)
        self._set_parameter = set_parameter
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
                result = await self._set_parameter(parameter)
            except Exception as exc:  # reported to the caller, never raised
                result = SetParametersResult(successful=False, reason=f"internal error: {exc}")
            response.results.append(result)
        return response

    def _set_parameters_atomically_callback(self, request: Any, response: Any) -> Any:
        response.result = SetParametersResult(
            successful=False, reason="set board parameters one at a time (set_parameters): "
            "each is confirmed by its board")
        return response
