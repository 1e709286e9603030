"""``step``: apply a reference step on one channel, record the response from telemetry and
report rise time, settling time, overshoot and steady-state error (optionally a plot)."""

from __future__ import annotations

import asyncio
import math
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fpgalink.boardclock import BoardClock
from fpgalink.cli.figures import check_plot_path, new_figure, save_figure
from fpgalink.cli.files import force_option
from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.liveview import add_live_boards, foxglove_option, opened_live
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    SignedNumbers,
    echo_out,
    format_value,
    note,
    number,
)
from fpgalink.cli.session import FAULTS, Streaming, install_stop_signals, run, wait_or_stop
from fpgalink.events import StatusEvent
from fpgalink.protocol import FLOAT32_MAX, ChannelTelemetry, Telemetry, float32
from fpgalink.robot.response import SETTLING_BAND, StepMetrics, step_metrics

if TYPE_CHECKING:
    from fpgalink.live import LiveAddress

__all__ = ["StepMetrics", "StepResponse", "step", "step_metrics"]

MAX_PHASE_S = 3600.0  #: longest --pre/--hold: a step is an experiment, not a service


@dataclass
class StepResponse:
    """Samples of the stepped channel, time 0 at the step."""

    t: list[float]
    reference: list[float]
    speed: list[float]
    pwm: list[int]


def split_response(samples: list[tuple[float, Telemetry]], channel: str, target: float,
                   step_time: float) -> StepResponse:
    """Time zero is the first sample whose reference shows the new value (the board's own
    view of the step); failing that, the host's time of sending it."""
    def pick(sample: Telemetry) -> ChannelTelemetry:
        return sample.a if channel == "A" else sample.b

    stored = float32(target)
    zero = next((ts for ts, s in samples if ts >= step_time - 0.5
                 and math.isclose(pick(s).reference, stored, rel_tol=1e-6, abs_tol=1e-6)),
                step_time)
    response = StepResponse([], [], [], [])
    for ts, sample in samples:
        ch = pick(sample)
        response.t.append(ts - zero)
        response.reference.append(ch.reference)
        response.speed.append(ch.speed)
        response.pwm.append(ch.pwm)
    return response


@dataclass(frozen=True, slots=True)
class StepSetup:
    """What the board ran the step with, read from it before the step (for the plot's title
    and the PWM limit)."""

    kp: float | None = None
    ti: float | None = None
    td: float | None = None
    max_control: int | None = None
    controller: int | None = None


CONTROLLERS = {0: "software speed PID", 1: "hardware speed PID", 2: "software current PID",
               3: "hardware current PID"}


def save_plot(path: Path, response: StepResponse, channel: str, start: float, target: float,
              metrics: StepMetrics, setup: StepSetup, *, force: bool = False) -> None:
    """Reference (dashed, so a speed on it still shows) and speed with the ±2 % band, the
    rise (10–90 %) and settling marks; PWM with the board's limit below."""
    figure = new_figure((9, 6.5))
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    size = abs(target - start)
    band = SETTLING_BAND * size
    top.axhspan(target - band, target + band, color="tab:green", alpha=0.12,
                label=f"±{SETTLING_BAND:.0%} band")
    top.plot(response.t, response.speed, color="tab:blue", linewidth=1.2, label="speed")
    top.plot(response.t, response.reference, color="black", linestyle="--", linewidth=1.0,
             drawstyle="steps-post", label="reference")
    if metrics.rise_start is not None and metrics.rise_end is not None:
        top.axvspan(metrics.rise_start, metrics.rise_end, color="tab:orange", alpha=0.15,
                    label=f"rise 10–90 %: {metrics.rise_time:.3f} s")
    if metrics.settling_time is not None:
        top.axvline(metrics.settling_time, color="tab:red", linestyle=":", linewidth=1.2,
                    label=f"settled (2 %): {metrics.settling_time:.3f} s")
    top.set_ylabel(f"channel {channel} speed, deg/s")
    gains = []
    if setup.kp is not None:
        gains.append(f"Kp {format_value(setup.kp)} PWM/(deg/s)")
    if setup.ti is not None:
        gains.append(f"Ti {format_value(setup.ti)} s")
    if setup.td is not None:
        gains.append(f"Td {format_value(setup.td)} s")
    title = f"channel {channel}: step {start:g} → {target:g} deg/s"
    if gains:
        title += "\n" + ", ".join(gains)
        if setup.controller is not None:
            title += f" ({CONTROLLERS.get(setup.controller, f'controller {setup.controller}')})"
    top.set_title(title)
    top.legend(loc="lower right", fontsize="small")
    top.grid(True, alpha=0.3)
    bottom.plot(response.t, response.pwm, color="tab:green", linewidth=1.0, label="PWM")
    if setup.max_control is not None:
        for sign in (1, -1):
            bottom.axhline(sign * setup.max_control, color="tab:red", linestyle="--",
                           linewidth=1.0,
                           label=f"limit ±{setup.max_control} (MaxControlSignal)"
                           if sign > 0 else None)
    bottom.set_ylabel("PWM, counts\n(±32760 = 100 %)")
    bottom.set_xlabel("time since the step, s")
    bottom.legend(loc="lower right", fontsize="small")
    bottom.grid(True, alpha=0.3)
    save_figure(figure, path, force=force)


def check_reach(target: float, start: float, conn: ConnectionOptions) -> None:
    """Say so when a reference is beyond what the wheel can turn: the speed saturates and
    the figures will say "not reached"."""
    from fpgalink.protocol.robot import DescriptionError, load_robot, seed_robot

    try:
        robot = load_robot(str(conn.settings.robot)) if conn.settings.robot else seed_robot()
    except DescriptionError:
        robot = seed_robot()
    reach = robot.max_wheel_speed
    for label, value in (("--to", target), ("--from", start)):
        if abs(value) > reach:
            note(f"{label} {value:g} deg/s is beyond the wheel's reach: {robot.name}'s wheels "
                 f"turn at most {reach:g} deg/s (max_wheel_speed): the speed will saturate "
                 "short of it and the figures will say so")


@click.command(cls=SignedNumbers, epilog=EXIT_CODES_HELP)
@click.option("--channel", "-c", type=click.Choice(["A", "B"], case_sensitive=False),
              required=True, help="Channel to step (the other gets reference 0).")
@click.option("--to", "target", type=float, required=True,
              help="Reference after the step (deg/s).")
@click.option("--from", "start", type=float, default=0.0, show_default=True,
              help="Reference before the step (deg/s).")
@click.option("--hold", type=FiniteRange(min=0, min_open=True, max=MAX_PHASE_S),
              default=3.0, show_default=True, help="How long to record after the step, s.")
@click.option("--pre", type=FiniteRange(min=0, max=MAX_PHASE_S), default=1.0,
              show_default=True, help="How long to hold --from before the step, s.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
              help="Save reference, speed and pwm against time to a .png, .svg or .pdf "
                   "(needs matplotlib; the path is checked before the step runs).")
@force_option
@format_option
@foxglove_option
@connection_options()
def step(channel: str, target: float, start: float, hold: float, pre: float,
         plot: Path | None, force: bool, fmt: str, foxglove: LiveAddress | None,
         conn: ConnectionOptions) -> int:
    """Step the speed reference of one channel and measure the response.

    Enables the board, turns telemetry on, holds --from for --pre seconds, steps to --to and
    records --hold seconds; then disables (also on Ctrl-C and SIGTERM, exit 130 and 143).
    Prints rise time (10-90 %), settling time (2 % band), overshoot and steady-state error
    of the channel's speed.
    """
    channel = channel.upper()
    for label, value in (("--to", target), ("--from", start)):
        if not abs(value) <= FLOAT32_MAX:  # NaN fails this too
            raise CliError(f"{label} must be a finite number within the float32 range "
                           f"(±{FLOAT32_MAX:.4g}), got {value}", ExitCode.BAD_INPUT)
    if float32(target) == float32(start):
        raise CliError("--to and --from are equal: there is no step", ExitCode.BAD_INPUT)
    if plot is not None:
        check_plot_path(plot, force=force)
    check_reach(target, start, conn)
    outcome = run(_step(conn, channel, start, target, pre, hold, foxglove), conn.single.url)
    if outcome.signal is not None:
        name = signal.Signals(outcome.signal).name
        note(f"interrupted by {name}: the board was disabled")
        return 128 + outcome.signal
    response = outcome.response
    if len(response.t) < 2:
        raise CliError(f"{conn.single.url}: no telemetry arrived during the step",
                       ExitCode.NO_ANSWER)
    after = [(t, v) for t, v in zip(response.t, response.speed, strict=True) if t >= 0]
    if not after:
        raise CliError("no telemetry after the step", ExitCode.NO_ANSWER)
    metrics = step_metrics([t for t, _ in after], [v for _, v in after], start, target)
    _print_metrics(fmt, metrics, channel, start, target, len(after), outcome.setup)
    if plot is not None:
        save_plot(plot, response, channel, start, target, metrics, outcome.setup,
                  force=force)
        click.echo(f"plot saved to {plot}", err=True)
    return ExitCode.OK


def _fmt_s(value: float | None) -> str:
    return "not reached" if value is None else f"{value:.3f} s"


def metrics_document(m: StepMetrics, channel: str, start: float, target: float,
                     samples: int, setup: StepSetup) -> dict[str, Any]:
    """The figures as JSON has them: numbers, the unit in each key."""
    return {
        "channel": channel, "from_dps": start, "to_dps": target, "samples": samples,
        "rise_time_s": m.rise_time, "settling_time_s": m.settling_time,
        "overshoot_percent": m.overshoot, "steady_state_error_dps": m.steady_state_error,
        "peak_dps": m.peak, **{key: None if value is None else number(value) for key, value in
                               (("kp", setup.kp), ("ti_s", setup.ti), ("td_s", setup.td))},
        "max_control_signal": setup.max_control,
    }


def _print_metrics(fmt: str, m: StepMetrics, channel: str, start: float, target: float,
                   samples: int, setup: StepSetup) -> None:
    document = metrics_document(m, channel, start, target, samples, setup)
    if fmt == "json":
        emit_document(document)
        return
    if fmt == "csv":
        emit_rows(fmt, [Column(k, k) for k in document], [document])
        return
    echo_out(f"Step response, channel {channel}: {start:g} → {target:g} deg/s "
             f"({samples} samples after the step)")
    rows: list[dict[str, Any]] = [
        {"figure": "rise time (10-90 %)", "value": _fmt_s(m.rise_time)},
        {"figure": "settling time (2 %)", "value": _fmt_s(m.settling_time)},
        {"figure": "overshoot", "value": f"{m.overshoot:.1f} %"},
        {"figure": "steady-state error", "value": f"{m.steady_state_error:.3f} deg/s"},
        {"figure": "peak", "value": f"{m.peak:.3f} deg/s"},
    ]
    emit_rows(fmt, [Column("figure", "figure"), Column("value", "value", justify="right")],
              rows)


@dataclass
class StepOutcome:
    response: StepResponse
    setup: StepSetup
    #: the signal (SIGINT, SIGTERM) that ended the step early, after the board was disabled
    signal: int | None = None


async def _read_setup(link: Any, channel: str) -> StepSetup:
    """The controller's gains and limits for ``channel`` as the board has them; what cannot
    be read is left out of the plot, not a reason to stop."""
    from fpgalink.errors import FpgalinkError

    code = 1 if channel == "A" else 2
    values: dict[str, Any] = {}
    for key, name in (("kp", "Kp_Wheel_Pid"), ("ti", "Ti_Wheel_Pid"), ("td", "Td_Wheel_Pid"),
                      ("max_control", "MaxControlSignal"), ("controller", "ActiveController")):
        try:
            values[key] = await link.get_param(name, code)
        except FpgalinkError:
            values[key] = None
    return StepSetup(**values)


async def _step(conn: ConnectionOptions, channel: str, start: float, target: float,
                pre: float, hold: float, foxglove: LiveAddress | None = None) -> StepOutcome:
    def refs(value: float) -> tuple[float, float]:
        return (value, 0.0) if channel == "A" else (0.0, value)

    stop = asyncio.Event()
    install_stop_signals(stop)  # SIGTERM as Ctrl-C: the board is disabled on the way out
    async with conn.link(conn.single) as link, \
            opened_live(foxglove, "fpgalink-cli step") as view:
        add_live_boards(view, {conn.single.name: link})
        streaming = Streaming(link)
        await streaming.start()
        setup = await _read_setup(link, channel)
        samples: list[tuple[float, Telemetry]] = []
        clock = BoardClock()
        loop = asyncio.get_running_loop()
        sub = link.telemetry(maxsize=1 << 20)
        step_time = loop.time()

        async def collect() -> None:
            async for sample in sub:
                samples.append((clock.seconds(sample.t_us, loop.time()), sample))

        collector = asyncio.ensure_future(collect())
        # A fault mid-step (the board restarted, its watchdog disabled it, its telemetry
        # stopped) ends the step: its figures would describe something else.
        faults: list[StatusEvent] = []
        remove = link.on_event(lambda e: faults.append(e) if isinstance(e, FAULTS) else None)
        try:
            with _StepProgress(pre + hold, samples, stop) as progress:
                link.enable()
                link.set_references(*refs(start))
                if await progress.phase(f"holding {start:g} deg/s on {channel}", pre,
                                        faults):
                    step_time = loop.time()  # on the samples' axis: anchored to this clock
                    link.set_references(*refs(target))
                    await progress.phase(f"stepped to {target:g} deg/s", hold, faults)
        finally:
            remove()
            link.disable()
            sub.close()
            await asyncio.gather(collector, return_exceptions=True)
            await streaming.restore()
    fired = getattr(stop, "signal", None)
    if faults and fired is None:
        fault = faults[0]
        raise CliError(f"the step was stopped: board {fault.name.replace('_', ' ')} "
                       f"({fault.describe()}); no figures", ExitCode.STOPPED)
    return StepOutcome(split_response(samples, channel, target, step_time), setup,
                       None if fired is None else int(fired))



class _StepProgress:
    """A bar on stderr while the step runs (only on a terminal, like ``record``'s)."""

    def __init__(self, total: float, samples: list[Any], stop: asyncio.Event) -> None:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from fpgalink.cli.output import console as plain_console

        console = plain_console(stderr=True)
        self._samples = samples
        self._stop = stop
        self._started = time.monotonic()
        self._progress = Progress(
            TextColumn("{task.description}", markup=False), BarColumn(), TimeElapsedColumn(),
            TextColumn("{task.fields[samples]} samples"),
            console=console, disable=not console.is_terminal)
        self._task = self._progress.add_task("starting", total=total, samples=0)

    def __enter__(self) -> _StepProgress:
        self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    async def phase(self, description: str, seconds: float, faults: list[Any]) -> bool:
        """Run one phase; False when a signal or a fault ended it early."""
        self._progress.update(self._task, description=description)
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0 and not faults:
            await wait_or_stop(self._stop, min(0.1, left))
            if self._stop.is_set():
                return False
            self._progress.update(self._task, completed=time.monotonic() - self._started,
                                  samples=len(self._samples))
        return not faults
