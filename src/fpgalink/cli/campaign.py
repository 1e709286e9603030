"""``campaign`` and ``tune``: many scenarios on emulated robots, on every core (or a Dask
cluster), into one table (docs/campaigns.md)."""

from __future__ import annotations

import contextlib
import itertools
import math
import signal
import sys
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import click

from fpgalink.campaign import (
    Campaign,
    CampaignError,
    Result,
    default_jobs,
    load_campaign,
    parse_campaign,
    run_campaign,
)
from fpgalink.campaign.results import (
    RUN_COLUMNS,
    columns,
    rows,
    write_csv,
    write_json,
    write_parquet,
)
from fpgalink.campaign.runner import check_runnable
from fpgalink.campaign.scenario import TOTALS
from fpgalink.campaign.spec import (
    MAX_ACTION_S,
    MAX_SCENARIOS,
    MAX_STEP_DPS,
    check_surface,
)
from fpgalink.cli.figures import check_plot_path
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.formats import Column, emit_rows, format_option
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    classify,
    console,
    note,
)
from fpgalink.cli.termination import Terminated, on_sigterm
from fpgalink.protocol.robot import seed_robot

__all__ = ["campaign", "tune"]

#: The seed's §3.4 pidtune gains (high gear) converted to this board's units
#: (docs/emulator.md §12: Kp 7.11, Ti 23.66, Td 0.43 in Matlab's units).
SEED_GAINS = {"Kp_Wheel_Pid": 2502.0, "Ti_Wheel_Pid": 0.30, "Td_Wheel_Pid": 0.060}
GAIN_NAMES = {"kp": "Kp_Wheel_Pid", "ti": "Ti_Wheel_Pid", "td": "Td_Wheel_Pid"}


def _check_jobs(jobs: int | None) -> None:
    if jobs is not None and jobs < 1:
        raise CliError("--jobs must be at least 1", ExitCode.BAD_INPUT)


def _run(spec: Campaign, jobs: int | None, dask: str | None, quiet: bool,
         mcap_dir: Path | None = None) -> list[Result]:
    # First: a SIGTERM from here on ends the campaign and its workers (exit 143).
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        return _run_campaign(spec, jobs, dask, quiet, mcap_dir)
    except Terminated:
        note("terminated: the campaign and its workers were stopped")
        sys.exit(128 + signal.SIGTERM)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run_campaign(spec: Campaign, jobs: int | None, dask: str | None, quiet: bool,
                  mcap_dir: Path | None) -> list[Result]:
    total = len(spec.scenarios)
    where = f"Dask ({dask})" if dask else \
        f"{min(jobs or default_jobs(), total)} process(es)"
    if not quiet:
        note(f"campaign {spec.name}: {total} scenario(s) on {where}")
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    failed = 0
    # The campaign's name is the user's text: shown as it is, never read as markup.
    with Progress(TextColumn("{task.description}", style="progress.description",
                             markup=False), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console(stderr=True), transient=True,
                  disable=quiet or not sys.stderr.isatty()) as progress:
        task = progress.add_task(spec.name, total=total)

        def done(result: Result) -> None:
            nonlocal failed
            progress.advance(task)
            if not result.ok:
                failed += 1
                note(f"scenario {result.index} ({result.name}) failed: {result.error}")
            if result.mcap_error is not None:
                note(f"scenario {result.index} ({result.name}): recording: "
                     f"{result.mcap_error}")

        try:
            return run_campaign(spec, jobs=jobs, dask=dask, on_result=done,
                                mcap_dir=mcap_dir)
        except CampaignError as exc:
            raise CliError(str(exc), ExitCode.BAD_INPUT) from None


#: What ``--out`` holds besides the recordings.
RESULT_FILES = ("results.csv", "results.json", "results.parquet", "summary.png")


def _make_directory(directory: Path, option: str) -> None:
    """``directory`` made before the first scenario runs, not after the last; one line
    naming ``option`` when it cannot be."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"{option} {directory}: {exc.strerror or exc}") from None


def _check_out(out: Path, spec: Campaign, recorded: bool, force: bool) -> None:
    """Before the first scenario: every file the campaign will write into ``out`` (results,
    recordings) may be written — none is there, unless ``--force``."""
    from fpgalink.campaign.runner import recording_paths

    if not out.is_dir():
        return
    paths = [out / name for name in RESULT_FILES]
    if recorded:
        paths += [Path(p) for p in recording_paths(spec.scenarios, out).values() if p]
    for path in paths:
        check_output(path, force=force)


def _write_result(path: Path, write: Any, table: list[dict[str, Any]], force: bool) -> bool:
    """One results file through ``NAME.partial``, put in place when whole; ``False`` when
    ``write`` wrote nothing (parquet without pyarrow)."""
    from fpgalink.recording import Output, RecordingError

    try:
        output = Output(path, force=force)
        try:
            written = write(output.path, table) is not False
        except OSError as exc:
            output.discard()
            raise RecordingError(f"{path}: cannot write: {exc.strerror or exc}") from None
        if not written:
            output.discard()
            return False
        output.commit()
    except RecordingError as exc:
        raise classify(exc) from None
    return True


def _write(out: Path | None, table: list[dict[str, Any]], spec: Campaign,
           force: bool) -> None:
    if out is None:
        return
    recorded = sum(1 for row in table if row.get("mcap"))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"--out {out}: {exc.strerror or exc}") from None
    _write_result(out / "results.csv", write_csv, table, force)
    _write_result(out / "results.json", write_json, table, force)
    parquet = _write_result(out / "results.parquet", write_parquet, table, force)
    written = "results.csv, results.json" + (", results.parquet" if parquet else "")
    if _summary_plot(out / "summary.png", table, spec, force):
        written += ", summary.png"
    if recorded:
        written += f" and {recorded} recording(s) (INDEX-NAME.mcap)"
    note(f"wrote {written} into {out}")


def _summary_plot(path: Path, table: list[dict[str, Any]], spec: Campaign,
                  force: bool) -> bool:
    """One bar chart per numeric figure column (up to six), a bar per scenario."""
    try:
        from fpgalink.cli.figures import new_figure, save_figure
    except ImportError:
        return False
    figure_columns = [c for c in columns(table) if "." in c and any(
        isinstance(row.get(c), int | float) and not isinstance(row.get(c), bool)
        for row in table)][:6]
    if not figure_columns:
        return False
    try:
        figure = new_figure((8.0, 2.2 * len(figure_columns)))
    except ImportError:
        return False
    labels = [f"{row['index']}" for row in table]
    for number, name in enumerate(figure_columns, 1):
        axes = figure.add_subplot(len(figure_columns), 1, number)
        values = [row.get(name) for row in table]
        heights = [v if isinstance(v, int | float) and math.isfinite(v) else 0.0
                   for v in values]
        axes.bar(labels, heights)
        axes.set_ylabel(name, fontsize=7)
    figure.axes[0].set_title(f"campaign {spec.name}: one bar per scenario (index)")
    figure.axes[-1].set_xlabel("scenario")
    save_figure(figure, path, force=force)
    return True


@contextlib.contextmanager
def _out_lock(directory: Path | None) -> Iterator[None]:
    """The lock on a directory of results and recordings, held while the block runs (none
    without one); a campaign writing there already is one line, exit 5."""
    if directory is None:
        yield
        return
    from fpgalink.recording import DirectoryLock, RecordingError

    try:
        with DirectoryLock(directory):
            yield
    except RecordingError as exc:
        raise classify(exc) from None


def _emit(fmt: str, table: list[dict[str, Any]], title: str) -> None:
    if fmt != "table":
        emit_rows(fmt, [Column(n, n) for n in columns(table)], table)
        return
    # For people: one table per kind of row (scenarios with the same figures share one),
    # what tells rows apart first, how it ran last.
    kinds: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for row in table:
        kinds.setdefault(tuple(k for k, v in row.items() if "." in k and v is not None),
                         []).append(row)
    for group in kinds.values():
        # A setting every row of the group shares goes into the title, not a column.
        shared = {n: group[0].get(n) for n in columns(group) if n not in _NOT_SETTINGS
                  and "." not in n and len({str(row.get(n)) for row in group}) == 1}
        names = [n for n in columns(group) if n not in (*_NOT_SHOWN, *shared) and (
            n in ("index", "status") or any(row.get(n) not in (None, "") for row in group))]
        if len({row["scenario"] for row in group}) == 1:
            shared = {"scenario": group[0]["scenario"], **shared}
            names.remove("scenario")
        cols = [Column(n, n, render=_cell, drop=0 if n in ("index", "status") else 1 + i)
                for i, n in enumerate(names)]
        said = ", ".join(f"{k} {_cell(v)}" for k, v in shared.items() if v not in (None, ""))
        emit_rows(fmt, cols, group, title=title + (f" ({said})" if said else ""))


#: Columns that are not a scenario's settings: its identity, how it ran, its totals.
_NOT_SETTINGS = frozenset({"index", "scenario", "status", "error", *RUN_COLUMNS, *TOTALS})
#: Left out of the table for people: where it ran, and the recordings (their paths are long,
#: and a failed one is said on stderr as it happens).
_NOT_SHOWN = ("worker", "mcap", "mcap_error")


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


@click.command(epilog=EXIT_CODES_HELP + " A campaign with failed scenarios exits 1.")
@click.argument("spec_file", metavar="SPEC.toml",
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("--jobs", "-j", type=int, default=None,
              help="Processes to run scenarios on [default: every core].")
@click.option("--dask", metavar="ADDRESS",
              help="Run on a Dask cluster: its scheduler's address (tcp://host:8786), or "
                   "'local' for a LocalCluster of --jobs workers on this machine.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Write results.csv, results.json (results.parquet with pyarrow) and "
                   "summary.png into this directory.")
@click.option("--mcap/--no-mcap", default=None,
              help="Record every scenario (or none) into --out as INDEX-NAME.mcap: "
                   "telemetry, events and the truth in emulated time [default: the "
                   "scenarios the file marks mcap = true].")
@force_option
@format_option
def campaign(spec_file: Path, jobs: int | None, dask: str | None, out: Path | None,
             mcap: bool | None, force: bool, fmt: str) -> None:
    """Run the scenarios of SPEC.toml on emulated robots and print their figures.

    Each scenario runs on a fresh in-process emulated robot, as fast as it goes (emulated
    time), one row of figures per scenario; the same campaign gives the same figures
    wherever it runs (docs/campaigns.md)."""
    _check_jobs(jobs)
    try:
        spec = load_campaign(spec_file)
        check_runnable(spec.scenarios, dask=dask, where=str(spec_file))
    except CampaignError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    if mcap is not None:
        spec = replace(spec, scenarios=tuple(replace(s, mcap=mcap) for s in spec.scenarios))
    recorded = sum(s.mcap for s in spec.scenarios)
    if recorded:
        if out is None:
            raise CliError("recording MCAP (--mcap, or mcap = true in the file) writes into "
                           "--out DIR: give one", ExitCode.BAD_INPUT)
        _make_directory(out, "--out")
    # One campaign at a time in --out (a second is refused, exit 5), held until its results
    # are written; what it will write checked before anything runs.
    with _out_lock(out):
        if out is not None:
            _check_out(out, spec, recorded > 0, force)
        results = _run(spec, jobs, dask, quiet=fmt != "table",
                       mcap_dir=out if recorded else None)
        table = rows(results)
        _write(out, table, spec, force)
    _emit(fmt, table, f"campaign {spec.name}")
    failed = sum(not r.ok for r in results)
    unrecorded = sum(r.mcap_error is not None for r in results)
    said = [f"{failed} of {len(results)} scenario(s) failed"] if failed else []
    if unrecorded:
        said.append(f"{unrecorded} of {recorded} recording(s) failed")
    if said:
        raise CliError("; ".join(said), ExitCode.FAILURE)


def _grid(entries: Sequence[str]) -> list[tuple[str, list[float]]]:
    """``--grid`` entries → (gain, values), each gain once; the combinations are counted
    from the entries' lengths before a value is read or a combination built."""
    given: dict[str, str] = {}
    words: list[tuple[str, str, list[str]]] = []
    for entry in entries:
        name, sep, values = entry.partition("=")
        key = GAIN_NAMES.get(name.strip().lower())
        if not sep or key is None:
            raise CliError(f"--grid {_short(entry)!r}: write Kp=V1,V2,…, Ti=…, or Td=…",
                           ExitCode.BAD_INPUT)
        if key in given:  # a second Kp= would silently replace the first
            raise CliError(f"--grid {_short(entry)!r}: {name.strip()} given twice (also "
                           f"--grid {_short(given[key])!r}): one --grid per gain, every "
                           "value in it (Kp=500,600)", ExitCode.BAD_INPUT)
        given[key] = entry
        words.append((key, entry, [v for v in values.split(",") if v.strip()]))
    if not words:
        raise CliError("--grid: give at least one of Kp=…, Ti=…, Td=…", ExitCode.BAD_INPUT)
    combinations = math.prod(len(texts) for _, _, texts in words)
    most = MAX_SCENARIOS - 1  # and the seed's row
    if combinations > most:
        product = " × ".join(f"{len(texts):,}" for _, _, texts in words)
        raise CliError(f"--grid: {combinations:,} combinations ({product}); at most {most:,}",
                       ExitCode.BAD_INPUT)
    grid = []
    for key, entry, texts in words:
        try:
            numbers = [float(v) for v in texts]
        except ValueError:
            raise CliError(f"--grid {_short(entry)!r}: values must be numbers",
                           ExitCode.BAD_INPUT) from None
        if not numbers or not all(math.isfinite(v) for v in numbers):
            raise CliError(f"--grid {_short(entry)!r}: give finite numbers",
                           ExitCode.BAD_INPUT)
        grid.append((key, numbers))
    return grid


def _short(text: str, most: int = 60) -> str:
    """A user's long option value, cut for a one-line message."""
    return text if len(text) <= most else text[:most - 1] + "…"


def _score(row: dict[str, Any]) -> tuple[float, float, float]:
    """Settled soonest, then least overshoot, then fastest rise; unsettled last."""
    def num(key: str) -> float:
        value = row.get(key)
        return float(value) if isinstance(value, int | float) else math.inf
    return (num("step.settling_s"), num("step.overshoot_pct"), num("step.rise_s"))


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--channel", "-c", type=click.Choice(["A", "B"], case_sensitive=False),
              required=True, help="The channel whose gains are tuned, on every board.")
@click.option("--grid", "-g", "grid_entries", multiple=True, required=True,
              metavar="NAME=V1,V2,…",
              help="Gains to try: Kp=…, Ti=…, Td=… (repeat; every combination runs).")
@click.option("--surface", default="gravel", show_default=True,
              help="The ground the robot stands on: with --body kinematic a surface of the "
                   "seed's robot (ideal, gravel, marble, grass), with mujoco gravel, marble, "
                   "grass, slope45-sand or stairs.")
@click.option("--body", type=click.Choice(["kinematic", "mujoco"]), default="kinematic",
              show_default=True)
@click.option("--to", "target", type=FiniteRange(-MAX_STEP_DPS, MAX_STEP_DPS), default=45.0,
              show_default=True,
              help="The step, deg/s, on every wheel (the robot drives straight).")
@click.option("--seconds", type=FiniteRange(0.0, MAX_ACTION_S, min_open=True), default=2.0,
              show_default=True, help="How long each step is measured (emulated s).")
@click.option("--jobs", "-j", type=int, default=None)
@click.option("--dask", metavar="ADDRESS")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
              help="Save the figures of every combination as a PNG.")
@click.option("--mcap", "mcap_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Record every combination's step into this directory as INDEX-NAME.mcap "
                   "(telemetry, events and the truth in emulated time).")
@force_option
@format_option
def tune(channel: str, grid_entries: tuple[str, ...], surface: str, body: str, target: float,
         seconds: float, jobs: int | None, dask: str | None, plot: Path | None,
         mcap_dir: Path | None, force: bool, fmt: str) -> None:
    """Pick the wheel PID gains that settle a step soonest, from a grid.

    Every wheel steps with each combination of gains set on CHANNEL of every board; the
    best settles soonest (then overshoots least). The seed's §3.4 pidtune gains, converted
    to this board's units, run beside them as the reference row."""
    # Everything the options say is checked before the first combination runs.
    _check_jobs(jobs)
    channel = channel.upper()
    grid = _grid(grid_entries)
    if target == 0:
        raise CliError("--to 0: a step to 0 deg/s from rest is no step", ExitCode.BAD_INPUT)
    try:
        check_surface(body, surface, seed_robot())
    except CampaignError as exc:
        raise CliError(f"--surface {_short(surface)} --body {body}: {exc}",
                       ExitCode.BAD_INPUT) from None
    if plot is not None:
        check_plot_path(plot, force=force)
    combos = [dict(zip([k for k, _ in grid], values, strict=True))
              for values in itertools.product(*(v for _, v in grid))]
    scenarios: list[dict[str, Any]] = [{"name": "seed §3.4", "params": {f"{k}.{channel}": v
                                                  for k, v in SEED_GAINS.items()}}]
    scenarios += [{"name": "grid", "params": {f"{k}.{channel}": v for k, v in combo.items()}}
                  for combo in combos]
    for scenario in scenarios:
        scenario["script"] = [{"step": target, "wheel": channel, "seconds": seconds,
                               "label": "step"}]
    document = {"campaign": {"name": f"tune {channel}", "surface": surface, "body": body,
                             "mcap": mcap_dir is not None},
                "scenario": scenarios}
    try:
        spec = parse_campaign(document, source="tune")
        check_runnable(spec.scenarios, dask=dask, where=f"tune --body {body}")
    except CampaignError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    if mcap_dir is not None:
        _make_directory(mcap_dir, "--mcap")
    with _out_lock(mcap_dir):
        if mcap_dir is not None:
            from fpgalink.campaign.runner import recording_paths

            for path in recording_paths(spec.scenarios, mcap_dir).values():
                if path:
                    check_output(Path(path), force=force)
        results = _run(spec, jobs, dask, quiet=fmt != "table", mcap_dir=mcap_dir)
    table = rows(results)
    for row in table:
        row["kp"], row["ti"], row["td"] = (row.get(f"{name}{channel}")
                                           for name in GAIN_NAMES.values())
    ok = [row for row in table if row["status"] == "ok" and row["scenario"] == "grid"]
    best = min(ok, key=_score) if ok else None
    for row in table:
        row["best"] = row is best
    cols = [Column("scenario", "gains", drop=0), Column("kp", "Kp", render=_cell),
            Column("ti", "Ti s", render=_cell), Column("td", "Td s", render=_cell),
            Column("step.rise_s", "rise s", render=_cell),
            Column("step.settling_s", "settling s", render=_cell),
            Column("step.overshoot_pct", "overshoot %", render=_cell),
            Column("step.error_dps", "error deg/s", render=_cell, drop=2),
            Column("best", "best", render=lambda v: "◀ best" if v else "", drop=0),
            Column("status", "status", drop=3)]
    emit_rows(fmt, cols, table, title=f"tune channel {channel}: step to {target:g} deg/s "
              f"on {surface} ({body})")
    if plot is not None:
        _tune_plot(plot, table, channel, force)
    if best is None:
        raise CliError("no combination ran: see the failures above", ExitCode.FAILURE)
    if mcap_dir is not None:
        unrecorded = sum(r.mcap_error is not None for r in results)
        if unrecorded:
            raise CliError(f"{unrecorded} of {len(results)} recording(s) failed",
                           ExitCode.FAILURE)
        note(f"wrote {len(results)} recording(s) (INDEX-NAME.mcap) into {mcap_dir}")


def _tune_plot(path: Path, table: list[dict[str, Any]], channel: str, force: bool) -> None:
    from fpgalink.cli.figures import new_figure, save_figure

    figure = new_figure((8.0, 6.0))
    names = [("step.settling_s", "settling s"), ("step.overshoot_pct", "overshoot %"),
             ("step.rise_s", "rise s")]
    labels = [f"Kp {_cell(r['kp'])}\nTi {_cell(r['ti'])}\nTd {_cell(r['td'])}"
              + ("\n(seed)" if r["scenario"] == "seed §3.4" else "") for r in table]
    for number, (key, unit) in enumerate(names, 1):
        axes = figure.add_subplot(len(names), 1, number)
        values = [float(r[key]) if isinstance(r.get(key), int | float) else 0.0
                  for r in table]
        colours = ["tab:green" if r["best"] else "tab:gray" if r["scenario"] != "grid"
                   else "tab:blue" for r in table]
        axes.bar(range(len(table)), values, color=colours)
        axes.set_ylabel(unit)
        axes.set_xticks(range(len(table)), labels if number == len(names) else [""] *
                        len(table), fontsize=6)
    figure.axes[0].set_title(f"tune channel {channel}: green the best, grey the seed's gains")
    save_figure(figure, path, force=force)
    note(f"wrote {path}")
