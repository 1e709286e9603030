"""``autotune``: identify each wheel (or take a model), design its speed PID from the model,
confirm the design with a closed-loop step on the board, and keep it only with ``--apply``
when the step confirms it (docs/hardware.md, "Bring-up checklist")."""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import signal
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fpgalink.cli.bringup import (
    Identification,
    Recorder,
    fit_document,
    fit_lines,
    fit_record,
    identification,
    identification_options,
    identify_on,
    load_model,
    recording,
    write_text,
)
from fpgalink.cli.figures import check_plot_path
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.formats import emit_document, format_option
from fpgalink.cli.options import ConnectionOptions, announce_emulator, connection_options
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    echo_out,
    note,
)
from fpgalink.cli.session import install_stop_signals, run
from fpgalink.protocol import identity_metadata

if TYPE_CHECKING:
    from fpgalink.aio.link import Link
    from fpgalink.bringup.design import Design, Gains
    from fpgalink.bringup.plant import ContinuousModel, PlantFit
    from fpgalink.bringup.session import StepRecord
    from fpgalink.robot.response import StepMetrics

__all__ = ["autotune"]

#: The step a design is made for and confirmed with, unless --step says: the seed's 45 deg/s
#: (docs/emulator_models.md), or half what the wheel reaches at the duty limit if less.
DEFAULT_STEP = 45.0


@dataclass
class Tuned:
    """One channel's outcome."""

    board: str
    channel: str
    fit: PlantFit | None
    model: ContinuousModel
    design: Design
    before: Gains
    before_prediction: StepMetrics
    step: StepRecord
    measured: StepMetrics
    confirmed: bool
    why: str
    counts_per_turn: int | None
    limit: int
    applied: bool = False


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--channel", "-c", "channels", type=click.Choice(["A", "B", "both"],
                                                                case_sensitive=False),
              default="both", show_default=True, help="Which channel(s) of every board.")
@identification_options
@click.option("--model", "model_file", type=click.Path(exists=True, dir_okay=False,
                                                       path_type=Path),
              help="Design from this model (identify --save-model) instead of identifying.")
@click.option("--step", "target", type=FiniteRange(min=0, min_open=True, max=1000),
              help="The step (deg/s, from 0) the design is made for and the board's step "
                   "confirms it with  [default: 45, or half the wheel's reach at the limit]")
@click.option("--overshoot", "max_overshoot", type=FiniteRange(min=0, max=50), default=2.0,
              show_default=True, help="The most overshoot the design may predict, %.")
@click.option("--apply", "apply", is_flag=True,
              help="Keep a design on the board when its step confirms the prediction.")
@click.option("--save", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the confirmed gains: into a robot file ([board_parameters.NAME.A]) "
                   "when FILE is one or several boards were tuned, else a parameter set "
                   "(param load FILE).")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
              help="Save each step, predicted and measured, to a .png/.svg/.pdf.")
@force_option
@format_option
@connection_options(multi=True, announce=False)
def autotune(channels: str, wheels: str | None, max_duty: float | None, duration: float,
             bit_s: float, period_ms: int, orders: tuple[int, int, int], offset: bool,
             record: Path | None, model_file: Path | None, target: float | None,
             max_overshoot: float, apply: bool, save: Path | None, plot: Path | None,
             force: bool, fmt: str, conn: ConnectionOptions) -> int:
    """Tune the wheels' speed PIDs from their identified plants, every board and channel.

    Per channel: identify (as identify does: --wheels and --max-duty needed) or take
    --model; design a PI by SIMC on the model (docs/hardware.md says the rule); step the
    board 0 → --step deg/s with it and print rise, settling and overshoot beside the
    prediction. With --apply a design is kept only where the step confirms it (settling
    within 25 % + 0.05 s, overshoot within 2 points); elsewhere the board keeps its gains
    and the exit is 1. --record and --plot are refused if they exist (checked before any
    board is driven) unless --force; a full disk stops the run (exit 1, the recording
    complete up to there). --save edits its file in place.
    """
    options = identification(wheels, max_duty, duration, bit_s, period_ms, orders, offset,
                             driving=True)
    model = None
    if model_file is not None:
        from fpgalink.bringup.plant import FitError

        try:
            model = load_model(model_file).continuous()
        except FitError as exc:
            raise CliError(f"--model {model_file}: {exc}", ExitCode.BAD_INPUT) from None
    if plot is not None:
        check_plot_path(plot, force=force)
    if record is not None:
        check_output(record, force=force)
    announce_emulator(conn)
    wanted = ["A", "B"] if channels.lower() == "both" else [channels.upper()]
    outcome = run(_autotune(conn, wanted, options, model, target, max_overshoot, apply,
                            record, force))
    if isinstance(outcome, int):
        note(f"interrupted by {signal.Signals(outcome - 128).name}: every board disabled, "
             "its parameters set back")
        return outcome
    _report(fmt, outcome)
    if plot is not None:
        _plot(plot, outcome, force)
        note(f"plot saved to {plot}")
    confirmed = [t for t in outcome if t.confirmed]
    if save is not None and confirmed:
        _save(save, confirmed, conn)
    refused = [t for t in outcome if not t.confirmed]
    if apply and refused:
        names = ", ".join(f"{t.board}/{t.channel} ({t.why})" for t in refused)
        raise CliError(f"not applied where the board's step did not confirm the design: "
                       f"{names}; those keep their gains", ExitCode.FAILURE)
    return ExitCode.OK


def _step_target(target: float | None, model: ContinuousModel, limit: int) -> float:
    if target is not None:
        return target
    reach = abs(model.dc_gain) * limit
    return min(DEFAULT_STEP, round(0.5 * reach, 1))


async def _autotune(conn: ConnectionOptions, channels: list[str], options: Identification,
                    model: ContinuousModel | None, target: float | None,
                    max_overshoot: float, apply: bool, record: Path | None, force: bool
                    ) -> Any:
    stop = asyncio.Event()
    install_stop_signals(stop)
    results: list[Tuned] = []
    async with contextlib.AsyncExitStack() as stack:
        # Every board asked who it is before any is driven: a mismatch refuses the run
        # before it starts, and the recording names each board.
        links = {endpoint.name: await stack.enter_async_context(conn.link(endpoint))
                 for endpoint in conn.endpoints}
        recorder = None if record is None else Recorder(
            record, list(links), {
                "command": "autotune", "wheels": options.wheels,
                "max_duty_percent": f"{options.max_duty:g}",
                **identity_metadata({name: (link.identification.identity, link.identification.known)
                                     for name, link in links.items()})},
            stop, force=force)
        with recording(recorder):
            for name, link in links.items():
                for channel in channels:
                    tuned = await _tune(link, name, channel, options, model, target,
                                        max_overshoot, apply, stop, recorder)
                    if tuned is not None:
                        results.append(tuned)
                    if stop.is_set():
                        break
                if stop.is_set():
                    break
    fired = getattr(stop, "signal", None)
    return 128 + int(fired) if fired is not None else results


async def _tune(link: Link, board: str, channel: str, options: Identification,
                given: ContinuousModel | None, target: float | None, max_overshoot: float,
                apply: bool, stop: asyncio.Event, recorder: Recorder | None) -> Tuned | None:
    """One channel tuned; ``None`` when ``stop`` came first (a signal, a recording that
    stopped)."""
    from fpgalink.bringup.design import DesignError, Gains, confirms, design_pi, predict_step
    from fpgalink.bringup.plant import FitError
    from fpgalink.bringup.session import ExperimentError, apply_gains, step_channel
    from fpgalink.robot.response import step_metrics

    fit = None
    if given is None:
        record = await identify_on(link, board, channel, options, stop, recorder)
        if stop.is_set():
            return None
        # The fit, the design and the predicted step run beside the loop, never in it: the
        # links go on being served (a blocked loop is a host that stopped answering).
        fit = await asyncio.to_thread(fit_record, record, options,
                                      f"board {board} channel {channel}")
        try:
            model = fit.continuous  # a low-order model's poles: microseconds
        except FitError as exc:
            raise CliError(f"board {board} channel {channel}: {exc}", ExitCode.FAILURE) from None
    else:
        model = given
    period = float(await link.get_param("TsTimerPeriod")) / 1000.0
    limit = min(int(await link.get_param(f"MaxControlSignal{channel}")), options.limit)
    before = Gains(*[float(await link.get_param(f"{name}{channel}"))
                     for name in ("Kp_Wheel_Pid", "Ti_Wheel_Pid", "Td_Wheel_Pid")])
    counts = 10 * int(await link.get_param(f"IncSenzRes{channel}")) or None
    step_to = _step_target(target, model, limit)
    try:
        design = await asyncio.to_thread(
            lambda: design_pi(model, period=period, target=step_to, limit=limit,
                              max_overshoot=max_overshoot, counts_per_turn=counts))
    except DesignError as exc:
        raise CliError(f"board {board} channel {channel}: {exc}", ExitCode.FAILURE) from None
    horizon = max(3.0, 12.0 * model.time_constant)
    t, y, _ = await asyncio.to_thread(
        lambda: predict_step(model, before, period=period, target=step_to, limit=limit,
                             duration=horizon, counts_per_turn=counts))
    before_prediction = step_metrics(list(t), list(y), 0.0, step_to)
    settling = design.prediction.settling_time or 1.0
    note(f"board {board} channel {channel}: stepping 0 → {step_to:g} deg/s with Kp "
         f"{design.gains.kp:.1f}, Ti {design.gains.ti:.3f} s (predicted settling "
         f"{settling:.3f} s)")
    try:
        step = await step_channel(link, channel, design.gains, step_to,
                                  hold=max(2.0, 3.0 * settling), limit=limit, stop=stop,
                                  on_sample=None if recorder is None
                                  else recorder.on_sample(board))
    except ExperimentError as exc:
        raise CliError(f"board {board}: confirmation step: {exc}", ExitCode.STOPPED) from None
    if stop.is_set():
        return None
    measured = step_metrics(list(step.t), list(step.speed), 0.0, step_to)
    confirmed, why = confirms(design.prediction, measured)
    tuned = Tuned(board, channel, fit, model, design, before, before_prediction, step,
                  measured, confirmed, why, counts, limit)
    if apply and confirmed and not stop.is_set():
        await apply_gains(link, channel, design.gains)
        tuned.applied = True
    if recorder is not None:
        recorder.metadata(f"autotune {board}/{channel}", {
            "kp": repr(design.gains.kp), "ti_s": repr(design.gains.ti),
            "td_s": repr(design.gains.td), "confirmed": str(confirmed), "why": why,
            "applied": str(tuned.applied)})
    return tuned


def _fmt(value: float | None, unit: str = " s", digits: int = 3) -> str:
    return "not reached" if value is None else f"{value:.{digits}f}{unit}"


def _document(t: Tuned) -> dict[str, Any]:
    def figures(m: StepMetrics) -> dict[str, Any]:
        return {"rise_time_s": m.rise_time, "settling_time_s": m.settling_time,
                "overshoot_percent": m.overshoot}

    g = t.design.gains
    return {
        "board": t.board, "channel": t.channel,
        "fit": None if t.fit is None else fit_document(t.fit, t.board, t.channel),
        "rule": t.design.rule, "tau_c_s": t.design.tau_c,
        "gains": {"kp": g.kp, "ti_s": g.ti, "td_s": g.td},
        "margins": {"phase_deg": t.design.margins.phase_margin,
                    "gain_db": t.design.margins.gain_margin_db,
                    "crossover_rad_s": t.design.margins.crossover},
        "step_dps": t.design.target, "period_s": t.design.period,
        "predicted": figures(t.design.prediction), "measured": figures(t.measured),
        "before": {"kp": t.before.kp, "ti_s": t.before.ti, "td_s": t.before.td,
                   "predicted": figures(t.before_prediction)},
        "confirmed": t.confirmed, "why": t.why, "applied": t.applied,
    }


def _report(fmt: str, results: list[Tuned]) -> None:
    if fmt != "table":
        documents = [_document(t) for t in results]
        if fmt == "json":
            emit_document(documents)
            return
        from fpgalink.cli.formats import Column, emit_rows

        rows = [{"board": d["board"], "channel": d["channel"], "kp": d["gains"]["kp"],
                 "ti_s": d["gains"]["ti_s"], "td_s": d["gains"]["td_s"],
                 "predicted_settling_s": d["predicted"]["settling_time_s"],
                 "measured_settling_s": d["measured"]["settling_time_s"],
                 "predicted_overshoot_percent": d["predicted"]["overshoot_percent"],
                 "measured_overshoot_percent": d["measured"]["overshoot_percent"],
                 "confirmed": d["confirmed"], "applied": d["applied"]} for d in documents]
        emit_rows(fmt, [Column(k, k) for k in rows[0]] if rows else [], rows)
        return
    for t in results:
        if t.fit is not None:
            for line in fit_lines(fit_document(t.fit, t.board, t.channel)):
                echo_out(line)
        g, b = t.design.gains, t.before
        echo_out(f"Design for board {t.board} channel {t.channel}: Kp {g.kp:.1f} PWM/(deg/s), "
                 f"Ti {g.ti:.4f} s, Td {g.td:g} s")
        echo_out(f"  rule          {t.design.rule}")
        echo_out(f"  margins       phase {t.design.margins.phase_margin:.1f}°, gain "
                 f"{t.design.margins.gain_margin_db:.1f} dB, crossover "
                 f"{t.design.margins.crossover:.2f} rad/s")
        echo_out(f"  step 0 → {t.design.target:g} deg/s at {t.design.period * 1000:g} ms:"
                 f"{'predicted':>14}{'on the board':>16}"
                 f"{'now (Kp ' + format(b.kp, '.0f') + ', Ti ' + format(b.ti, '.3g') + ')':>28}")
        for label, key in (("rise 10-90 %", "rise_time"), ("settling 2 %", "settling_time")):
            echo_out(f"    {label:<27}{_fmt(getattr(t.design.prediction, key)):>14}"
                     f"{_fmt(getattr(t.measured, key)):>16}"
                     f"{_fmt(getattr(t.before_prediction, key)):>28}")
        echo_out(f"    {'overshoot':<27}{t.design.prediction.overshoot:>12.1f} %"
                 f"{t.measured.overshoot:>14.1f} %{t.before_prediction.overshoot:>26.1f} %")
        verdict = "confirmed" if t.confirmed else "NOT confirmed"
        kept = ("applied: the board keeps these gains" if t.applied else
                "not applied (--apply keeps a confirmed design)" if t.confirmed else
                "the board keeps its gains")
        echo_out(f"  {verdict}: {t.why}; {kept}")


def _plot(path: Path, results: list[Tuned], force: bool) -> None:
    from fpgalink.bringup.design import predict_step
    from fpgalink.cli.figures import new_figure, save_figure

    figure = new_figure((9, 3.2 * len(results) + 0.5))
    axes = figure.subplots(len(results), 1, squeeze=False)[:, 0]
    for ax, t in zip(axes, results, strict=True):
        horizon = float(t.step.t[-1]) if len(t.step.t) else 3.0
        times, speed, _ = predict_step(t.model, t.design.gains, period=t.design.period,
                                       target=t.design.target, limit=t.limit,
                                       duration=horizon, counts_per_turn=t.counts_per_turn)
        ax.plot(t.step.t, t.step.speed, color="tab:blue", label="on the board")
        ax.plot(times, speed, color="tab:orange", linestyle="--", label="predicted")
        band = 0.02 * t.design.target
        ax.axhspan(t.design.target - band, t.design.target + band, color="tab:green",
                   alpha=0.12, label="±2 %")
        ax.set_title(f"board {t.board} channel {t.channel}: Kp {t.design.gains.kp:.0f}, Ti "
                     f"{t.design.gains.ti:.3f} s — "
                     f"{'confirmed' if t.confirmed else 'NOT confirmed'}")
        ax.set_ylabel("deg/s")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
    axes[-1].set_xlabel("s after the step")
    save_figure(figure, path, force=force)


def _save(path: Path, results: list[Tuned], conn: ConnectionOptions) -> None:
    from fpgalink.bringup.robotfile import EditError, set_values
    from fpgalink.protocol.robot import SEED_ROBOT_TOML, DescriptionError, parse_robot
    from fpgalink.protocol.tomlfile import TomlFileError, parse_toml

    existing = path.read_text(encoding="utf-8") if path.is_file() else None
    boards = {t.board for t in results}
    robot_file = False
    if existing is not None:
        try:
            robot_file = "wheels" in parse_toml(existing, str(path))
        except TomlFileError as exc:
            raise CliError(f"--save {exc}", ExitCode.BAD_INPUT) from None
    elif len(boards) > 1:
        robot_file = True
        source = conn.settings.robot
        existing = Path(source).read_text(encoding="utf-8") if source else SEED_ROBOT_TOML
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    values: dict[tuple[str, str], float] = {}
    for t in results:
        table = f"board_parameters.{t.board}.{t.channel}" if robot_file else t.channel
        g = t.design.gains
        values.update({(table, "Kp_Wheel_Pid"): g.kp, (table, "Ti_Wheel_Pid"): g.ti,
                       (table, "Td_Wheel_Pid"): g.td})
    header = (f"# Speed PID gains from fpgalink-cli autotune, {when}: "
              f"{'; '.join(f'{t.board}/{t.channel} {t.why}' for t in results)}\n")
    try:
        text = set_values(existing if existing is not None else header, values, str(path))
        if robot_file:
            parse_robot(text, str(path))
        else:
            from fpgalink.protocol.paramfile import parse_parameter_file

            parse_parameter_file(text, str(path))
    except (EditError, DescriptionError, TomlFileError, ValueError) as exc:
        raise CliError(f"--save {exc}", ExitCode.FAILURE) from None
    write_text(path, text, force=True)  # an edit in place (or a new file)
    what = "robot file" if robot_file else "parameter set"
    note(f"saved the confirmed gains to {path} ({what}" + (
        "; load it with fpgalink-cli param load FILE)" if not robot_file else ")"))
