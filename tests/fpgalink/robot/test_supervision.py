"""Supervision as a table: enabled only while every board is alive and the deadman is
renewed; any lapse disables every board, says why, and never re-enables by itself."""

from __future__ import annotations

import pytest

from fpgalink.robot.supervision import (
    TRANSITIONS,
    Action,
    Input,
    NotReady,
    State,
    StopReason,
    Supervisor,
)


def ready(now: float = 0.0) -> Supervisor:
    supervisor = Supervisor(("L", "R"))
    supervisor.board_alive("L", True, now)
    supervisor.board_alive("R", True, now)
    return supervisor


def current(supervisor: Supervisor) -> State:
    """The state now (a call, so a type checker does not carry an earlier check over)."""
    return supervisor.state


def test_the_table_covers_every_state_and_input() -> None:
    assert set(TRANSITIONS) == {(s, i) for s in State for i in Input}


def test_enable_needs_every_board_alive() -> None:
    supervisor = Supervisor(("L", "R"))
    supervisor.board_alive("L", True, 0.0)
    with pytest.raises(NotReady, match="board R not answering") as caught:
        supervisor.request_enable(0.0)
    assert caught.value.actions == [] and supervisor.state is State.DISABLED
    supervisor.board_alive("R", True, 0.1)
    assert supervisor.request_enable(0.1) == [Action.ENABLE_ALL]
    assert current(supervisor) is State.ENABLED
    assert [e.state for e in supervisor.events()] == [State.ENABLED]


def test_the_deadman_lapses_half_a_second_after_the_last_renewal() -> None:
    supervisor = ready()
    supervisor.request_enable(0.0)
    assert supervisor.request_enable(0.4) == []  # renewed: nothing to send
    assert supervisor.get_timer() == pytest.approx(0.9)
    assert supervisor.handle_timer(0.89) == []
    assert supervisor.handle_timer(0.9) == [Action.DISABLE_ALL]
    stop = supervisor.events()[-1]
    assert stop.reason is StopReason.DEADMAN and supervisor.state is State.DISABLED
    assert supervisor.get_timer() is None


def test_a_silent_board_stops_every_board_and_is_named() -> None:
    supervisor = ready()
    supervisor.request_enable(0.0)
    supervisor.events()
    assert supervisor.board_alive("R", False, 0.2, "silent for 0.700 s") == [Action.DISABLE_ALL]
    (stop,) = supervisor.events()
    assert stop.reason is StopReason.BOARD_LOST and stop.board == "R"
    assert "board R" in stop.describe() and "silent for 0.700 s" in stop.describe()


def test_recovery_does_not_re_enable() -> None:
    supervisor = ready()
    supervisor.request_enable(0.0)
    supervisor.board_alive("L", False, 0.1)
    assert supervisor.board_alive("L", True, 0.5) == []
    assert supervisor.state is State.DISABLED
    assert supervisor.handle_timer(10.0) == []  # no deadman while disabled
    assert supervisor.request_enable(11.0) == [Action.ENABLE_ALL]  # only when asked


def test_a_renewal_after_a_lapse_is_a_new_enable() -> None:
    supervisor = ready()
    supervisor.request_enable(0.0)
    supervisor.handle_timer(0.5)
    assert supervisor.state is State.DISABLED
    assert supervisor.request_enable(0.6) == [Action.ENABLE_ALL]  # asked for again


def test_the_deadman_must_be_positive() -> None:
    with pytest.raises(ValueError, match="deadman_s"):
        Supervisor(("L",), deadman_s=float("nan"))
