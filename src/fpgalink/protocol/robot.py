"""The robot both sides agree on: a four-wheel skid-steered body (the seed's SSMR) whose left
and right boards each drive the front (channel A) and rear (channel B) wheel of one side —
described as data (a TOML file, or :data:`SEED_ROBOT_TOML`), and its kinematics.

The host uses it to turn a body command into wheel references and encoder counts into
odometry; the emulator uses the very same model to move its emulated body from the wheels'
rotation. Nothing here does I/O or reads a clock.

**Frame.** REP-103, as ROS expects: x forward, y left, z up, yaw counter-clockwise. (The
seed's URDF puts the left wheels at y = −0.33 m, a y-right frame; its eq. 2.20 has the
matching sign. We keep the seed's wheel names and distances and use y-left.)

**Skid-steer model** (seed §2.6, eqs. 2.19–2.23, with the expanded track of Mandow et al.):
the two wheels of a side turn together; a side's ground speed is ``v_s = r·ω_s``; the body
moves as a differential drive whose track is the geometric one times ``χ ≥ 1``, because the
wheels slip sideways and the body turns slower than the speed difference says::

    v = (v_L + v_R) / 2                 (2.19)
    Ω = (v_R − v_L) / (χ·B)             (2.20, REP-103 sign, B = geometric track)
    ICR_x = −v_y / Ω = 0                (2.21: no lateral body speed in this model)
    ICR_y = v / Ω                       (2.22)
    R = √(ICR_x² + ICR_y²)              (2.23)

χ depends on the surface; the seed's measurements (§3.6) give about 1.65 on gravel and
1.85 on marble (docs/robot.md has the calibration); grass, which the seed drove on without
a figure, takes the 1.63 the emulator's physics body shows there.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from fpgalink.protocol.errors import FpgalinkError, ParameterError
from fpgalink.protocol.paramfile import Setting, parse_parameter_table
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B
from fpgalink.protocol.tomlfile import TomlFileError, load_toml, parse_toml

__all__ = [
    "BOARD_NAME",
    "LEFT_WHEELS",
    "RIGHT_WHEELS",
    "SEED_ROBOT_TOML",
    "WHEEL_NAMES",
    "BodyShape",
    "DescriptionError",
    "OdometryNoise",
    "Pose",
    "RobotDescription",
    "SkidSteer",
    "WheelMount",
    "check_board_name",
    "integrate_arc",
    "load_robot",
    "parse_robot",
    "seed_robot",
    "wrap_angle",
]

WHEEL_NAMES = ("FL", "BL", "FR", "BR")
LEFT_WHEELS = ("FL", "BL")
RIGHT_WHEELS = ("FR", "BR")
_CHANNELS = {"A": CHANNEL_A, "B": CHANNEL_B}

#: The seed's robot (SapRoover, seed §3.1 and the URDF of §3.3.4), as a robot file.
SEED_ROBOT_TOML = """\
# The seed's robot: a four-wheel skid-steered body, boards L and R, channel A = front wheel.
name = "SapRoover"
wheel_radius = 0.20        # m (wheel diameter 0.40 m)
gear_ratio = 70            # the worm gearbox; the boards measure wheel speed after it
max_wheel_speed = 90.0     # deg/s, at the wheel
max_linear_speed = 0.25    # m/s (seed §3.1)
max_angular_speed = 25.0   # deg/s (seed §3.1)
surface = "gravel"         # the chi odometry and driving use

[surfaces]                 # skid-steer expanded-track factor chi (docs/robot.md)
ideal = 1.0
gravel = 1.65
marble = 1.85
grass = 1.63               # no seed figure: what the emulator's physics body shows on grass

# Wheel positions from the seed's URDF, in REP-103 (x forward, y left). forward: the sign
# of the board's speed that drives the robot forward.
[wheels.FL]
board = "L"
channel = "A"
x = 0.29
y = 0.33
forward = 1

[wheels.BL]
board = "L"
channel = "B"
x = -0.29
y = 0.33
forward = 1

[wheels.FR]
board = "R"
channel = "A"
x = 0.29
y = -0.33
forward = 1

[wheels.BR]
board = "R"
channel = "B"
x = -0.29
y = -0.33
forward = 1

# The chassis, for a physics body and the URDF (docs/robot.md: what the seed gives and what
# is assumed). Positions in m from base_link, which the seed's URDF puts at the centre of
# the wheel axles; REP-103 axes.
[body]
mass = 60.0                # kg, the whole robot on the seed's scales (§2.5.3)
centre_of_mass = [-0.048, -0.012, -0.10]  # x, y from the scales (§2.5.3); z calibrated
wheel_mass = 2.5           # kg each, assumed (a 0.40 m wheel with its hub)
wheel_width = 0.10         # m, assumed
chassis = [0.80, 0.50, 0.30]   # m, length, width, height of the chassis box (§3.1: 80 cm long)
chassis_z = 0.05           # m, the box's centre above base_link (0.10 m ground clearance)
imu = [0.125, -0.03, 0.11]     # the seed's ImuALink (§3.3.4), y flipped to REP-103
lidar = [0.39, 0.02, 0.23]     # the seed's laser (§3.3.4), facing backwards (yaw 180°)

[odometry]                 # how fast the pose covariance grows
distance_noise = 1e-4      # m² of position variance per m travelled
turn_noise = 1.6e-3        # rad² of heading variance per rad turned
drift_noise = 1e-4         # rad² of heading variance per m travelled

# Loaded into every board at start (the format `fpgalink-cli param dump` writes); then
# [board_parameters.NAME] for one board. The encoder resolution is read back from the
# boards, never assumed.
[parameters]
TsTimerPeriod = 1

[parameters.A]
IncSenzRes = 500
IncSenzCountDirection = 1
Kp_Wheel_Pid = 520.0
Ti_Wheel_Pid = 0.24
Td_Wheel_Pid = 0.0

[parameters.B]
IncSenzRes = 500
IncSenzCountDirection = 1
Kp_Wheel_Pid = 520.0
Ti_Wheel_Pid = 0.24
Td_Wheel_Pid = 0.0
"""

#: A board's name: what the robot file's ``board``, ``[ports]`` keys, ``--port NAME=URL``
#: and ``fpgaemu serve`` use; it appears in ready lines, topics and messages, so it is one
#: word of letters, digits, ``_`` and ``-``.
BOARD_NAME = re.compile(r"[A-Za-z0-9_-]+")

# Geometry and limits below these make no robot: a wheel of zero radius, wheels of one side
# on the centre line, a top speed nobody could drive at. The bounds are far below any real
# robot (the seed's: radius 0.20 m, track 0.66 m, wheel base 0.58 m) and far above the
# values (1e-300, 5e-324) whose divisions overflow the odometry.
#: m: a 1 cm wheel (a micro-robot's) is the smallest
MIN_WHEEL_RADIUS = 0.01
#: m from the centre line to a wheel (the track is at least twice that)
MIN_WHEEL_OFFSET = 0.01
#: the smallest gear ratio (an overdrive of 100:1)
MIN_GEAR_RATIO = 0.01
#: deg/s at the wheel, m/s, deg/s of the body: the lowest top speeds accepted
MIN_WHEEL_SPEED = 0.1
MIN_LINEAR_SPEED = 0.001
MIN_ANGULAR_SPEED = 0.1

_TOP_KEYS = frozenset({"name", "wheel_radius", "gear_ratio", "max_wheel_speed",
                       "max_linear_speed", "max_angular_speed", "surface", "surfaces",
                       "wheels", "odometry", "parameters", "board_parameters", "body"})
_WHEEL_KEYS = frozenset({"board", "channel", "x", "y", "forward"})
_ODOMETRY_KEYS = frozenset({"distance_noise", "turn_noise", "drift_noise"})
_BODY_KEYS = frozenset({"mass", "centre_of_mass", "wheel_mass", "wheel_width", "chassis",
                        "chassis_z", "imu", "lidar"})


class DescriptionError(FpgalinkError, ValueError):
    """A robot description that does not hold together; the message names the file and
    the key."""


def wrap_angle(angle: float) -> float:
    """``angle`` in (−π, π]."""
    wrapped = math.remainder(angle, math.tau)
    return math.pi if wrapped == -math.pi else wrapped


@dataclass(frozen=True, slots=True)
class Pose:
    """A pose in the plane: m, m, rad (REP-103, θ in (−π, π])."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


def integrate_arc(pose: Pose, distance: float, turn: float) -> Pose:
    """Move ``pose`` along a circular arc of length ``distance`` (m, signed) that turns by
    ``turn`` (rad): exact for a constant body twist over the step."""
    if abs(turn) < 1e-9:
        forward, left = distance, distance * turn / 2  # second order, the arc's chord
    else:
        radius = distance / turn
        forward, left = radius * math.sin(turn), radius * (1.0 - math.cos(turn))
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    return Pose(pose.x + c * forward - s * left, pose.y + s * forward + c * left,
                wrap_angle(pose.theta + turn))


@dataclass(frozen=True, slots=True)
class SkidSteer:
    """The expanded-track skid-steer model (module docstring). Wheel speeds are the wheels'
    own angular speeds in deg/s, positive when driving the body forward."""

    wheel_radius: float  #: m
    track: float  #: m, geometric (between left and right wheel centres)
    chi: float = 1.0  #: ≥ 1, per surface
    #: each side's rolling radius over ``wheel_radius`` (worn or differently inflated
    #: wheels; diff_drive_controller's ``left/right_wheel_radius_multiplier``)
    left_radius_multiplier: float = 1.0
    right_radius_multiplier: float = 1.0

    @property
    def effective_track(self) -> float:
        return self.chi * self.track

    def side_radius(self, left: bool) -> float:
        """The rolling radius of the left (or right) side's wheels, m."""
        return self.wheel_radius * (self.left_radius_multiplier if left
                                    else self.right_radius_multiplier)

    def side_speed(self, wheel_dps: float, left: bool = True) -> float:
        """A side's ground speed, m/s, for its wheels turning at ``wheel_dps``."""
        return math.radians(wheel_dps) * self.side_radius(left)

    def wheel_speeds(self, v: float, omega: float) -> tuple[float, float]:
        """(left, right) wheel speeds, deg/s, for body speed ``v`` (m/s) and yaw rate
        ``omega`` (rad/s): the inverse of eqs. 2.19–2.20."""
        half = omega * self.effective_track / 2.0
        return (math.degrees((v - half) / self.side_radius(True)),
                math.degrees((v + half) / self.side_radius(False)))

    def body_twist(self, left_dps: float, right_dps: float) -> tuple[float, float]:
        """(v m/s, Ω rad/s) from the sides' wheel speeds (eqs. 2.19–2.20)."""
        v_left, v_right = self.side_speed(left_dps, True), self.side_speed(right_dps, False)
        return (v_left + v_right) / 2.0, (v_right - v_left) / self.effective_track

    def icr(self, left_dps: float, right_dps: float) -> tuple[float, float, float]:
        """(ICR_x, ICR_y, R) in the body frame (eqs. 2.21–2.23); ``inf`` for a straight
        line."""
        v, omega = self.body_twist(left_dps, right_dps)
        if omega == 0.0:
            return 0.0, math.inf, math.inf
        icr_y = v / omega
        return 0.0, icr_y, abs(icr_y)

    def displacement(self, left_m: float, right_m: float) -> tuple[float, float]:
        """(distance m, turn rad) of the body for its sides rolling ``left_m``/``right_m``
        of ground: the twist of eqs. 2.19–2.20 integrated over a step."""
        return (left_m + right_m) / 2.0, (right_m - left_m) / self.effective_track


@dataclass(frozen=True, slots=True)
class WheelMount:
    name: str  #: FL, BL, FR, BR
    board: str  #: the board that drives it (L, R)
    channel: int  #: that board's channel code (CHANNEL_A front, CHANNEL_B rear)
    x: float  #: m, forward of the body centre
    y: float  #: m, left of the body centre
    forward: int  #: +1 or −1: the sign of the board's speed that drives the robot forward

    @property
    def left(self) -> bool:
        return self.name in LEFT_WHEELS


@dataclass(frozen=True, slots=True)
class OdometryNoise:
    """How the odometry covariance grows (a standard odometry motion model)."""

    distance_noise: float = 1e-4  #: m² per m travelled
    turn_noise: float = 1.6e-3  #: rad² per rad turned
    drift_noise: float = 1e-4  #: rad² per m travelled


@dataclass(frozen=True, slots=True)
class BodyShape:
    """The chassis as a rigid body (for a physics body and the URDF): m, kg, REP-103, from
    base_link (the centre of the wheel axles, as the seed's URDF has it)."""

    mass: float = 60.0  #: the whole robot, wheels included
    centre_of_mass: tuple[float, float, float] = (-0.048, -0.012, -0.10)  #: whole robot
    wheel_mass: float = 2.5  #: each
    wheel_width: float = 0.10
    chassis: tuple[float, float, float] = (0.80, 0.50, 0.30)  #: box: length, width, height
    chassis_z: float = 0.05  #: the box's centre above base_link
    imu: tuple[float, float, float] = (0.125, -0.03, 0.11)
    lidar: tuple[float, float, float] = (0.39, 0.02, 0.23)

    @property
    def chassis_mass(self) -> float:
        return self.mass - 4 * self.wheel_mass

    def chassis_com(self, wheels: tuple[WheelMount, ...]) -> tuple[float, float, float]:
        """The chassis's own centre of mass: the whole robot's, less its wheels'."""
        cx, cy, cz = self.centre_of_mass
        wx = sum(w.x for w in wheels) * self.wheel_mass
        wy = sum(w.y for w in wheels) * self.wheel_mass
        m = self.chassis_mass
        return ((cx * self.mass - wx) / m, (cy * self.mass - wy) / m, cz * self.mass / m)

    @property
    def chassis_inertia(self) -> tuple[float, float, float]:
        """Principal moments about the chassis's centre of mass: a uniform box."""
        length, width, height = self.chassis
        m = self.chassis_mass / 12.0
        return (m * (width**2 + height**2), m * (length**2 + height**2),
                m * (length**2 + width**2))


@dataclass(frozen=True, slots=True)
class RobotDescription:
    """A robot: its wheels and boards, geometry, limits, surfaces and start-up parameters."""

    name: str
    wheel_radius: float  #: m
    gear_ratio: float
    max_wheel_speed: float  #: deg/s
    max_linear_speed: float  #: m/s
    max_angular_speed: float  #: deg/s
    wheels: tuple[WheelMount, ...]
    surfaces: Mapping[str, float]
    surface: str
    odometry: OdometryNoise = field(default_factory=OdometryNoise)
    #: settings loaded into every board at start, then each board's own
    parameters: tuple[Setting, ...] = ()
    board_parameters: Mapping[str, tuple[Setting, ...]] = field(default_factory=dict)
    body: BodyShape = field(default_factory=BodyShape)

    @property
    def boards(self) -> tuple[str, ...]:
        """Board names in wheel order (L, R for the seed's robot)."""
        return tuple(dict.fromkeys(w.board for w in self.wheels))

    def wheel(self, name: str) -> WheelMount:
        return next(w for w in self.wheels if w.name == name)

    @property
    def track(self) -> float:
        left = [w.y for w in self.wheels if w.left]
        right = [w.y for w in self.wheels if not w.left]
        return sum(left) / len(left) - sum(right) / len(right)

    @property
    def wheelbase(self) -> float:
        return self.wheel("FL").x - self.wheel("BL").x

    @property
    def chi(self) -> float:
        return self.surfaces[self.surface]

    @property
    def max_angular_speed_rad(self) -> float:
        return math.radians(self.max_angular_speed)

    def kinematics(self, surface: str | None = None) -> SkidSteer:
        chi = self.surfaces[surface] if surface is not None else self.chi
        return SkidSteer(self.wheel_radius, self.track, chi)

    def on_surface(self, surface: str) -> RobotDescription:
        """The same robot, driving (and computing odometry) for ``surface``."""
        if surface not in self.surfaces:
            raise DescriptionError(f"no surface {surface!r}; the robot knows "
                                   f"{', '.join(sorted(self.surfaces))}")
        return replace(self, surface=surface)

    def settings_for(self, board: str) -> list[Setting]:
        """Start-up settings of ``board``: the common ones, then its own (which win)."""
        chosen: dict[tuple[int, int], Setting] = {}
        for setting in (*self.parameters, *self.board_parameters.get(board, ())):
            chosen[(setting[0].id, setting[1])] = setting
        return list(chosen.values())


def check_board_name(name: object, where: str) -> str:
    """``name`` if it is a board name (:data:`BOARD_NAME`), else :class:`DescriptionError`
    naming ``where``."""
    if not isinstance(name, str) or not BOARD_NAME.fullmatch(name):
        raise DescriptionError(f"{where}: a board name is letters, digits, _ and - (such as "
                               f"\"L\"), got {_shown(name)}")
    return name


def _shown(value: object) -> str:
    """``repr(value)`` cut to a line's worth: a hostile value is not echoed whole."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(table: Mapping[str, Any], key: str, where: str, *, low: float = 0.0,
            low_open: bool = True, high: float = math.inf) -> float:
    if key not in table:
        raise DescriptionError(f"{where}{key}: missing")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
            value) or value < low or (low_open and value == low) or value > high:
        bound = f"> {low:g}" if low_open else f"≥ {low:g}"
        if high != math.inf:
            bound += f" and ≤ {high:g}"
        raise DescriptionError(f"{where}{key}: must be a finite number {bound}, got "
                               f"{_shown(value)}")
    return float(value)


def _unknown(table: Mapping[str, Any], known: frozenset[str], where: str) -> None:
    extra = sorted(set(table) - known)
    if extra:
        raise DescriptionError(f"{where}{extra[0]}: unknown key (known: "
                               f"{', '.join(sorted(known))})")


def parse_robot(document: Mapping[str, Any] | str, source: str = "robot") -> RobotDescription:
    """A robot file (TOML text, or the parsed table) → a validated description;
    :class:`DescriptionError` naming ``source`` and the key otherwise."""
    if isinstance(document, str):
        try:
            document = parse_toml(document, source)
        except TomlFileError as exc:
            raise DescriptionError(str(exc)) from None
    if not isinstance(document, Mapping):
        raise DescriptionError(f"{source}: not a robot description (a TOML table)")
    try:
        return _parse_robot(document, f"{source}: ")
    except (TypeError, ValueError, AttributeError, KeyError, OverflowError,
            RecursionError) as exc:
        if isinstance(exc, DescriptionError):
            raise
        # A value of a type no check above foresaw: still one line naming the file.
        raise DescriptionError(f"{source}: a value of the wrong type "
                               f"({type(exc).__name__}: {exc})") from None


#: The robot's top speeds and sizes: key → (lowest, highest), both accepted.
_LIMITS: dict[str, tuple[float, float]] = {
    "wheel_radius": (MIN_WHEEL_RADIUS, 10.0),
    "gear_ratio": (MIN_GEAR_RATIO, 1e4),
    "max_wheel_speed": (MIN_WHEEL_SPEED, 1e5),
    "max_linear_speed": (MIN_LINEAR_SPEED, 100.0),
    "max_angular_speed": (MIN_ANGULAR_SPEED, 1e4),
}


def _parse_robot(document: Mapping[str, Any], where: str) -> RobotDescription:
    """The description, each section read by its reader in the order the errors are found:
    the top-level keys, the name and limits, the surfaces, the wheels, odometry, the body,
    the parameters; then the geometry as a whole."""
    _unknown(document, _TOP_KEYS, where)
    name = document.get("name", "robot")
    if not isinstance(name, str):
        raise DescriptionError(f"{where}name: must be a string, got {_shown(name)}")
    limits = {key: _number(document, key, where, low=low, low_open=False, high=high)
              for key, (low, high) in _LIMITS.items()}
    surfaces, surface = _surfaces(document, where)
    wheels = _wheels(document.get("wheels"), where)
    noise = _odometry(document.get("odometry", {}), f"{where}odometry.")
    body = _body(document.get("body", {}), f"{where}body.")
    boards = tuple(dict.fromkeys(w.board for w in wheels))
    common = _settings(document.get("parameters", {}), f"{where}parameters")
    per_board = _board_settings(document.get("board_parameters", {}), boards, where)
    description = RobotDescription(
        name=name, **limits, wheels=wheels, surfaces=surfaces, surface=surface,
        odometry=noise, parameters=common, board_parameters=per_board, body=body)
    _check_geometry(description, where)
    return description


def _surfaces(document: Mapping[str, Any], where: str) -> tuple[dict[str, float], str]:
    """``[surfaces]`` (NAME = chi) and the ``surface`` the robot is on, one of them."""
    surfaces_table = document.get("surfaces", {"ideal": 1.0})
    if not isinstance(surfaces_table, dict) or not surfaces_table:
        raise DescriptionError(f"{where}surfaces: must be a table of NAME = chi")
    surfaces = {str(k): _number(surfaces_table, k, f"{where}surfaces.", low=1.0,
                                low_open=False, high=10.0) for k in surfaces_table}
    surface = document.get("surface", next(iter(surfaces)))
    if not isinstance(surface, str) or surface not in surfaces:
        raise DescriptionError(f"{where}surface: {_shown(surface)} is not in [surfaces] "
                               f"({', '.join(sorted(surfaces))})")
    return surfaces, str(surface)


def _wheels(wheels_table: object, where: str) -> tuple[WheelMount, ...]:
    """``[wheels.FL]`` … ``[wheels.BR]``, each channel of a board driving one wheel."""
    if not isinstance(wheels_table, dict):
        raise DescriptionError(f"{where}wheels: missing (tables [wheels.FL], [wheels.BL], "
                               "[wheels.FR], [wheels.BR])")
    _unknown(wheels_table, frozenset(WHEEL_NAMES), f"{where}wheels.")
    wheels = tuple(_wheel(wheel_name, wheels_table.get(wheel_name), where)
                   for wheel_name in WHEEL_NAMES)
    used: dict[tuple[str, int], str] = {}
    for wheel in wheels:
        other = used.setdefault((wheel.board, wheel.channel), wheel.name)
        if other != wheel.name:
            raise DescriptionError(f"{where}wheels.{wheel.name}: board {wheel.board} channel "
                                   f"{'AB'[wheel.channel - 1]} already drives {other}")
    return wheels


def _wheel(wheel_name: str, entry: object, where: str) -> WheelMount:
    """One ``[wheels.NAME]`` table: its board and channel, where it is, its forward sign."""
    at = f"{where}wheels.{wheel_name}."
    if not isinstance(entry, dict):
        raise DescriptionError(f"{where}wheels.{wheel_name}: missing")
    _unknown(entry, _WHEEL_KEYS, at)
    board = check_board_name(entry.get("board"), f"{at}board")
    channel = entry.get("channel")
    if not isinstance(channel, str) or channel not in _CHANNELS:
        raise DescriptionError(f"{at}channel: must be \"A\" or \"B\", got "
                               f"{_shown(channel)}")
    forward = entry.get("forward", 1)
    if isinstance(forward, bool) or not isinstance(forward, int) or forward not in (1, -1):
        raise DescriptionError(f"{at}forward: must be 1 or -1, got {_shown(forward)}")
    x = _number(entry, "x", at, low=-100.0, low_open=False, high=100.0)
    y = _number(entry, "y", at, low=-100.0, low_open=False, high=100.0)
    if (y > 0) != (wheel_name in LEFT_WHEELS) or y == 0:
        side = "left (y > 0)" if wheel_name in LEFT_WHEELS else "right (y < 0)"
        raise DescriptionError(f"{at}y: {wheel_name} is a {side} wheel in REP-103 "
                               f"(x forward, y left), got {y!r}")
    if abs(y) < MIN_WHEEL_OFFSET:
        raise DescriptionError(f"{at}y: a wheel at least {MIN_WHEEL_OFFSET:g} m from the "
                               f"centre line (the track is at least "
                               f"{2 * MIN_WHEEL_OFFSET:g} m), got {y!r}")
    return WheelMount(wheel_name, board, _CHANNELS[channel], x, y, int(forward))


def _odometry(table: object, where: str) -> OdometryNoise:
    if not isinstance(table, dict):
        raise DescriptionError(f"{where[:-1]}: must be a table")
    _unknown(table, _ODOMETRY_KEYS, where)
    return OdometryNoise(**{
        key: _number(table, key, where, low=0.0, low_open=False, high=1.0)
        for key in _ODOMETRY_KEYS if key in table})


def _board_settings(table: object, boards: tuple[str, ...], where: str
                    ) -> dict[str, tuple[Setting, ...]]:
    """``[board_parameters.NAME]``: each named board's own settings."""
    if not isinstance(table, dict):
        raise DescriptionError(f"{where}board_parameters: must be tables [board_parameters.NAME]")
    per_board: dict[str, tuple[Setting, ...]] = {}
    for board_name, settings in table.items():
        if not isinstance(board_name, str) or board_name not in boards:
            raise DescriptionError(f"{where}board_parameters.{board_name}: no such board "
                                   f"(the wheels name {', '.join(boards)})")
        per_board[board_name] = _settings(settings, f"{where}board_parameters.{board_name}")
    return per_board


def _check_geometry(description: RobotDescription, where: str) -> None:
    """The wheels as a whole: left of right, front ahead of rear, a side's two apart."""
    if description.track <= 0 or description.wheelbase < 0:
        raise DescriptionError(f"{where}wheels: the left wheels must be left of the right "
                               "ones and the front wheels ahead of the rear ones")
    radius = description.wheel_radius
    for front, rear in (("FL", "BL"), ("FR", "BR")):
        base = description.wheel(front).x - description.wheel(rear).x
        if base < 2 * radius:
            raise DescriptionError(
                f"{where}wheels.{front}.x: the front and rear wheels of a side overlap: "
                f"their centres are {base:g} m apart, less than a wheel's diameter "
                f"({2 * radius:g} m)")


def _vector(table: Mapping[str, Any], key: str, where: str, limit: float) -> tuple[
        float, float, float]:
    value = table[key]
    if not isinstance(value, list) or len(value) != 3:
        raise DescriptionError(f"{where}{key}: must be [x, y, z], got {value!r}")
    return (_number({"x": value[0]}, "x", f"{where}{key}.", low=-limit, low_open=False,
                    high=limit),
            _number({"y": value[1]}, "y", f"{where}{key}.", low=-limit, low_open=False,
                    high=limit),
            _number({"z": value[2]}, "z", f"{where}{key}.", low=-limit, low_open=False,
                    high=limit))


def _body(table: object, where: str) -> BodyShape:
    if not isinstance(table, dict):
        raise DescriptionError(f"{where[:-1]}: must be a table")
    _unknown(table, _BODY_KEYS, where)
    values: dict[str, Any] = {}
    for key in ("mass", "wheel_mass", "wheel_width"):
        if key in table:
            values[key] = _number(table, key, where, high=1e5)
    if "chassis_z" in table:
        values["chassis_z"] = _number(table, "chassis_z", where, low=-10.0, low_open=False,
                                      high=10.0)
    for key in ("centre_of_mass", "imu", "lidar"):
        if key in table:
            values[key] = _vector(table, key, where, 100.0)
    if "chassis" in table:
        size = _vector(table, "chassis", where, 100.0)
        if min(size) <= 0:
            raise DescriptionError(f"{where}chassis: sizes must be > 0, got {list(size)}")
        values["chassis"] = size
    body = BodyShape(**values)
    if body.chassis_mass <= 0:
        raise DescriptionError(f"{where}mass: the four wheels ({4 * body.wheel_mass:g} kg) "
                               f"weigh more than the robot ({body.mass:g} kg)")
    return body


def _settings(table: object, where: str) -> tuple[Setting, ...]:
    if not isinstance(table, dict):
        raise DescriptionError(f"{where}: must be a table of parameter values")
    try:
        return tuple(parse_parameter_table(table, where))
    except ParameterError as exc:
        raise DescriptionError(str(exc)) from None


def load_robot(path: str, text: str | None = None) -> RobotDescription:
    """The robot file at ``path`` (``text`` when the caller already read it)."""
    if text is None:
        try:
            document = load_toml(path)
        except TomlFileError as exc:
            raise DescriptionError(str(exc)) from None
        return parse_robot(document, path)
    return parse_robot(text, path)


def seed_robot() -> RobotDescription:
    """The seed's robot, as :data:`SEED_ROBOT_TOML` describes it."""
    return parse_robot(SEED_ROBOT_TOML, "the built-in seed robot")
