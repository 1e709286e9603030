"""One scenario: a fresh in-process emulated robot (``emu://robot/…``), driven by the library's
own :class:`~fpgalink.robot.Robot` on an emulated-time loop
(:mod:`fpgalink.aio.virtualtime`), so it runs as fast as the machine goes and its figures do
not depend on the machine's speed or load: the same scenario gives the same figures on a
laptop, a loaded CI runner or a Dask worker.

The host side is the one users run (supervision, heartbeat, deadman, odometry, go-to), with
the emulated robot's truth beside it. A fault stops the robot as it would on the bench; the
scenario then does what a user's drive loop does — asks for the enable again every control
period — and counts the stops and the time the robot stood still.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import socket
import time
import traceback
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgalink.aio.tasks import cancel_and_wait
from fpgalink.aio.virtualtime import run_virtual
from fpgalink.campaign.recording import ScenarioRecording
from fpgalink.campaign.spec import Action, ParamSetting, Scenario
from fpgalink.errors import FpgalinkError
from fpgalink.protocol import Telemetry
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B, Scope, lookup
from fpgalink.protocol.robot import WheelMount
from fpgalink.robot.response import step_metrics
from fpgalink.robot.robot import GoalTimeout, Robot, RobotStopped
from fpgalink.robot.supervision import State, SupervisionEvent

__all__ = ["TOTALS", "Figure", "Result", "run_scenario"]

Figure = float | int | bool | str | None
CONTROL_PERIOD_S = 0.1  #: commands renewed and the truth sampled this often
AT_REST_DPS = 1.0  #: a step starts once every wheel is slower than this
REST_WAIT_S = 5.0  #: at most this long for the wheels to come to rest before a step
#: The figures of a whole scenario, after its actions' own (``LABEL.figure``).
TOTALS = ("emulated_s", "distance_m", "odometry_error_m", "odometry_heading_error_deg",
          "stops", "first_stop", "stopped_s", "telemetry", "lost", "damaged", "restarts")


@dataclass(frozen=True, slots=True)
class Result:
    """A scenario's outcome: ``figures`` by ``label.figure`` (deterministic: the same
    scenario gives the same figures), and how it ran (``wall_s``, ``worker``: not)."""

    index: int
    name: str
    status: str  #: "ok" or "failed"
    figures: dict[str, Figure]
    error: str | None = None
    wall_s: float = 0.0
    worker: str = ""
    grid: tuple[tuple[str, Any], ...] = ()
    settings: dict[str, Any] = field(default_factory=dict)
    #: the scenario's MCAP file, where the worker wrote it (on the worker's machine), if
    #: one was asked for and is there
    mcap: str | None = None
    #: why the recording failed or stopped (one line); the figures stand all the same
    mcap_error: str | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def run_scenario(scenario: Scenario, mcap: str | Path | None = None) -> Result:
    """Run ``scenario`` here and now, recorded into the MCAP file ``mcap`` if given; any
    failure is the result's ``error`` (one line), never an exception: a campaign goes on past
    a scenario that fails. A recording that fails is the result's ``mcap_error``: the
    scenario runs on, its figures unchanged."""
    started = time.perf_counter()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    settings = {"surface": scenario.surface, "body": scenario.body, "seed": scenario.seed,
                **{p.label: p.value for p in scenario.params},
                "faults": " ".join(scenario.faults)}
    figures: dict[str, Figure] = {}
    recording = None if mcap is None else ScenarioRecording(Path(mcap), scenario)
    status, text = "ok", None
    try:
        run_virtual(_Run(scenario, figures, recording).main())
    except Exception as exc:
        where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
        status, text = "failed", f"{type(exc).__name__}: {exc}".splitlines()[0]
        if where is not None and not isinstance(exc, FpgalinkError):
            text += f" ({os.path.basename(where.filename)}:{where.lineno})"
    except BaseException:  # the campaign is being stopped
        if recording is not None:
            recording.abandon()
        raise
    if recording is not None:
        recording.close(status, text, figures)
    return Result(scenario.index, scenario.name, status, figures, text,
                  time.perf_counter() - started, worker, scenario.grid, settings,
                  str(recording.path) if recording is not None and recording.written else None,
                  recording.error if recording is not None else None)


class _Run:
    def __init__(self, scenario: Scenario, figures: dict[str, Figure],
                 recording: ScenarioRecording | None = None) -> None:
        self.scenario = scenario
        self.figures = figures
        self.recording = recording
        self.stops: list[SupervisionEvent] = []
        self.stopped_s = 0.0  #: emulated seconds the robot stood stopped by a fault
        self.stopped_at: float | None = None
        self.command: Callable[[], None] | None = None  #: renewed every control period

    async def main(self) -> None:
        scenario = self.scenario
        # The identity's nonces from the scenario's seed: the same bytes on the line wherever
        # the scenario runs, so the same figures.
        robot = Robot.open(scenario.description, scenario.urls(), identity_seed=scenario.seed)
        self.robot = robot
        if self.recording is not None:
            self.recording.attach(robot)  # before the start: the boards from their first word
        loop = asyncio.get_running_loop()
        async with robot:
            started = loop.time()
            for setting in scenario.params:
                await self._set(setting)
            watcher = asyncio.ensure_future(self._watch())
            keeper = asyncio.ensure_future(self._keep_enabled())
            try:
                for action in scenario.script:
                    if self.recording is not None:
                        self.recording.action(action)
                    await _ACTIONS[action.kind](self, action)
                    self.command = None
                    with contextlib.suppress(FpgalinkError):
                        robot.stop()
            finally:
                # Both ended before either's failure is raised: none left running.
                failures = [await cancel_and_wait(helper) for helper in (keeper, watcher)]
                for failed in failures:
                    if failed is not None:
                        raise failed
            self._totals(loop.time() - started)
            if robot.state is State.ENABLED:
                robot.disable()

    # --- the user's loop ----------------------------------------------------------------

    async def _keep_enabled(self) -> None:
        """Renew the enable, or ask for it again after a stop, every control period; renew
        the current command with it (an enable after a stop starts from zero references)."""
        robot = self.robot
        while True:
            try:
                robot.enable()
                if self.command is not None:
                    self.command()
            except RobotStopped:
                pass
            await asyncio.sleep(CONTROL_PERIOD_S)

    async def _watch(self) -> None:
        async for event in self.robot.events():
            if self.recording is not None:
                self.recording.supervision(event)
            if event.recovered:
                continue
            if event.reason is not None:
                self.stops.append(event)
                if self.stopped_at is None:
                    self.stopped_at = event.at
            elif self.stopped_at is not None:
                self.stopped_s += event.at - self.stopped_at
                self.stopped_at = None

    async def _set(self, setting: ParamSetting) -> None:
        param = lookup(setting.name)
        boards = [setting.board] if setting.board else list(self.robot.description.boards)
        channels = [setting.channel] if setting.channel or param.scope is Scope.BOARD \
            else [CHANNEL_A, CHANNEL_B]
        for board in boards:
            for channel in channels:
                await self.robot.boards.set_parameter(board, param.name, setting.value,
                                                      channel or None)

    def _truth(self) -> dict[str, Any]:
        truth = self.robot.truth()
        if truth is None:
            raise RuntimeError("the robot gives no truth: not an emulated robot")
        return truth

    def _put(self, action: Action, name: str, value: Figure) -> None:
        if isinstance(value, float):
            value = round(value, 9)  # stable text in CSV/JSON; far below any figure's sense
        self.figures[f"{action.label}.{name}"] = value

    async def _hold(self, seconds: float,
                    sample: Callable[[dict[str, Any]], None] | None = None) -> None:
        """Exactly ``seconds`` of emulated time in control periods (the last one shorter),
        the truth sampled after each: figures over ``seconds`` are over what was sampled."""
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while (left := end - loop.time()) > 1e-9:
            await asyncio.sleep(min(CONTROL_PERIOD_S, left))
            if sample is not None:
                sample(self._truth())

    def _hold_command(self, send: Callable[[], object]) -> None:
        """``send`` the action's command now and with every renewal of the enable (an
        enable after a stop starts from zero references); only while enabled."""
        robot = self.robot

        def command() -> None:
            if robot.state is State.ENABLED:
                send()

        self.command = command
        command()

    def _hold_references(self, speed: Callable[[WheelMount], float]) -> None:
        """Every wheel at ``speed(wheel)`` deg/s forward (the robot applies each board's
        sign)."""
        references = {wheel.name: speed(wheel) for wheel in self.robot.description.wheels}
        self._hold_command(lambda: self.robot.set_wheel_references(references))

    # --- actions ------------------------------------------------------------------------

    async def wheels(self, action: Action) -> None:
        self._hold_references(lambda wheel: action.left if wheel.left else action.right)
        await self._hold(action.settle)
        track = _Track(self._truth())
        await self._hold(action.seconds, track.add)
        rate = track.turned / action.seconds if action.seconds else 0.0
        speed = track.path / action.seconds if action.seconds else 0.0
        self._put(action, "turn_rate_dps", math.degrees(rate))
        self._put(action, "radius_m", speed / abs(rate) if rate else None)
        self._put(action, "wander_x_m", track.span_x)
        self._put(action, "wander_y_m", track.span_y)

    async def drive(self, action: Action) -> None:
        omega = math.radians(action.omega)
        self._hold_command(lambda: self.robot.drive(action.v, omega))
        track = _Track(self._truth())
        await self._hold(action.seconds, track.add)
        self._put(action, "distance_m", track.path)
        self._put(action, "turn_rate_dps",
                  math.degrees(track.turned / action.seconds) if action.seconds else 0.0)

    async def goto(self, action: Action) -> None:
        robot = self.robot
        loop = asyncio.get_running_loop()
        started = loop.time()
        end = started + action.seconds
        theta = None if action.theta is None else math.radians(action.theta)
        while True:
            try:
                await robot.go_to(action.x, action.y, theta,
                                  timeout=max(1e-3, end - loop.time()))
                outcome = "arrived"
                break
            except GoalTimeout:
                outcome = "timeout"
                break
            except RobotStopped:
                # A fault stopped it: as a user would, wait for the robot to be enabled
                # again (the keeper asks) and go on towards the goal.
                outcome = "stopped"
                while robot.state is not State.ENABLED and loop.time() < end:
                    await asyncio.sleep(CONTROL_PERIOD_S)
                if loop.time() >= end:
                    break
        truth = self._truth()
        self._put(action, "outcome", outcome)
        self._put(action, "time_s", loop.time() - started)
        self._put(action, "error_m", math.hypot(truth["x"] - action.x, truth["y"] - action.y))
        if theta is not None:
            self._put(action, "heading_error_deg",
                      math.degrees(math.remainder(truth["theta"] - theta, math.tau)))

    async def step(self, action: Action) -> None:
        robot = self.robot
        loop = asyncio.get_running_loop()
        channel = {"A": CHANNEL_A, "B": CHANNEL_B}.get((action.wheel or "").upper())
        wheels = [w for w in robot.description.wheels
                  if action.wheel in (None, w.name) or w.channel == channel]
        if not wheels:
            raise ValueError(f"step wheel {action.wheel!r}: the robot's wheels are "
                             f"{', '.join(w.name for w in robot.description.wheels)} "
                             "(or A, B: every wheel on that channel)")
        deadline = loop.time() + REST_WAIT_S
        while loop.time() < deadline and any(
                abs(_channel(robot.latest.get(w.board), w.channel).speed) >= AT_REST_DPS
                for w in wheels if robot.latest.get(w.board) is not None):
            await asyncio.sleep(CONTROL_PERIOD_S)
        subs = {board: robot.boards.telemetry(board, maxsize=1 << 16)
                for board in {w.board for w in wheels}}
        samples: dict[str, list[Telemetry]] = {board: [] for board in subs}

        async def collect(board: str) -> None:
            async for sample in subs[board]:
                samples[board].append(sample)

        collectors = [asyncio.ensure_future(collect(board)) for board in subs]
        self._hold_references(lambda wheel: action.to)
        await self._hold(action.seconds)
        for sub in subs.values():
            sub.close()
        for task in collectors:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        worst: dict[str, float | None] = {"rise_s": 0.0, "settling_s": 0.0,
                                          "overshoot_pct": 0.0, "error_dps": 0.0}
        for wheel in wheels:
            metrics = _wheel_step(samples[wheel.board], wheel.channel, wheel.forward,
                                  action.to)
            if metrics is None:
                worst = dict.fromkeys(worst)
                break
            rise, settling, overshoot, error = metrics
            worst["rise_s"] = _worse(worst["rise_s"], rise)
            worst["settling_s"] = _worse(worst["settling_s"], settling)
            worst["overshoot_pct"] = max(worst["overshoot_pct"] or 0.0, overshoot)
            worst["error_dps"] = max(worst["error_dps"] or 0.0, abs(error))
        for name, value in worst.items():
            self._put(action, name, value)

    async def wait(self, action: Action) -> None:
        await self._hold(action.seconds)

    # --- the scenario's totals ----------------------------------------------------------

    def _totals(self, emulated_s: float) -> None:
        if self.stopped_at is not None:  # still stopped at the end
            self.stopped_s += asyncio.get_running_loop().time() - self.stopped_at
        truth = self._truth()
        pose = self.robot.pose
        stats = [self.robot.boards.stats(board) for board in self.robot.description.boards]
        put = self.figures.__setitem__
        put("emulated_s", round(emulated_s, 6))
        put("distance_m", round(truth["distance"], 9))
        put("odometry_error_m", round(math.hypot(pose.x - truth["x"], pose.y - truth["y"]), 9))
        put("odometry_heading_error_deg",
            round(math.degrees(math.remainder(pose.theta - truth["theta"], math.tau)), 9))
        put("stops", len(self.stops))
        put("first_stop", self.stops[0].describe() if self.stops else None)
        put("stopped_s", round(self.stopped_s, 6))
        put("telemetry", sum(s.telemetry_received for s in stats))
        put("lost", sum(s.lost for s in stats))
        put("damaged", sum(s.decode_errors + s.corrupt_counters for s in stats))
        put("restarts", sum(s.restarts for s in stats))


_ACTIONS: dict[str, Callable[[_Run, Action], Coroutine[Any, Any, None]]] = {
    "wheels": _Run.wheels, "drive": _Run.drive, "goto": _Run.goto, "step": _Run.step,
    "wait": _Run.wait}


class _Track:
    """The body's path from the truth sampled every control period."""

    def __init__(self, first: dict[str, Any]) -> None:
        self.last = first
        self.turned = self.path = 0.0
        self.xs: list[float] = [first["x"]]
        self.ys: list[float] = [first["y"]]

    def add(self, truth: dict[str, Any]) -> None:
        self.turned += math.remainder(truth["theta"] - self.last["theta"], math.tau)
        self.path += math.hypot(truth["x"] - self.last["x"], truth["y"] - self.last["y"])
        self.xs.append(truth["x"])
        self.ys.append(truth["y"])
        self.last = truth

    @property
    def span_x(self) -> float:
        return max(self.xs) - min(self.xs)

    @property
    def span_y(self) -> float:
        return max(self.ys) - min(self.ys)


def _channel(sample: Telemetry | None, channel: int) -> Any:
    assert sample is not None
    return sample.a if channel == CHANNEL_A else sample.b


def _wheel_step(samples: list[Telemetry], channel: int, forward: int, to: float
                ) -> tuple[float | None, float | None, float, float] | None:
    """A wheel's step figures from its board's samples, time 0 at the first sample whose
    reference shows the step (the board's own view of it)."""
    target = to * forward
    picked = [(s.t_us / 1e6, _channel(s, channel)) for s in samples]
    zero = next((t for t, ch in picked if math.isclose(ch.reference, target, rel_tol=1e-6)),
                None)
    if zero is None:
        return None
    after = [(t - zero, ch.speed * forward) for t, ch in picked if t >= zero]
    metrics = step_metrics([t for t, _ in after], [v for _, v in after], 0.0, to)
    return (metrics.rise_time, metrics.settling_time, metrics.overshoot,
            metrics.steady_state_error)


def _worse(a: float | None, b: float | None) -> float | None:
    """The worse of two times, ``None`` (never reached) the worst."""
    if a is None or b is None:
        return None
    return max(a, b)
