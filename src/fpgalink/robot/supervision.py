"""Supervision (the seed's HeartBeat and GlobalEnable nodes), sans-I/O: the robot is enabled
only while every board is alive and ready and the caller keeps renewing its enable — a
deadman, as the seed's ``/globalEnable`` had to arrive every 500 ms.

A lapse, a board going silent, restarting, its telemetry stopping or its watchdog disabling
it, or a robot task failing: each disables every board at once and says why (an event,
whatever the state). A board that restarted is not ready until it is reconfigured, one
whose telemetry stopped until it comes again: enable is refused meanwhile, naming the
board and why. After recovery the robot stays disabled until enable is asked for again; it
never re-enables by itself. The transitions are the table :data:`TRANSITIONS`, and nothing
else."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol import FpgalinkError

__all__ = [
    "DEADMAN_S",
    "TRANSITIONS",
    "Action",
    "Fault",
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
    BOARD_RESTARTED = "board_restarted"  #: a board restarted (not ready: reconfiguring)
    TELEMETRY_STALE = "telemetry_stale"  #: a board's telemetry stopped (not ready)
    WATCHDOG_LAPSED = "watchdog_lapsed"  #: a board's watchdog disabled it
    TASK_FAILED = "task_failed"  #: a robot task failed (the robot is not ready any more)
    ENABLE_FAILED = "enable_failed"  #: a board's link could not send its enable


class Action(Enum):
    ENABLE_ALL = "enable_all"  #: RE to every board (and keep their heartbeats)
    DISABLE_ALL = "disable_all"  #: RD to every board, at once
    RENEW = "renew"  #: push the deadman deadline out


class StopReason(Enum):
    DEADMAN = "the enable was not renewed within the deadman time"
    BOARD_LOST = "a board stopped answering"
    BOARD_RESTARTED = "a board restarted"
    TELEMETRY_STALE = "a board's telemetry stopped"
    WATCHDOG_LAPSED = "a board disabled itself"
    TASK_FAILED = "a robot task failed"
    ENABLE_FAILED = "a board could not be enabled"
    REQUESTED = "disable was asked for"


class Fault(Enum):
    """What a board's link reported, and the supervision input it is."""

    RESTARTED = Input.BOARD_RESTARTED
    TELEMETRY_STALE = Input.TELEMETRY_STALE
    WATCHDOG_LAPSED = Input.WATCHDOG_LAPSED


#: Faults after which a board is not ready until it recovers (the others stop the robot, and
#: enable may be asked for again at once).
BLOCKING = frozenset({Fault.RESTARTED, Fault.TELEMETRY_STALE})


@dataclass(frozen=True, slots=True)
class SupervisionEvent:
    """The robot was enabled (``reason is None``) or stopped, when, and why; or a board is
    ready again (``recovered``: the robot stays as it is)."""

    at: float
    state: State
    reason: StopReason | None = None
    board: str | None = None  #: the board the stop is about
    detail: str = ""
    recovered: bool = False

    def describe(self) -> str:
        if self.recovered:
            return f"board {self.board} ready again" + (f": {self.detail}" if self.detail
                                                        else "")
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
    # A fault while disabled changes nothing on the wire, and is still said.
    (State.DISABLED, Input.BOARD_LOST): (State.DISABLED, (), StopReason.BOARD_LOST),
    (State.DISABLED, Input.BOARD_RESTARTED): (State.DISABLED, (), StopReason.BOARD_RESTARTED),
    (State.DISABLED, Input.TELEMETRY_STALE): (State.DISABLED, (), StopReason.TELEMETRY_STALE),
    (State.DISABLED, Input.WATCHDOG_LAPSED): (State.DISABLED, (), StopReason.WATCHDOG_LAPSED),
    (State.DISABLED, Input.TASK_FAILED): (State.DISABLED, (Action.DISABLE_ALL,),
                                          StopReason.TASK_FAILED),
    # The enable reached some boards and not another: those are disabled again, and said.
    (State.DISABLED, Input.ENABLE_FAILED): (State.DISABLED, (Action.DISABLE_ALL,),
                                            StopReason.ENABLE_FAILED),
    (State.ENABLED, Input.ENABLE): (State.ENABLED, (Action.RENEW,), None),
    (State.ENABLED, Input.ENABLE_REFUSED): (State.DISABLED, (Action.DISABLE_ALL,),
                                            StopReason.BOARD_LOST),
    (State.ENABLED, Input.DISABLE): (State.DISABLED, (Action.DISABLE_ALL,),
                                     StopReason.REQUESTED),
    (State.ENABLED, Input.DEADMAN_LAPSED): (State.DISABLED, (Action.DISABLE_ALL,),
                                            StopReason.DEADMAN),
    (State.ENABLED, Input.BOARD_LOST): (State.DISABLED, (Action.DISABLE_ALL,),
                                        StopReason.BOARD_LOST),
    (State.ENABLED, Input.BOARD_RESTARTED): (State.DISABLED, (Action.DISABLE_ALL,),
                                             StopReason.BOARD_RESTARTED),
    (State.ENABLED, Input.TELEMETRY_STALE): (State.DISABLED, (Action.DISABLE_ALL,),
                                             StopReason.TELEMETRY_STALE),
    (State.ENABLED, Input.WATCHDOG_LAPSED): (State.DISABLED, (Action.DISABLE_ALL,),
                                             StopReason.WATCHDOG_LAPSED),
    (State.ENABLED, Input.TASK_FAILED): (State.DISABLED, (Action.DISABLE_ALL,),
                                         StopReason.TASK_FAILED),
    (State.ENABLED, Input.ENABLE_FAILED): (State.DISABLED, (Action.DISABLE_ALL,),
                                           StopReason.ENABLE_FAILED),
}


class NotReady(FpgalinkError):
    """Enable was asked for while a board is not answering or not ready (reconfiguring
    after a restart, its telemetry stopped), or after a robot task failed. ``actions``:
    what must still be carried out (a robot that was enabled is stopped)."""

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
        #: why a board is not ready (a restart being reconfigured, telemetry stopped), by
        #: board; ``"robot"`` when a robot task failed
        self.blocked: dict[str, str] = {}
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
        alive or not ready (and, if the robot was enabled, everything is stopped first)."""
        silent = [name for name, alive in self.alive.items() if not alive]
        if silent:
            actions = self._apply(Input.ENABLE_REFUSED, now, silent[0], "enable refused")
            raise NotReady(f"board {', '.join(silent)} not answering: the robot stays "
                           "disabled", actions)
        if self.blocked:
            name, why = next(iter(self.blocked.items()))
            actions = self._apply(Input.ENABLE_REFUSED, now, name, "enable refused")
            what = "the robot" if name == "robot" else f"board {name}"
            raise NotReady(f"{what}: {why}: the robot stays disabled", actions)
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

    def board_fault(self, board: str, fault: Fault, now: float, detail: str = ""
                    ) -> list[Action]:
        """A board restarted, its telemetry stopped, or its watchdog disabled it: the robot
        stops (whatever its state, the fault is an event). After a restart or stopped
        telemetry the board is not ready until :meth:`board_ready`."""
        if fault in BLOCKING:
            self.blocked[board] = detail or fault.name.lower()
        return self._apply(fault.value, now, board, detail)

    def board_ready(self, board: str, now: float, detail: str = "") -> list[Action]:
        """The board recovered (reconfigured, telemetry flowing): enable may be asked for
        again. Nothing is enabled by it."""
        if self.blocked.pop(board, None) is not None:
            self._events.append(SupervisionEvent(now, self.state, None, board, detail,
                                                 recovered=True))
        return []

    def enable_failed(self, board: str, now: float, detail: str) -> list[Action]:
        """``board``'s link could not send the enable (its port gone, say): an enable that
        failed on any board is a failed enable, every board disabled and the reason
        said."""
        return self._apply(Input.ENABLE_FAILED, now, board, detail)

    def task_failed(self, now: float, detail: str) -> list[Action]:
        """A robot task failed: every board stops, and the robot is not ready any more."""
        self.blocked["robot"] = f"a robot task failed ({detail})"
        return self._apply(Input.TASK_FAILED, now, None, detail)

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
