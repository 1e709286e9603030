"""What ``identify``, ``autotune`` and ``calibrate`` share: the identification's options,
running it on a board with its recording (through the one recording path every command
writes by: :mod:`fpgalink.recording`), the fit, and how a fit is shown (table, JSON,
plot)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from fpgalink.cli.output import CliError, ExitCode, FiniteRange, classify, echo_out, note
from fpgalink.recording import RecordingError

if TYPE_CHECKING:
    from fpgalink.aio.link import Link
    from fpgalink.bringup.plant import DiscreteModel, PlantFit
    from fpgalink.bringup.session import ChannelRecord
    from fpgalink.protocol import Telemetry

__all__ = ["Identification", "Recorder", "fit_document", "fit_record", "identification",
           "identification_options", "identify_on", "load_model", "print_fit",
           "record_from_file", "recording", "save_fit_plot", "write_text"]

T = TypeVar("T")

MAX_DUTY = 32760
#: The seed's identification's sample time: the fit is shown at it too, to compare.
SEED_TS = 0.05


def _orders(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int, int]:
    try:
        nb, nf, nk = (int(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r}: give NB,NF,NK, e.g. 2,3,1", ctx, param) from None
    if not (1 <= nb <= nf <= 8 and 1 <= nk <= 50):
        raise click.BadParameter(f"{value!r}: need 1 ≤ NB ≤ NF ≤ 8 and 1 ≤ NK ≤ 50", ctx, param)
    return nb, nf, nk


def identification_options(func: Callable[..., T]) -> Callable[..., T]:
    """``--wheels``, ``--max-duty`` (both needed to drive: :func:`identification`), the
    excitation's and the fit's options, ``--record``."""
    for option in reversed([
        click.option("--wheels", type=click.Choice(["air", "ground"]),
                     help="Where the wheels are: air (the robot on blocks: the duty steps "
                          "between 40 and 100 % of --max-duty, one way round) or ground "
                          "(between −100 and +100 %, so the robot rocks where it stands)."),
        click.option("--max-duty", type=FiniteRange(min=0, min_open=True, max=100),
                     metavar="PERCENT",
                     help="The largest duty the experiment may apply, % of full "
                          "(MaxControlSignal while it runs)."),
        click.option("--duration", type=FiniteRange(min=3, max=600), default=20.0,
                     show_default=True, help="How long the excitation runs, s."),
        click.option("--bit", "bit_s", type=FiniteRange(min=0.01, max=10), default=0.2,
                     show_default=True,
                     help="The PRBS's bit time, s (about the plant's time constant)."),
        click.option("--period-ms", type=click.IntRange(1, 1000), default=10,
                     show_default=True,
                     help="TsTimerPeriod while identifying: the fit's sample time."),
        click.option("--orders", default="2,3,1", show_default=True, callback=_orders,
                     metavar="NB,NF,NK",
                     help="The model's zeros, poles and delay (samples): the seed's form."),
        click.option("--offset", is_flag=True,
                     help="Fit a constant output offset too (a drive whose friction makes "
                          "its response affine)."),
        click.option("--record", type=click.Path(dir_okay=False, path_type=Path),
                     help="Record the telemetry into an MCAP file (fpgalink-cli plot reads "
                          "it; identify --from fits it again)."),
    ]):
        func = option(func)
    return func


def identification(wheels: str | None, max_duty: float | None, duration: float, bit_s: float,
                   period_ms: int, orders: tuple[int, int, int], offset: bool,
                   *, driving: bool = True) -> Identification:
    """The options, refused (exit 2) when the run would drive a wheel without being told
    where the wheels are and the largest duty it may apply."""
    if driving and (wheels is None or max_duty is None):
        raise CliError("this drives the wheels: say where they are (--wheels air|ground) and "
                       "the largest duty it may apply (--max-duty PERCENT); nothing was sent",
                       ExitCode.BAD_INPUT)
    return Identification(wheels or "air", max_duty or 100.0, duration, bit_s, period_ms,
                          orders, offset)


@dataclass(frozen=True)
class Identification:
    """The options of one identification."""

    wheels: str
    max_duty: float  #: percent
    duration: float
    bit_s: float
    period_ms: int
    orders: tuple[int, int, int]
    offset: bool

    @property
    def where(self) -> str:
        """Where the wheels are, in words."""
        return "in the air" if self.wheels == "air" else "on the ground"

    @property
    def limit(self) -> int:
        return max(1, round(self.max_duty / 100.0 * MAX_DUTY))


class Recorder:
    """``--record``: every board's telemetry as ``record`` writes it, a metadata record per
    fit, and any topic of the command's own (``extra_topics``), through the one recording
    path (:class:`fpgalink.recording.McapSink`: ``NAME.partial`` put in place when complete,
    an existing file refused unless ``--force``, checked before anything drives). The first
    write that fails (a full disk) stops the recording and sets ``stop``: the experiment
    ends as on Ctrl-C, the board disabled and set back; :meth:`close` then says what is on
    disk, one line, exit 1 — as ``record`` and ``drive --record`` do."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str],
                 stop: asyncio.Event, *, force: bool,
                 extra_topics: dict[str, dict[str, Any]] | None = None) -> None:
        from fpgalink.cli.sinks import McapSink

        try:
            self.sink = McapSink(path, boards, metadata, extra_topics, force=force)
        except RecordingError as exc:
            raise classify(exc) from None
        self.path = path
        self.stop = stop
        self.failed = False

    def write(self, call: Callable[..., None], *args: Any) -> None:
        """One write; a failure stops the recording and the run (said at :meth:`close`)."""
        if self.failed:
            return
        try:
            call(*args)
        except RecordingError:
            self.failed = True
            self.stop.set()

    def add(self, topic: str, record: dict[str, Any], log_time: float) -> None:
        """A message on one of ``extra_topics``."""
        self.write(self.sink.add, topic, record, log_time)

    def on_sample(self, board: str) -> Callable[[Telemetry], None]:
        """A writer for ``board``'s samples: received at the host's time, sampled at the
        board's (its ``t_us`` from the first sample, on the host's clock then)."""
        from fpgalink.boardclock import BoardClock
        from fpgalink.recording import compact, json_safe, telemetry_row

        clock = BoardClock()

        def write(sample: Telemetry) -> None:
            now = time.time()
            sampled = clock.seconds(sample.t_us, now)
            row = json_safe({k: compact(v) for k, v in telemetry_row(sample, sampled).items()})
            self.write(self.sink.telemetry, board, row, now, sampled)

        return write

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self.write(self.sink.metadata, name, data)

    def close(self, *, failing: bool = False) -> None:
        """Finish the file and put it in place. A recording that stopped early (or cannot
        be finished) is one line, exit 1, saying what is on disk; ``failing`` (another
        error is on its way out: that one is the command's) says it as a note."""
        try:
            self.sink.close()
        except RecordingError as exc:
            if failing:
                note(str(exc))
                return
            raise classify(exc) from None
        note(f"recorded {self.sink.messages} messages to {self.path}")


@contextlib.contextmanager
def recording(recorder: Recorder | None) -> Iterator[Recorder | None]:
    """``recorder`` closed however the block ends (see :meth:`Recorder.close`)."""
    try:
        yield recorder
    except BaseException:
        if recorder is not None:
            recorder.close(failing=True)
        raise
    if recorder is not None:
        recorder.close()


async def identify_on(link: Link, board: str, channel: str, options: Identification,
                      stop: asyncio.Event, recorder: Recorder | None) -> ChannelRecord:
    """The identification run on one channel (:func:`fpgalink.bringup.session.identify_channel`)."""
    from fpgalink.bringup.excitation import Excitation
    from fpgalink.bringup.session import ExperimentError, identify_channel

    excitation = Excitation.for_wheels(options.wheels, options.limit,
                                       duration_s=options.duration, bit_s=options.bit_s)
    note(f"identifying board {board} channel {channel}: wheels {options.where}, duty "
         f"up to {options.max_duty:g} % for {options.duration:g} s")
    try:
        return await identify_channel(
            link, channel, excitation, period_ms=options.period_ms, limit=options.limit,
            stop=stop, on_sample=None if recorder is None else recorder.on_sample(board))
    except ExperimentError as exc:
        raise CliError(f"board {board}: identification: {exc}", ExitCode.STOPPED) from None


def fit_record(record: ChannelRecord, options: Identification, where: str) -> PlantFit:
    from fpgalink.bringup.plant import FitError, fit_plant

    u, y, _ = record.grid()
    nb, nf, nk = options.orders
    try:
        return fit_plant(u, y, record.period_s, nb=nb, nf=nf, nk=nk, offset=options.offset)
    except FitError as exc:
        raise CliError(f"{where}: cannot fit the plant: {exc}", ExitCode.FAILURE) from None


def _pole(s: complex) -> dict[str, float]:
    return {"re": s.real, "im": s.imag}


def fit_document(fit: PlantFit, board: str, channel: str) -> dict[str, Any]:
    """A fit as JSON has it: numbers, the unit in each key."""
    model = fit.model
    continuous = fit.continuous
    fopdt = continuous.fopdt()
    seed_form = continuous.discretize(SEED_TS)
    return {
        "board": board, "channel": channel, "samples": fit.samples, "missing": fit.missing,
        "ts_s": model.ts, "b": list(model.b), "f": list(model.f), "nk": model.nk,
        "offset_dps": model.offset,
        "dc_gain_dps_per_count": model.dc_gain, "full_duty_speed_dps": model.dc_gain * MAX_DUTY,
        "poles_z": [_pole(z) for z in model.poles],
        "poles_rad_s": [_pole(s) for s in continuous.poles],
        "dominant_pole_rad_s": continuous.dominant_pole.real,
        "time_constant_s": continuous.time_constant, "delay_s": model.nk * model.ts,
        "fopdt": {"gain_dps_per_count": fopdt.gain, "tau_s": fopdt.tau,
                  "dead_time_s": fopdt.dead_time},
        "fit_percent": fit.fit_percent, "estimation_fit_percent": fit.estimation_fit_percent,
        "residual_dps": fit.residual,
        "at_seed_ts": {"ts_s": SEED_TS, "b": list(seed_form.b), "f": list(seed_form.f),
                       "nk": seed_form.nk},
    }


def _polynomial(coefficients: list[float], first: int) -> str:
    terms = []
    for i, c in enumerate(coefficients):
        power = first + i
        terms.append(f"{c:+.5g}" + (f" z^-{power}" if power else ""))
    return " ".join(terms).lstrip("+")


def fit_lines(document: dict[str, Any]) -> list[str]:
    """The fit for people, a figure a line."""
    d = document
    poles = ", ".join(f"{p['re']:.3f}" + (f" ± {abs(p['im']):.3f}j" if p["im"] > 1e-9 else "")
                      for p in d["poles_rad_s"] if p["im"] >= -1e-9)
    z = ", ".join(f"{p['re']:.4f}" + (f" ± {abs(p['im']):.4f}j" if p["im"] > 1e-9 else "")
                  for p in d["poles_z"] if p["im"] >= -1e-9)
    seed = d["at_seed_ts"]
    lost = f", {d['missing']} lost" if d["missing"] else ", none lost"
    return [
        f"Plant of board {d['board']} channel {d['channel']}: {d['samples']} samples every "
        f"{d['ts_s'] * 1000:g} ms{lost}",
        f"  H(z) = ({_polynomial(d['b'], d['nk'])}) / (1 {_polynomial(d['f'], 1)})"
        if d["f"][0] < 0 else
        f"  H(z) = ({_polynomial(d['b'], d['nk'])}) / (1 +{_polynomial(d['f'], 1)})",
        f"  DC gain       {d['dc_gain_dps_per_count']:.6g} deg/s per PWM count "
        f"({d['full_duty_speed_dps']:.2f} deg/s at full duty)"
        + (f", offset {d['offset_dps']:.3f} deg/s" if d["offset_dps"] else ""),
        f"  poles         z = {z}; s = {poles} rad/s",
        f"  dominant      {d['dominant_pole_rad_s']:.3f} rad/s (time constant "
        f"{d['time_constant_s']:.3f} s); delay {d['nk']} sample(s), {d['delay_s']:.3f} s",
        f"  FOPDT         K {d['fopdt']['gain_dps_per_count']:.6g} deg/s per count, τ "
        f"{d['fopdt']['tau_s']:.3f} s, θ {d['fopdt']['dead_time_s']:.3f} s",
        f"  fit           {d['fit_percent']:.2f} % on held-out data (the last 30 %; "
        f"{d['estimation_fit_percent']:.2f} % on the rest), residual "
        f"{d['residual_dps']:.3f} deg/s RMS",
        f"  at Ts {seed['ts_s']:g} s  H(z) = ({_polynomial(seed['b'], seed['nk'])}) / "
        f"(1 {_polynomial(seed['f'], 1)})  (the seed's form, to compare with §3.4)",
    ]


def print_fit(fmt: str, documents: list[dict[str, Any]]) -> None:
    from fpgalink.cli.formats import Column, emit_document, emit_rows

    if fmt == "json":
        emit_document(documents[0] if len(documents) == 1 else documents)
    elif fmt == "csv":
        keys = ["board", "channel", "samples", "missing", "ts_s", "dc_gain_dps_per_count",
                "full_duty_speed_dps", "dominant_pole_rad_s", "time_constant_s", "delay_s",
                "fit_percent", "residual_dps"]
        emit_rows(fmt, [Column(k, k) for k in keys], documents)
    else:
        for document in documents:
            for line in fit_lines(document):
                echo_out(line)


def save_fit_plot(path: Path, record: ChannelRecord, fit: PlantFit, title: str, *,
                  force: bool) -> None:
    """Measured and simulated speed with the duty (the held-out part shaded), the model's
    step response, and its Bode plot."""
    import numpy as np

    from fpgalink.cli.figures import new_figure, save_figure

    u, y, _ = record.grid()
    t = np.arange(len(y)) * record.period_s
    continuous = fit.continuous
    figure = new_figure((10, 9))
    grid = figure.add_gridspec(3, 2, height_ratios=[2, 1, 2])
    top = figure.add_subplot(grid[0, :])
    top.plot(t, y, color="tab:blue", linewidth=1.0, label="measured speed")
    top.plot(t, fit.simulated, color="tab:orange", linewidth=1.0, linestyle="--",
             label=f"model ({fit.fit_percent:.1f} % on held-out data)")
    top.axvspan(t[fit.validation_start], t[-1], color="tab:grey", alpha=0.12,
                label="held out")
    top.set_ylabel("speed, deg/s")
    top.set_title(title)
    top.legend(loc="lower right", fontsize="small")
    top.grid(True, alpha=0.3)
    duty = figure.add_subplot(grid[1, :], sharex=top)
    duty.plot(t, u, color="tab:green", linewidth=1.0, drawstyle="steps-post")
    duty.set_ylabel("PWM, counts")
    duty.set_xlabel("board time, s")
    duty.grid(True, alpha=0.3)
    step = figure.add_subplot(grid[2, 0])
    horizon = continuous.delay + 6 * continuous.time_constant
    ts = np.linspace(0, horizon, 400)
    step.plot(ts, continuous.step(ts, MAX_DUTY), color="tab:blue", label="model")
    fopdt = continuous.fopdt()
    first = np.where(ts >= fopdt.dead_time,
                     fopdt.gain * MAX_DUTY * (1 - np.exp(-(ts - fopdt.dead_time) / fopdt.tau)),
                     0.0)
    step.plot(ts, first, color="tab:red", linestyle=":", label="FOPDT summary")
    step.set_xlabel("s")
    step.set_ylabel("deg/s at full duty")
    step.set_title("step response")
    step.legend(fontsize="small")
    step.grid(True, alpha=0.3)
    bode = figure.add_subplot(grid[2, 1])
    omega = np.logspace(-1, math.log10(math.pi / record.period_s), 400)
    response = continuous.frequency_response(omega) * MAX_DUTY
    bode.semilogx(omega, 20 * np.log10(np.abs(response)), color="tab:blue",
                  label="|G|, dB (deg/s at full duty)")
    phase = bode.twinx()
    phase.semilogx(omega, np.degrees(np.unwrap(np.angle(response))), color="tab:orange",
                   label="phase, deg")
    bode.set_xlabel("rad/s")
    bode.set_title("Bode")
    bode.grid(True, which="both", alpha=0.3)
    bode.legend(loc="lower left", fontsize="small")
    phase.legend(loc="upper right", fontsize="small")
    save_figure(figure, path, force=force)


def load_model(path: Path) -> DiscreteModel:
    from fpgalink.bringup.modelfile import model_from_toml
    from fpgalink.bringup.plant import FitError
    from fpgalink.protocol.tomlfile import TomlFileError, read_bounded

    try:
        with path.open("rb") as stream:
            text = read_bounded(stream, str(path))
        return model_from_toml(text, str(path))
    except OSError as exc:
        raise CliError(f"--model {path}: cannot read: {exc.strerror or exc}",
                       ExitCode.BAD_INPUT) from None
    except (FitError, TomlFileError) as exc:
        raise CliError(f"--model {exc}", ExitCode.BAD_INPUT) from None


def record_from_file(path: Path, board: str | None, channel: str
                     ) -> tuple[str, ChannelRecord, int]:
    """A recording's telemetry of ``channel`` (``fpgalink-cli record``, ``identify --record``):
    (the board's name, its samples in the board's time, how many damaged parts were skipped
    — each named on stderr, as ``plot`` names them)."""
    import numpy as np

    from fpgalink.bringup.session import ChannelRecord
    from fpgalink.cli.plot import read_series
    from fpgalink.protocol import ChannelTelemetry

    prefix = channel.lower()
    fields = ["t_us", f"{prefix}_pwm", f"{prefix}_speed", f"{prefix}_ref", f"{prefix}_flags"]
    reading = read_series(path, None, fields)
    for damage in reading.damage:
        note(f"damaged: {damage}; skipped")
    damaged = len(reading.damage) + (1 if reading.orphans else 0)
    topics = sorted({s.topic for s in reading.series})
    if board is not None:
        topics = [t for t in topics if t == f"/board/{board}/telemetry"]
    if len(topics) != 1:
        found = ", ".join(t.split("/")[2] for t in sorted({s.topic for s in reading.series}))
        raise CliError(f"--from {path}: " + (f"no telemetry of board {board} (it has: "
                       f"{found or 'none'})" if board is not None or not found else
                       f"telemetry of several boards ({found}): pick one with --board NAME"),
                       ExitCode.BAD_INPUT)
    topic = topics[0]
    columns = {s.field: dict(zip(s.t, s.values, strict=True)) for s in reading.series
               if s.topic == topic}
    stamps = sorted(set.intersection(*(set(columns.get(f, {})) for f in fields)))
    if len(stamps) < 50:
        raise CliError(f"--from {path}: {len(stamps)} complete samples of channel {channel}: "
                       "too few to fit", ExitCode.BAD_INPUT)
    t_us = [int(columns["t_us"][s]) for s in stamps]
    period_us = float(np.median(np.diff(t_us) % (1 << 32)))
    record = ChannelRecord(channel, round(period_us) / 1e6)
    for s, t in zip(stamps, t_us, strict=True):
        record.add(t, ChannelTelemetry(0, columns[f"{prefix}_speed"][s], 0.0,
                                       int(columns[f"{prefix}_pwm"][s]),
                                       columns[f"{prefix}_ref"][s],
                                       int(columns[f"{prefix}_flags"][s])))
    return topic.split("/")[2], record, damaged


def write_text(path: Path, text: str, *, force: bool) -> None:
    """``text`` into ``path`` the way every file a command writes goes
    (:func:`fpgalink.cli.files.write_file`): whole or not at all, through ``NAME.partial``;
    an existing one replaced only with ``force`` (an edit of a file in place passes it)."""
    from fpgalink.cli.files import write_file

    write_file(path, text.encode("utf-8"), force=force)
