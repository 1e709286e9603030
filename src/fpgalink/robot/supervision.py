"""Supervision (the seed's HeartBeat and GlobalEnable nodes), sans-I/O: the robot is enabled
only while every board is alive and the caller keeps renewing its enable — a deadman, as
the seed's ``/globalEnable`` had to arrive every 500 ms.

A lapse, or any board going silent, disables every board at once and says why; after
recovery the robot stays disabled until enable is asked for again. It never re-enables by
itself. The transitions are the table :data:`TRANSITIONS`, and nothing else."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol import FpgalinkError

__all__ = [
    "DEADMAN_S",
    "TRANSITIONS",
    "Action",
    "Input",
    "NotReady",
    "State",
    "StopReason",
    "SupervisionEvent",
    "Supervisor",
]

#: How long an enable lasts without renewal (the seed's /globalEnable period).
DEADMAN_S = 0.5


class State(Enum):
    DISABLED = "disabled"  #: motors off; enable must be asked for
    ENABLED = "enabled"  #: every board enabled; the deadman is being renewed


class Input(Enum):
    ENABLE = "enable"  #: asked for (or renewed) with every board alive
    ENABLE_REFUSED = "enable_refused"  #: asked for while a board is not alive
    DISABLE = "disable"  #: asked for
    DEADMAN_LAPSED = "deadman_lapsed"  #: not renewed within the deadman time
    BOARD_LOST = "board_lost"  #: a board went silent or its port went away


class Action(Enum):
    ENABLE_ALL = "enable_all"  #: RE to every board (and keep their heartbeats)
    DISABLE_ALL = "disable_all"  #: RD to every board, at once
    RENEW = "renew"  #: push the deadman deadline out


class StopReason(Enum):
    DEADMAN = "the enable was not renewed within the deadman time"
    BOARD_LOST = "a board stopped answering"
    REQUESTED = "disable was asked for"


@dataclass(frozen=True, slots=True)
class SupervisionEvent:
    """The robot was enabled (``reason is None``) or stopped, when, and why."""

    at: float
    state: State
    reason: StopReason | None = None
    board: str | None = None  #: the board that went silent
    detail: str = ""

    def describe(self) -> str:
        if self.reason is None:
            return "enabled"
        which = f" (board {self.board})" if self.board else ""
        tail = f": {self.detail}" if self.detail else ""
        return f"stopped: {self.reason.value}{which}{tail}"


#: (state, input) → (next state, actions, event: None, "enabled" or a stop reason)
TRANSITIONS: dict[tuple[State, Input], tuple[State, tuple[Action, ...], object]] = {
    (State.DISABLED, Input.ENABLE): (State.ENABLED, (Action.ENABLE_ALL, Action.RENEW),
                                     "enabled"),
    (State.DISABLED, Input.ENABLE_REFUSED): (State.DISABLED, (), None),
    (State.DISABLED, Input.DISABLE): (State.DISABLED, (Action.DISABLE_ALL,), None),
    (State.DISABLED, Input.DEADMAN_LAPSED): (State.DISABLED, (), None),
    (State.DISABLED, Input.BOARD_LOST): (State.DISABLED, (), None),
    (State.ENABLED, Input.ENABLE): (State.ENABLED, (Action.RENEW,), None),
    (State.ENABLED, Input.ENABLE_REFUSED): (State.DISABLED, (Action.DISABLE_ALL,),
                                            StopReason.BOARD_LOST),
    (State.ENABLED, Input.DISABLE): (State.DISABLED, (Action.DISABLE_ALL,),
                                     StopReason.REQUESTED),
    (State.ENABLED, Input.DEADMAN_LAPSED): (State.DISABLED, (Action.DISABLE_ALL,),
                                            StopReason.DEADMAN),
    (State.ENABLED, Input.BOARD_LOST): (State.DISABLED, (Action.DISABLE_ALL,),
                                        StopReason.BOARD_LOST),
}


class NotReady(FpgalinkError):
    """Enable was asked for while a board is not answering. ``actions``: what must still be
    carried out (a robot that was enabled is stopped)."""

    def __init__(self, message: str, actions: list[Action]) -> None:
        super().__init__(message)
        self.actions = actions


class Supervisor:
    """Feed it the boards' liveness and the caller's enable requests; carry out the actions
    it returns; read its events. Time is passed in."""

    def __init__(self, boards: tuple[str, ...] | list[str], deadman_s: float = DEADMAN_S
                 ) -> None:
        if not (math.isfinite(deadman_s) and deadman_s > 0):
            raise ValueError(f"deadman_s must be a positive number of seconds, got {deadman_s!r}")
        self.deadman_s = deadman_s
        self.state = State.DISABLED
        self.alive = dict.fromkeys(boards, False)
        self.deadline: float | None = None
        self.last_stop: SupervisionEvent | None = None
        self._events: list[SupervisionEvent] = []

    def _apply(self, event_input: Input, now: float, board: str | None = None,
               detail: str = "") -> list[Action]:
        next_state, actions, outcome = TRANSITIONS[(self.state, event_input)]
        self.state = next_state
        if Action.RENEW in actions:
            self.deadline = now + self.deadman_s
        if next_state is State.DISABLED:
            self.deadline = None
        if outcome == "enabled":
            self._events.append(SupervisionEvent(now, State.ENABLED))
        elif isinstance(outcome, StopReason):
            event = SupervisionEvent(now, State.DISABLED, outcome, board, detail)
            self.last_stop = event
            self._events.append(event)
        return [a for a in actions if a is not Action.RENEW]

    def request_enable(self, now: float) -> list[Action]:
        """Enable, or renew the enable. :class:`NotReady` naming the board when one is not
        alive (and, if the robot was enabled, everything is stopped first)."""
        silent = [name for name, alive in self.alive.items() if not alive]
        if silent:
            actions = self._apply(Input.ENABLE_REFUSED, now, silent[0], "enable refused")
            raise NotReady(f"board {', '.join(silent)} not answering: the robot stays "
                           "disabled", actions)
        return self._apply(Input.ENABLE, now)

    def request_disable(self, now: float) -> list[Action]:
        return self._apply(Input.DISABLE, now)

    def board_alive(self, board: str, alive: bool, now: float, detail: str = ""
                    ) -> list[Action]:
        """A board's liveness changed (or was confirmed)."""
        self.alive[board] = alive
        if alive:
            return []  # coming back never enables anything
        return self._apply(Input.BOARD_LOST, now, board, detail or "silent")

    def get_timer(self) -> float | None:
        """When :meth:`handle_timer` must be called next (the deadman), or ``None``."""
        return self.deadline

    def handle_timer(self, now: float) -> list[Action]:
        if self.deadline is not None and now >= self.deadline:
            return self._apply(Input.DEADMAN_LAPSED, now,
                               detail=f"not renewed for {self.deadman_s:g} s")
        return []

    def events(self) -> list[SupervisionEvent]:
        """Events since the last call, oldest first."""
        events, self._events = self._events, []
        return events
