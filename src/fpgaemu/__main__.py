"""``fpgaemu serve``: emulated boards as devices (pty or TCP), paced to the wall clock."""

from __future__ import annotations

import asyncio
import signal
import sys
import tomllib
from pathlib import Path
from typing import Any

import click

from fpgaemu.build import build_board
from fpgaemu.serve import PacedBoard, PtyEndpoint, TcpEndpoint

#: The robot has two boards, one per side; the seed calls them L and R.
BOARD_NAMES = ("L", "R")


def board_names(count: int) -> list[str]:
    return [BOARD_NAMES[i] if i < len(BOARD_NAMES) else f"B{i + 1}" for i in range(count)]


def parse_assignments(values: tuple[str, ...]) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in values:
        name, sep, raw = item.partition("=")
        if not sep:
            raise click.BadParameter(f"{item!r}: expected NAME=VALUE", param_hint="--set")
        try:
            out[name.strip()] = float(raw) if any(c in raw for c in ".eE") else int(raw)
        except ValueError:
            raise click.BadParameter(f"{item!r}: {raw!r} is not a number",
                                     param_hint="--set") from None
    return out


@click.group()
def cli() -> None:
    """Cycle-level emulator of the FPGA motor-controller board."""


@cli.command()
@click.option("--pty", "use_pty", is_flag=True, help="Serve each board on a pseudo-terminal.")
@click.option("--tcp", "tcp", metavar="HOST:PORT",
              help="Serve on TCP; port 0 picks a free one, further boards take the next ports.")
@click.option("--boards", default=1, show_default=True, type=click.IntRange(1, 8),
              help="How many boards (2 = the robot's L and R).")
@click.option("--baud", default=1_000_000, show_default=True, type=click.IntRange(1200, 12_000_000))
@click.option("--seed", default=0, show_default=True, type=int, help="Seed for noise and faults.")
@click.option("--gear", default="high", show_default=True, type=click.Choice(["high", "low"]))
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False,
              path_type=Path), help="TOML file of initial parameter values (NAME = VALUE).")
@click.option("--set", "assignments", multiple=True, metavar="NAME=VALUE",
              help="Initial parameter value, e.g. --set Kp_Wheel_PidA=9 (repeatable).")
@click.option("--fault", "faults", multiple=True, metavar="SPEC",
              help="Fault injection, repeatable. Per line (rx- host->board, tx- "
                   "board->host): rx-ber=RATE, rx-drop=RATE, rx-dup=RATE, rx-noise=RATE:LEN, "
                   "rx-stuck=START_S:DURATION_S (held low), rx-cut=START_S:DURATION_S, and "
                   "the tx- forms; both lines: stuck=, disconnect=START_S:DURATION_S; host: "
                   "stall=START_S:DURATION_S, babble=START_S:DURATION_S (random bytes at "
                   "line rate); drop-frames=ID:N. See docs/reliability.md.")
def serve(use_pty: bool, tcp: str | None, boards: int, baud: int, seed: int, gear: str,
          config_path: Path | None, assignments: tuple[str, ...], faults: tuple[str, ...]) -> None:
    """Serve emulated boards until SIGINT/SIGTERM. Prints `ready <board> <path-or-url>` per
    board once it is reachable."""
    if use_pty == (tcp is not None):
        raise click.UsageError("give exactly one of --pty or --tcp HOST:PORT")
    settings: dict[str, Any] = {}
    if config_path is not None:
        try:
            settings.update(tomllib.loads(config_path.read_text()))
        except tomllib.TOMLDecodeError as exc:
            raise click.BadParameter(f"{config_path}: {exc}", param_hint="--config") from None
    settings.update(parse_assignments(assignments))
    host, port = "127.0.0.1", 0
    if tcp is not None:
        host, _, port_text = tcp.rpartition(":")
        if not host or not port_text.isdigit():
            raise click.BadParameter(f"{tcp!r}: expected HOST:PORT", param_hint="--tcp")
        port = int(port_text)
    try:
        code = asyncio.run(_serve(use_pty, host, port, boards, baud, seed, gear, settings,
                                  list(faults)))
    except ValueError as exc:
        click.echo(f"fpgaemu: {exc}", err=True)
        sys.exit(2)
    sys.exit(code)


async def _serve(use_pty: bool, host: str, port: int, count: int, baud: int, seed: int,
                 gear: str, settings: dict[str, Any], faults: list[str]) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    endpoints: list[PtyEndpoint | TcpEndpoint] = []
    try:
        for index, name in enumerate(board_names(count)):
            board = build_board(baud=baud, seed=seed + index, gear=gear,
                                        settings=settings, faults=faults)
            paced = PacedBoard(board)
            if use_pty:
                pty = PtyEndpoint(paced)
                pty.start()
                endpoints.append(pty)
                where = pty.path
            else:
                tcp = TcpEndpoint(paced, host, port + index if port else 0)
                await tcp.start()
                endpoints.append(tcp)
                where = tcp.url
            print(f"ready {name} {where}", flush=True)
        await stop.wait()
    finally:
        for endpoint in endpoints:
            await endpoint.close()
        for endpoint, name in zip(endpoints, board_names(count), strict=False):
            dropped = getattr(endpoint, "dropped_tx", 0)
            if dropped:
                print(f"dropped {name}: {dropped} TX bytes nobody read in time",
                      file=sys.stderr, flush=True)
            lag = endpoint.paced.lag
            if lag.lag_events:
                print(f"lag {name}: fell behind real time {lag.lag_events} times, worst "
                      f"{lag.worst_lag_s * 1000:.1f} ms (caught up, no bytes lost)",
                      file=sys.stderr, flush=True)
    return 0


def main() -> None:
    cli()


if __name__ == "__main__":
    main()
