"""``step``: apply a reference step on one channel, record the response from telemetry and
report rise time, settling time, overshoot and steady-state error (optionally a plot)."""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from fpgalink.aio.link import LinkEvent
from fpgalink.boardclock import BoardClock
from fpgalink.cli.figures import check_plot_path, new_figure, save_figure
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, FiniteRange, table_console
from fpgalink.cli.session import FAULT_KINDS, Streaming, run
from fpgalink.protocol import FLOAT32_MAX, ChannelTelemetry, Telemetry, float32

__all__ = ["StepMetrics", "StepResponse", "step", "step_metrics"]

RISE_LOW, RISE_HIGH = 0.1, 0.9  #: rise time is measured between 10 % and 90 % of the step
SETTLING_BAND = 0.02  #: settled once within ±2 % of the step size, for good
STEADY_FRACTION = 0.1  #: steady-state error: mean of the last 10 % of the hold
MAX_PHASE_S = 3600.0  #: longest --pre/--hold: a step is an experiment, not a service


@dataclass(frozen=True, slots=True)
class StepMetrics:
    rise_time: float | None  #: s, 10 → 90 %; None if 90 % was never reached
    settling_time: float | None  #: s after the step; None if not settled by the end
    overshoot: float  #: % of the step size, ≥ 0
    steady_state_error: float  #: target − mean of the last 10 %, in the signal's unit
    peak: float


def step_metrics(t: list[float], y: list[float], start: float, target: float) -> StepMetrics:
    """Classic step-response figures of ``y(t)`` (``t`` = 0 at the step) for a step from
    ``start`` to ``target``. Works for downward steps too (everything relative to the step)."""
    if not t or len(t) != len(y):
        raise ValueError("need matching, non-empty time and value lists")
    size = target - start
    if size == 0:
        raise ValueError("the step has zero size")
    progress = [(v - start) / size for v in y]  # 0 at start, 1 at target
    t_low = next((ti for ti, p in zip(t, progress, strict=True) if p >= RISE_LOW), None)
    t_high = next((ti for ti, p in zip(t, progress, strict=True) if p >= RISE_HIGH), None)
    rise = t_high - t_low if t_low is not None and t_high is not None else None
    band = SETTLING_BAND
    outside = [i for i, p in enumerate(progress) if abs(p - 1.0) > band]
    if not outside:
        settling: float | None = t[0]
    elif outside[-1] == len(t) - 1:
        settling = None
    else:
        settling = t[outside[-1] + 1]
    peak_progress = max(progress)
    tail = y[-max(1, int(len(y) * STEADY_FRACTION)):]
    return StepMetrics(
        rise_time=rise,
        settling_time=settling,
        overshoot=max(0.0, (peak_progress - 1.0) * 100.0),
        steady_state_error=target - sum(tail) / len(tail),
        peak=start + peak_progress * size,
    )


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


def save_plot(path: Path, response: StepResponse, channel: str, title: str) -> None:
    figure = new_figure((8, 6))
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    top.plot(response.t, response.reference, label="reference", drawstyle="steps-post")
    top.plot(response.t, response.speed, label="speed")
    top.set_ylabel("deg/s")
    top.set_title(title)
    top.legend(loc="lower right")
    top.grid(True, alpha=0.3)
    bottom.plot(response.t, response.pwm, color="tab:green", label="pwm")
    bottom.set_ylabel(f"pwm {channel}")
    bottom.set_xlabel("time since step, s")
    bottom.grid(True, alpha=0.3)
    save_figure(figure, path)


@click.command(epilog=EXIT_CODES_HELP)
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
@connection_options()
def step(channel: str, target: float, start: float, hold: float, pre: float,
         plot: Path | None, conn: ConnectionOptions) -> int:
    """Step the speed reference of one channel and measure the response.

    Enables the board, turns telemetry on, holds --from for --pre seconds, steps to --to and
    records --hold seconds; then disables. Prints rise time (10-90 %), settling time (2 %
    band), overshoot and steady-state error of the channel's speed.
    """
    channel = channel.upper()
    for label, value in (("--to", target), ("--from", start)):
        if not abs(value) <= FLOAT32_MAX:  # NaN fails this too
            raise CliError(f"{label} must be a finite number within the float32 range "
                           f"(±{FLOAT32_MAX:.4g}), got {value}", ExitCode.BAD_INPUT)
    if float32(target) == float32(start):
        raise CliError("--to and --from are equal: there is no step", ExitCode.BAD_INPUT)
    if plot is not None:
        check_plot_path(plot)
    response = run(_step(conn, channel, start, target, pre, hold), conn.single.url)
    if len(response.t) < 2:
        raise CliError(f"{conn.single.url}: no telemetry arrived during the step",
                       ExitCode.NO_ANSWER)
    after = [(t, v) for t, v in zip(response.t, response.speed, strict=True) if t >= 0]
    if not after:
        raise CliError("no telemetry after the step", ExitCode.NO_ANSWER)
    metrics = step_metrics([t for t, _ in after], [v for _, v in after], start, target)
    _print_metrics(metrics, channel, start, target, len(after))
    if plot is not None:
        save_plot(plot, response, channel, f"channel {channel}: step {start:g} → {target:g}")
        click.echo(f"plot saved to {plot}", err=True)
    return ExitCode.OK


def _fmt_s(value: float | None) -> str:
    return "not reached" if value is None else f"{value:.3f} s"


def _print_metrics(m: StepMetrics, channel: str, start: float, target: float,
                   samples: int) -> None:
    console = table_console()
    console.print(f"Step response, channel {channel}: {start:g} → {target:g} deg/s "
                  f"({samples} samples after the step)")
    table = Table()
    table.add_column("figure")
    table.add_column("value", justify="right")
    rows: list[tuple[str, Any]] = [
        ("rise time (10-90 %)", _fmt_s(m.rise_time)),
        ("settling time (2 %)", _fmt_s(m.settling_time)),
        ("overshoot", f"{m.overshoot:.1f} %"),
        ("steady-state error", f"{m.steady_state_error:.3f}"),
        ("peak", f"{m.peak:.3f}"),
    ]
    for name, value in rows:
        table.add_row(name, value)
    console.print(table)


async def _step(conn: ConnectionOptions, channel: str, start: float, target: float,
                pre: float, hold: float) -> StepResponse:
    def refs(value: float) -> tuple[float, float]:
        return (value, 0.0) if channel == "A" else (0.0, value)

    async with conn.link(conn.single) as link:
        streaming = Streaming(link)
        await streaming.start()
        samples: list[tuple[float, Telemetry]] = []
        clock = BoardClock()
        loop = asyncio.get_running_loop()
        sub = link.telemetry(maxsize=1 << 20)

        async def collect() -> None:
            async for sample in sub:
                samples.append((clock.seconds(sample.t_us, loop.time()), sample))

        collector = asyncio.ensure_future(collect())
        # A fault mid-step (the board restarted, its watchdog disabled it, its telemetry
        # stopped) ends the step: its figures would describe something else.
        faults: list[LinkEvent] = []
        remove = link.on_event(lambda e: faults.append(e) if e.kind in FAULT_KINDS else None)
        try:
            with _StepProgress(pre + hold, samples) as progress:
                link.enable()
                link.set_references(*refs(start))
                await progress.phase(f"holding {start:g} deg/s on {channel}", pre, faults)
                step_time = loop.time()  # on the samples' axis: anchored to this clock
                link.set_references(*refs(target))
                await progress.phase(f"stepped to {target:g} deg/s", hold, faults)
        finally:
            remove()
            link.disable()
            sub.close()
            await asyncio.gather(collector, return_exceptions=True)
            await streaming.restore()
    if faults:
        fault = faults[0]
        raise CliError(f"the step was stopped: board {fault.kind.value.replace('_', ' ')} "
                       f"({fault.detail}); no figures", ExitCode.STOPPED)
    return split_response(samples, channel, target, step_time)



class _StepProgress:
    """A bar on stderr while the step runs (only on a terminal, like ``record``'s)."""

    def __init__(self, total: float, samples: list[Any]) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        console = Console(stderr=True)
        self._samples = samples
        self._started = time.monotonic()
        self._progress = Progress(
            TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
            TextColumn("{task.fields[samples]} samples"),
            console=console, disable=not console.is_terminal)
        self._task = self._progress.add_task("starting", total=total, samples=0)

    def __enter__(self) -> _StepProgress:
        self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    async def phase(self, description: str, seconds: float, faults: list[Any]) -> None:
        self._progress.update(self._task, description=description)
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0 and not faults:
            await asyncio.sleep(min(0.1, left))
            self._progress.update(self._task, completed=time.monotonic() - self._started,
                                  samples=len(self._samples))
