"""A scenario's MCAP recording (docs/campaigns.md): its boards' telemetry, parameters, link
events and statistics, the robot's supervision events, the script's actions, the body's
truth and the host's odometry, every message stamped in emulated seconds from the scenario's
start.

A recording must not change what it records: every hook is a synchronous read (a link
listener, a link event callback, the scenario's own watcher), none starts a task or a timer,
so the emulated-time loop runs the same callbacks at the same times with or without one, and
the figures are the same. A write that fails (a full disk, a directory that cannot be
written) stops the recording, never the scenario: the error is kept for the scenario's
result (``mcap_error``).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fpgalink import __version__
from fpgalink.boardclock import BoardClock
from fpgalink.protocol import Event, ParamAck, ParamNack, Telemetry
from fpgalink.recording import (
    CHANNEL_FIELDS,
    EVENT_SCHEMA,
    POSE_SCHEMA,
    STATS_FIELDS,
    McapSink,
    RecordingError,
    log_record,
    parameter_record,
)

if TYPE_CHECKING:
    from fpgalink.campaign.spec import Action, Scenario
    from fpgalink.events import StatusEvent
    from fpgalink.robot.robot import Robot
    from fpgalink.robot.supervision import SupervisionEvent

__all__ = ["ScenarioRecording", "recording_name"]

#: The truth and the host's odometry at most this often (the truth endpoint's 50 Hz: a path
#: plot's resolution), read at the first telemetry sample after each period.
TRUTH_PERIOD_S = 0.02
STATS_PERIOD_S = 1.0
#: Topics beside each board's: the body's truth, the host's odometry, supervision (enabled,
#: stopped and why, a board ready again) and the script's actions as they start.
TOPICS = {"/robot/truth": POSE_SCHEMA, "/robot/odometry": POSE_SCHEMA,
          "/robot/events": EVENT_SCHEMA, "/scenario/actions": EVENT_SCHEMA}
CLOCK = ("log_time: emulated seconds from the scenario's start (the loop's clock), when the "
         "host received or did it; telemetry publish_time: the board's t_us mapped onto that "
         "clock")


def recording_name(scenario: Scenario, digits: int = 1) -> str:
    """``0007-turn_and_go.mcap``: the index first (names repeat across grid points), then
    the name with what a file name should not hold replaced."""
    slug = re.sub(r"[^\w.-]+", "_", scenario.name).strip("._")[:80] or "scenario"
    return f"{scenario.index:0{digits}d}-{slug}.mcap"


class ScenarioRecording:
    """Open at once (a failure to open is kept in :attr:`error`); :meth:`attach` to the
    robot before it starts; :meth:`close` after the scenario, wherever it ended."""

    def __init__(self, path: Path, scenario: Scenario) -> None:
        self.path = path
        self.error: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._robot: Robot | None = None
        self._removers: list[Callable[[], None]] = []
        self._next_truth = -math.inf
        self._boards: list[_BoardState] = []
        self._last = 0.0  #: the latest log time written: the file's end
        metadata = {
            "scenario": scenario.name, "index": str(scenario.index), "body": scenario.body,
            "surface": scenario.surface, "seed": str(scenario.seed),
            "robot": scenario.description.name, "faults": " ".join(scenario.faults),
            "params": " ".join(f"{p.label}={p.value:g}" for p in scenario.params),
            "grid": " ".join(f"{k}={v}" for k, v in scenario.grid), "clocks": CLOCK}
        self._sink: McapSink | None = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._sink = McapSink(path, list(scenario.description.boards), metadata, TOPICS,
                                  library=f"fpgalink-campaign {__version__}")
        except Exception as exc:  # whatever it was, the scenario runs unrecorded
            self._failed(exc, "cannot write")
            if path.is_file():  # a header and no room for more is no recording
                with contextlib.suppress(OSError):
                    path.unlink()

    @property
    def written(self) -> bool:
        """Whether a file is there (complete, or up to where it stopped)."""
        return self.error is None or self.path.is_file()

    def attach(self, robot: Robot) -> None:
        if self._sink is None:
            return
        self._loop = asyncio.get_running_loop()
        self._robot = robot
        for board, link in robot.links.items():
            state = _BoardState(board)
            self._boards.append(state)
            self._removers.append(link.add_listener(
                functools.partial(self._guard, self._received, state)))
            self._removers.append(link.on_event(
                functools.partial(self._guard, self._link_event, board)))

    # --- hooks (each guarded: a listener must not raise) -----------------------------------

    def _received(self, state: _BoardState, event: Event) -> None:
        now = self._now()
        if type(event) is Telemetry:
            assert isinstance(event, Telemetry)
            sampled = state.clock.seconds(event.t_us, now)
            self._add(state.telemetry_topic, _telemetry_row(event, sampled), now, sampled)
            if now >= self._next_truth:
                self._next_truth = now + TRUTH_PERIOD_S
                self._robot_state(now)
            if now >= state.next_stats:
                self._stats(state, now)
        elif isinstance(event, ParamAck | ParamNack):
            record = parameter_record(event, now)
            if record is not None:
                self._add(f"/board/{state.board}/params", record, now)

    def _link_event(self, board: str, event: StatusEvent) -> None:
        self._add(f"/board/{board}/events",
                  log_record(event.name, event.describe(), event.at, board), self._now())

    def _robot_state(self, now: float) -> None:
        robot = self._robot
        assert robot is not None
        truth = robot.truth()
        if truth is not None:
            self._add("/robot/truth", _finite(truth), now)
        state = robot.odometry_state
        self._add("/robot/odometry", _finite(
            {"t": now, "x": state.pose.x, "y": state.pose.y, "theta": state.pose.theta,
             "v": state.v, "omega": state.omega}), now)

    def _stats(self, state: _BoardState, now: float) -> None:
        assert self._robot is not None
        stats = self._robot.links[state.board].stats
        received = stats.telemetry_received
        span = now - state.stats_at
        rate = (received - state.stats_received) / span if span > 0 else 0.0
        record: dict[str, Any] = {"timestamp": now, "telemetry_rate": round(rate, 6)}
        for name in STATS_FIELDS[1:]:
            record[name] = getattr(stats, name)
        self._add(f"/board/{state.board}/stats", record, now)
        state.stats_at, state.stats_received = now, received
        state.next_stats = now + STATS_PERIOD_S

    # --- what the scenario says -------------------------------------------------------------

    def action(self, action: Action) -> None:
        detail = f"{action.kind} for {action.seconds:g} s"
        self._guard(self._log, "/scenario/actions", action.label, detail, "scenario", 2)

    def supervision(self, event: SupervisionEvent) -> None:
        level = 3 if event.reason is not None and not event.recovered else 2
        self._guard(self._log, "/robot/events", event.describe(), "", "robot", level,
                    event.at)

    def _log(self, topic: str, kind: str, detail: str, name: str, level: int,
             at: float | None = None) -> None:
        now = self._now()
        self._add(topic, log_record(kind, detail, now if at is None else at, name, level),
                  now)

    def close(self, status: str, error: str | None, figures: dict[str, Any]) -> None:
        """The scenario's outcome and figures as the file's ``fpgalink.result`` metadata,
        then the summary. Never raises: a failure is :attr:`error`."""
        for remove in self._removers:
            remove()
        self._removers.clear()
        if self._robot is not None:  # each board's count at the end, links closed
            for state in self._boards:
                self._guard(self._stats, state, self._last)
        sink, self._sink = self._sink, None
        if sink is None:
            return
        result = {"status": status, "error": error or "",
                  **{name: json.dumps(value) for name, value in figures.items()}}
        try:
            sink.metadata("fpgalink.result", result)
        except Exception as exc:
            self._failed(exc, "cannot write")
        try:
            sink.close()
        except RecordingError as exc:
            self.error = self.error or str(exc)
        except Exception as exc:
            self.error = self.error or (
                f"{self.path}: cannot finish: {type(exc).__name__}: {exc}".splitlines()[0])

    def abandon(self) -> None:
        """The campaign is being stopped, by an exception raised wherever the scenario was
        (a write included): the file is left at its last complete chunk, without summary."""
        for remove in self._removers:
            remove()
        self._removers.clear()
        sink, self._sink = self._sink, None
        if sink is not None:
            with contextlib.suppress(Exception):
                sink.abandon()

    # --- plumbing ---------------------------------------------------------------------------

    def _now(self) -> float:
        # The loop's clock, not the link's (Link._now keeps state): reading it changes nothing.
        return self._loop.time() if self._loop is not None else 0.0

    def _add(self, topic: str, record: dict[str, Any], log_time: float,
             publish_time: float | None = None) -> None:
        if self._sink is not None:
            self._sink.add(topic, record, log_time, publish_time)
            self._last = log_time

    def _guard(self, hook: Callable[..., None], *args: Any) -> None:
        if self._sink is None:
            return
        try:
            hook(*args)
        except Exception as exc:  # the recording stops; the scenario must not
            self._failed(exc, "stopped")

    def _failed(self, exc: BaseException, what: str) -> None:
        if self.error is None:
            reason = (exc.strerror or str(exc)) if isinstance(exc, OSError) else (
                f"{type(exc).__name__}: {exc}")
            at = f" at {self._now():.3f} s emulated" if self._loop is not None else ""
            self.error = f"{self.path}: {what}{at}: {reason}".splitlines()[0]
        # The hooks stay registered (a link runs its listeners from the very list removing
        # one would change under it); without a sink they do nothing.
        sink, self._sink = self._sink, None
        if sink is not None:
            with contextlib.suppress(Exception):
                sink.close()  # complete up to the last chunk, or cut back to it


class _BoardState:
    """One board's clock mapping and statistics period, for its listener."""

    def __init__(self, board: str) -> None:
        self.board = board
        self.telemetry_topic = f"/board/{board}/telemetry"
        self.clock = BoardClock()
        self.next_stats = STATS_PERIOD_S
        self.stats_at = 0.0
        self.stats_received = 0


_CHANNEL_KEYS = tuple(tuple(f"{prefix}_{name}" for name in CHANNEL_FIELDS)
                      for prefix in ("a", "b"))


def _telemetry_row(sample: Telemetry, sampled: float) -> dict[str, Any]:
    """The row ``record`` writes (:func:`~fpgalink.recording.telemetry_row`, each float to 7
    digits, a non-finite one as null), in one pass: it is built 2,000 times per emulated
    second."""
    row: dict[str, Any] = {"timestamp": round(sampled, 6), "t_us": sample.t_us,
                           "counter": sample.counter}
    for keys, channel in zip(_CHANNEL_KEYS, (sample.a, sample.b), strict=True):
        for key, value in zip(keys, channel, strict=True):
            if type(value) is float:
                row[key] = float(f"{value:.7g}") if math.isfinite(value) else None
            else:
                row[key] = value
    return row


def _finite(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with every non-finite float, at any depth, as ``null`` (JSON has none)."""
    def clean(value: Any) -> Any:
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [clean(v) for v in value]
        return value

    result: dict[str, Any] = clean(record)
    return result
