"""The link's two small state machines as data tables (h11 style): what each input does to
the board's liveness and to the host's enable request. Anything not in a table is a no-op."""

from __future__ import annotations

from enum import Enum

__all__ = ["EnableState", "Liveness", "LivenessInput", "next_liveness"]


class Liveness(Enum):
    UNKNOWN = "unknown"  #: nothing heard yet
    ALIVE = "alive"
    LOST = "lost"  #: silent for longer than the liveness timeout


class LivenessInput(Enum):
    HEARD = "heard"  #: a well-formed message (``E``, ``TM``, ``PA`` …) arrived
    SILENT = "silent"  #: the liveness deadline passed without one


class EnableState(Enum):
    DISABLED = "disabled"
    ENABLED = "enabled"  #: we send ``RE`` every heartbeat interval


LIVENESS_TABLE: dict[tuple[Liveness, LivenessInput], Liveness] = {
    (Liveness.UNKNOWN, LivenessInput.HEARD): Liveness.ALIVE,
    (Liveness.UNKNOWN, LivenessInput.SILENT): Liveness.LOST,
    (Liveness.ALIVE, LivenessInput.HEARD): Liveness.ALIVE,
    (Liveness.ALIVE, LivenessInput.SILENT): Liveness.LOST,
    (Liveness.LOST, LivenessInput.HEARD): Liveness.ALIVE,
    (Liveness.LOST, LivenessInput.SILENT): Liveness.LOST,
}


def next_liveness(state: Liveness, event: LivenessInput) -> Liveness:
    return LIVENESS_TABLE[(state, event)]
