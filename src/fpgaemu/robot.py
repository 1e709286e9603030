"""The emulated robot: two boards (``L``, ``R``) whose four wheels move one body — the
seed's robot wired as the robot description says. Two bodies:

* ``mujoco`` (:mod:`fpgaemu.physics`, the default where MuJoCo is installed): a rigid body on
  a physics engine, driven by the motors' torque; the wheels slip and carry the ground's
  load, so odometry, controllers and localisation meet something they do not contain;
* ``kinematic`` (:mod:`fpgaemu.body`): the expanded-track model the host's odometry uses,
  fast and exact — for testing the protocol, the boards and the host's own arithmetic.

The boards keep their own timelines; :meth:`EmulatedRobot.run_until` advances them in
lockstep with the body. The kinematic body follows the wheels' angles after every 1 ms
step, never ahead of either board. The physics body steps first (2 ms at a time, with the
motors' torques at the step's start) and the boards then run through the step, their
encoders following the wheels' motion within it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

from fpgaemu import physics
from fpgaemu.board import Board
from fpgaemu.body import Body, BodyState
from fpgaemu.build import build_board, parse_emu_options, seed_option
from fpgaemu.motor import PHYSICS_STEP_CYCLES, DrivenMotors, Motors
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol.robot import RobotDescription, WheelMount, load_robot, seed_robot

__all__ = ["BODIES", "ROBOT_OPTIONS", "EmulatedRobot", "check_body", "default_body",
           "robot_from_options", "robot_from_url"]

#: The query options of an ``emu://robot/NAME`` URL: ``fault=L:SPEC`` names the board a
#: fault applies to, ``robot`` a robot file (default: the seed's robot), ``body`` the body.
#: ``run`` names one in-process robot among others with the same options (a campaign runs
#: several in one process); the emulator itself does not read it.
ROBOT_OPTIONS = ("seed", "gear", "fault", "surface", "robot", "body", "uart_rx", "tx_gap",
                 "run")
#: The bodies an emulated robot can have.
BODIES = ("mujoco", "kinematic")

_log = logging.getLogger("fpgaemu")
_said_fallback = False


def default_body(surface: str | None = None) -> str:
    """``mujoco`` where MuJoCo is installed (said once on the ``fpgaemu`` logger when it is
    not), unless ``surface`` is one only the kinematic body knows (``ideal``: no slip, which
    no physical ground gives, or a robot file's own): then ``kinematic``."""
    global _said_fallback
    if surface is not None and surface not in physics.SURFACES:
        return "kinematic"
    missing = physics.why_unavailable()
    if missing is None:
        return "mujoco"
    if not _said_fallback:
        _said_fallback = True
        _log.warning("the emulated robot's body is the kinematic one: %s", missing)
    return "kinematic"


def check_body(body: str, surface: str | None, description: RobotDescription) -> None:
    """``ValueError`` (one line) for a body or surface the emulator cannot serve."""
    if body not in BODIES:
        raise ValueError(f"body {body!r}: choose {' or '.join(BODIES)}")
    if body == "mujoco":
        missing = physics.why_unavailable()
        if missing is not None:
            raise ValueError(f"body mujoco: {missing}")
        if surface is not None and surface not in physics.SURFACES:
            raise ValueError(f"surface {surface!r}: the mujoco body knows "
                             f"{', '.join(physics.SURFACES)}")
    elif surface is not None and surface not in description.surfaces:
        known = f"the kinematic body knows {', '.join(description.surfaces)}"
        ground = physics.SURFACES.get(surface)
        if ground is None:
            raise ValueError(f"surface {surface!r}: {known}; the mujoco body "
                             f"{', '.join(physics.SURFACES)}")
        flat = " (it is flat: slopes and stairs need the mujoco body)" \
            if ground.slope_deg or ground.steps else ""
        raise ValueError(f"surface {surface!r}: {known}{flat}")


class EmulatedRobot:
    """Boards by name, their wheels, and the body they move."""

    def __init__(
        self,
        description: RobotDescription | None = None,
        surface: str | None = None,
        *,
        baud: int = 1_000_000,
        seed: int = 0,
        gear: str = "high",
        faults: Mapping[str, list[str]] | None = None,
        settings: Mapping[str, int | float] | None = None,
        firmware: str = "python",
        body: str | None = None,
        uart_rx: str = "edge",
        tx_byte_gap: int = 0,
        physics_step_cycles: int = physics.STEP_CYCLES,
        identity: bool = True,
        declarations: int | None = None,
    ) -> None:
        self.description = description or seed_robot()
        surface = surface or self.description.surface
        self.body_kind = body = body if body is not None else default_body(surface)
        check_body(body, surface, self.description)
        if surface in self.description.surfaces:
            self.description = self.description.on_surface(surface)
        faults = faults or {}
        unknown = sorted(set(faults) - set(self.description.boards))
        if unknown:
            raise ValueError(f"faults for board {unknown[0]!r}: the robot's boards are "
                             f"{', '.join(self.description.boards)}")
        self.boards: dict[str, Board] = {
            name: build_board(baud=baud, seed=seed + index, gear=gear,
                              settings=dict(settings or {}),
                              faults=list(faults.get(name, [])), firmware=firmware,
                              wheels="driven" if body == "mujoco" else "identified",
                              uart_rx=uart_rx, tx_byte_gap=tx_byte_gap,
                              identity=identity, declarations=declarations)
            for index, name in enumerate(self.description.boards)
        }
        self._motors = {name: self._motors_of(board) for name, board in self.boards.items()}
        # Each board's motors with the cycle getter they follow, and each wheel's plant by
        # name: the same objects for the robot's life, looked up once.
        self._settled = [(motors, self.boards[name]) for name, motors in self._motors.items()]
        self._plants = [(w.name, self.wheel(w)) for w in self.description.wheels]
        self._board_list = list(self.boards.values())
        self.now = 0
        self.body = Body(self.description)
        self.physics: physics.PhysicsBody | None = None
        if body == "mujoco":
            self.physics = physics.PhysicsBody(
                self.description, dict(self._plants), self.body.mount, surface, seed=seed,
                step_cycles=physics_step_cycles)
            self._driven = [m for m, _ in self._settled if isinstance(m, DrivenMotors)]
        self.surface = surface
        self._follow()

    @staticmethod
    def _motors_of(board: Board) -> Motors | DrivenMotors:
        motors = board.peripherals["motors"]
        assert isinstance(motors, Motors | DrivenMotors)
        return motors

    def wheel(self, mount: WheelMount | str) -> Any:
        """The motor plant of a wheel (``"FL"``…), e.g. to stall it in a test."""
        if isinstance(mount, str):
            mount = self.description.wheel(mount)
        return self._motors[mount.board].wheels[mount.channel]

    def _follow(self) -> None:
        if self.physics is not None:
            return
        for motors, board in self._settled:
            motors.advance_to(board.now)
        self.body.follow(self.now / CLOCK_HZ,
                         {name: plant.angle_deg for name, plant in self._plants})

    def run_until(self, cycle: int) -> None:
        """Every board and the body up to ``cycle``."""
        if self.physics is not None:
            self._run_physics(cycle)
            return
        boards = self._board_list
        while self.now < cycle:
            step = min(cycle, self.now + PHYSICS_STEP_CYCLES)
            if step < cycle and all(board.quiescent for board in boards):
                # Every board idle and every wheel exactly at rest: the body cannot move
                # before some board's next event that may change something, so whole
                # physics steps up to it are one step (on the same grid, the same result).
                quiet_until = min(
                    (d for board in boards if (d := board.next_deadline()) is not None),
                    default=cycle)
                whole = (min(cycle, quiet_until) - self.now) // PHYSICS_STEP_CYCLES
                step = max(step, self.now + whole * PHYSICS_STEP_CYCLES)
            for board in boards:
                board.run_until(step)
            self.now = step
            self._follow()

    def _run_physics(self, cycle: int) -> None:
        """The physics steps first (the drives' torques at the step's start); the boards
        then run up to the end of the step, or to ``cycle`` if that comes first."""
        body = self.physics
        assert body is not None
        boards, driven = self._board_list, self._driven
        step = body.step_cycles
        while self.now < cycle:
            if self.now >= body.cycle:
                end = body.cycle + step
                for motors in driven:
                    motors.prepare_step(self.now)
                if body.asleep and end < cycle and all(b.quiescent for b in boards):
                    quiet_until = min(
                        (d for b in boards if (d := b.next_deadline()) is not None),
                        default=cycle)
                    whole = (min(cycle, quiet_until) - body.cycle) // step
                    end = max(end, body.cycle + whole * step)
                body.advance(end)
            target = min(cycle, body.cycle)
            for board in boards:
                board.run_until(target)
            self.now = target

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now + round(seconds * CLOCK_HZ))

    def truth(self) -> BodyState:
        body = self.physics
        if body is None:
            return self.body.state()
        pose = body.pose()
        v, omega = body.twist() if not body.lifted else (0.0, 0.0)
        roll, pitch, _ = body.attitude() if not body.lifted else (0.0, 0.0, 0.0)
        z = float(body.data.qpos[2]) if not body.lifted else 0.0
        return BodyState(body.t, pose, v, omega, body.distance, self.surface, "mujoco", z,
                         roll, pitch, body.read_imu())


def robot_from_url(url: str) -> tuple[str, str, dict[str, list[str]]] | None:
    """``emu://robot/L?surface=marble`` → (the robot's identity: its options, the board
    ``L``, the options); ``None`` for a one-board URL."""
    parts = urlsplit(url)
    if parts.scheme != "emu" or parts.netloc != "robot":
        return None
    side = parts.path.strip("/")
    if not side or "/" in side:
        raise ValueError("expected emu://robot/BOARD (emu://robot/L, emu://robot/R) with "
                         f"optional ?{'&'.join(ROBOT_OPTIONS)} options")
    options = parse_emu_options(parts.query, ROBOT_OPTIONS, "emu://robot")
    key = "&".join(f"{k}={v}" for k in sorted(options) for v in options[k])
    return key, side, options


def robot_from_options(options: dict[str, list[str]], baud: int) -> EmulatedRobot:
    """An emulated robot from ``emu://robot/…`` options."""
    path = options.get("robot", [""])[-1]
    description = load_robot(path) if path else seed_robot()
    faults: dict[str, list[str]] = {}
    for spec in options.get("fault", []):
        board, sep, fault = spec.partition(":")
        if not sep or board not in description.boards:
            raise ValueError(f"emu://robot fault {spec!r}: write BOARD:SPEC, BOARD one of "
                             f"{', '.join(description.boards)}")
        faults.setdefault(board, []).append(fault)
    surface = options.get("surface", [None])[-1]
    body = options.get("body", [None])[-1]
    gap_text = options.get("tx_gap", ["0"])[-1]
    if not gap_text.isdigit():
        raise ValueError(f"emu:// tx_gap must be a whole number of cycles, got {gap_text!r}")
    return EmulatedRobot(description, surface, baud=baud, seed=seed_option(options),
                         gear=options.get("gear", ["high"])[-1], faults=faults, body=body,
                         uart_rx=options.get("uart_rx", ["edge"])[-1],
                         tx_byte_gap=int(gap_text))
