"""The emulated robot: two boards (``L``, ``R``) whose four wheels move one body
(:mod:`fpgaemu.body`) — the seed's robot wired as the robot description says.

The boards keep their own timelines; :meth:`EmulatedRobot.run_until` advances them in
lockstep, one physics step (1 ms) at a time, and after each step the body follows the
wheels' angles, so the body moves as the wheels turn, never ahead of either board.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

from fpgaemu.board import Board
from fpgaemu.body import Body, BodyState
from fpgaemu.build import build_board, parse_emu_options, seed_option
from fpgaemu.motor import PHYSICS_STEP_CYCLES, Motors
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol.robot import RobotDescription, WheelMount, load_robot, seed_robot

__all__ = ["ROBOT_OPTIONS", "EmulatedRobot", "robot_from_options", "robot_from_url"]

#: The query options of an ``emu://robot/NAME`` URL: ``fault=L:SPEC`` names the board a
#: fault applies to, ``robot`` a robot file (default: the seed's robot).
ROBOT_OPTIONS = ("seed", "gear", "fault", "surface", "robot")


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
    ) -> None:
        self.description = description or seed_robot()
        if surface is not None:
            self.description = self.description.on_surface(surface)
        faults = faults or {}
        unknown = sorted(set(faults) - set(self.description.boards))
        if unknown:
            raise ValueError(f"faults for board {unknown[0]!r}: the robot's boards are "
                             f"{', '.join(self.description.boards)}")
        self.boards: dict[str, Board] = {
            name: build_board(baud=baud, seed=seed + index, gear=gear,
                              settings=dict(settings or {}),
                              faults=list(faults.get(name, [])), firmware=firmware)
            for index, name in enumerate(self.description.boards)
        }
        self.body = Body(self.description)
        self._motors = {name: self._motors_of(board) for name, board in self.boards.items()}
        # Each board's motors with the cycle getter they follow, and each wheel's plant by
        # name: the same objects for the robot's life, looked up once.
        self._settled = [(motors, self.boards[name]) for name, motors in self._motors.items()]
        self._plants = [(w.name, self.wheel(w)) for w in self.description.wheels]
        self.now = 0
        self._follow()

    @staticmethod
    def _motors_of(board: Board) -> Motors:
        motors = board.peripherals["motors"]
        assert isinstance(motors, Motors)
        return motors

    def wheel(self, mount: WheelMount | str) -> Any:
        """The motor plant of a wheel (``"FL"``…), e.g. to stall it in a test."""
        if isinstance(mount, str):
            mount = self.description.wheel(mount)
        return self._motors[mount.board].wheels[mount.channel]

    def _follow(self) -> None:
        for motors, board in self._settled:
            motors.advance_to(board.now)
        self.body.follow(self.now / CLOCK_HZ,
                         {name: plant.angle_deg for name, plant in self._plants})

    def run_until(self, cycle: int) -> None:
        """Every board and the body up to ``cycle``."""
        boards = list(self.boards.values())
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

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now + round(seconds * CLOCK_HZ))

    def truth(self) -> BodyState:
        return self.body.state()


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
    return EmulatedRobot(description, surface, baud=baud, seed=seed_option(options),
                         gear=options.get("gear", ["high"])[-1], faults=faults)
