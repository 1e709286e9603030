"""``bench``: the message-throughput benchmark (codec, host stack, paced wire, two boards),
side by side with pymavlink. The measuring lives in :mod:`fpgalink._bench`, which
``benchmarks/throughput.py`` runs too, so both print the same figures."""

from __future__ import annotations

from pathlib import Path

import click

from fpgalink import _bench

__all__ = ["bench", "default_output"]


def default_output() -> Path:
    """``benchmarks/results/throughput.json`` when run from a checkout (where the README's
    figures are kept), else ``throughput.json`` here."""
    results = Path("benchmarks") / "results"
    return (results if Path("benchmarks").is_dir() else Path()) / f"{_bench.NAME}.json"


@click.command()
@click.option("--quick", is_flag=True,
              help="Tiny counts and short streams, one repetition (< 20 s; the smoke test).")
@click.option("--reps", type=click.IntRange(1, 100), default=None,
              help="Repetitions per measurement (default 5, --quick 1).")
@click.option("--window", "window_s", type=click.FloatRange(0.2, 600), default=None,
              help="Seconds of paced streaming per repetition (default 5, --quick 1).")
@click.option("--seed", type=int, default=_bench.SEED, show_default=True,
              help="Seed for the random message contents.")
@click.option("--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="JSON report path [default: benchmarks/results/throughput.json in a "
                   "checkout, else ./throughput.json].")
@click.option("--no-progress", is_flag=True, help="No progress bar on stderr.")
def bench(quick: bool, reps: int | None, window_s: float | None, seed: int,
          output: Path | None, no_progress: bool) -> None:
    """Measure message throughput of the whole stack and compare the codec with pymavlink.

    Starts `python -m fpgaemu serve --pty` twice (one board, then two) for the paced
    sections. Prints one table on stdout and writes every repetition to a JSON report."""
    config = _bench.BenchConfig.make(quick=quick, reps=reps, window_s=window_s, seed=seed)
    report = _bench.run(config, progress=not no_progress)
    path = _bench.write(report, output if output is not None else default_output())
    _bench.print_report(report)
    click.echo(f"\n{report['timing']['total_s']:.0f} s in all; results in {path}")
