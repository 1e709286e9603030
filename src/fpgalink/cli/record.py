"""``record``: telemetry, parameter changes, link events and link statistics into MCAP
(JSON Schema + JSON, so Foxglove and PlotJuggler plot it as is) or telemetry into CSV."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import time
from pathlib import Path
from typing import Any

import click

from fpgalink.aio.link import Stamped, Subscription
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, FiniteRange, note
from fpgalink.cli.robotsession import description_options
from fpgalink.cli.session import (
    BoardSession,
    check_boards_answered,
    compact,
    install_stop_signals,
    json_safe,
    on_messages,
    open_sessions,
    restore_streaming,
    run,
    start_streaming,
    stop_exit_code,
    telemetry_row,
    wait_or_stop,
)
from fpgalink.cli.settings import DEFAULT, EMULATOR_URL
from fpgalink.cli.sinks import STATS_FIELDS, CsvSink, McapSink, Sink
from fpgalink.protocol import Parsed, identity_metadata
from fpgalink.recording import RecordingError, parameter_record

__all__ = ["record"]

STATS_PERIOD_S = 1.0


@click.command(epilog=EXIT_CODES_HELP)
@click.argument("file", required=False,
                type=click.Path(dir_okay=False, writable=True, path_type=Path))
@click.option("--duration", type=FiniteRange(min=0, min_open=True, max=1e7),
              help="Stop after S seconds (default: until Ctrl-C).")
@click.option("--csv", "as_csv", is_flag=True,
              help="Write telemetry as CSV instead of MCAP.")
@click.option("--passive", is_flag=True,
              help="Only listen: no parameter snapshot, GetDataPeriodical left alone.")
@click.option("--rosbag2", "rosbag", metavar="DIR",
              type=click.Path(file_okay=False, path_type=Path),
              help="Instead of FILE: the robot (both boards) into a new rosbag2 DIR — "
                   "joint_states, odom, diagnostics, and truth when emulated (MCAP, CDR; "
                   "needs the ros2 extra's rosbags).")
@force_option
@description_options
@connection_options(multi=True, announce=False)
def record(file: Path | None, duration: float | None, as_csv: bool, passive: bool,
           rosbag: Path | None, force: bool, robot_file: Path | None, surface: str | None,
           truth_url: str | None, conn: ConnectionOptions) -> int:
    """Record telemetry, parameter changes and link events into FILE (or a rosbag2).

    FILE is MCAP (JSON Schema + JSON), or CSV of the telemetry alone with --csv. Topics per
    board NAME: /board/NAME/telemetry (flat numeric fields: timestamp, t_us, a_speed, b_pwm
    …), /board/NAME/params (every PA/PN the board sent: the initial snapshot and each
    change), /board/NAME/events (link events, as foxglove.Log), /board/NAME/stats (1 Hz).
    Each message's log_time is when the host received it, its publish_time the board's
    sample time on the host clock. Ctrl-C stops cleanly: the file is closed and valid
    (exit 130). A full disk stops the recording with the file complete so far (exit 1).
    FILE is written as FILE.partial and renamed when complete; an existing FILE is refused
    unless --force.

    --rosbag2 DIR records the robot as the ROS 2 node publishes it (topics /joint_states,
    /odom, /diagnostics, /truth; docs/ros2.md): the robot description's boards (--robot,
    --surface; with no --port, the emulated robot), not enabled or driven (drive and goto
    take --rosbag2 too).
    """
    if rosbag is not None:
        if file is not None or as_csv or passive:
            raise CliError("--rosbag2 DIR records the robot on its own: no FILE, --csv or "
                           "--passive with it", ExitCode.BAD_INPUT)
        return _record_rosbag(conn, rosbag, duration, robot_file, surface, truth_url, force)
    if file is None:
        raise CliError("give FILE (MCAP, or CSV with --csv), or --rosbag2 DIR",
                       ExitCode.BAD_INPUT)
    if robot_file is not None or surface is not None or truth_url is not None:
        raise CliError("--robot, --surface and --truth go with --rosbag2 DIR",
                       ExitCode.BAD_INPUT)
    if str(file) == "-":
        # Not a file named "-" in the working directory, as it was: param dump - means stdout,
        # and a user trying the same here wants a stream, which monitor gives.
        raise CliError("record writes a file (MCAP, or CSV with --csv), not stdout: give a "
                       "file name; for telemetry on stdout use monitor --format csv|jsonl",
                       ExitCode.BAD_INPUT)
    check_output(file, force=force)
    if conn.settings.sources["port"] == DEFAULT:
        # Not just "the emulator": an idle board records zeros, which looked like a fault.
        note(f"no --port given (nor FPGALINK_PORT or a config file): recording the built-in "
             f"emulated board {EMULATOR_URL}, at rest: nothing drives it in this command, so "
             "its wheels read zero (to record a run, drive --record FILE, or serve a board "
             "with fpgaemu serve and record it with --port)")
    return run(_record(conn, file, duration, as_csv, passive, force))


async def _record(conn: ConnectionOptions, path: Path, duration: float | None, as_csv: bool,
                  passive: bool, force: bool) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    failure: list[BaseException] = []
    started = time.time()
    loop = asyncio.get_running_loop()
    to_epoch = time.time() - loop.time()  # loop clock → host epoch
    counts: dict[str, int] = {}
    async with contextlib.AsyncExitStack() as stack:
        sessions = await open_sessions(stack, conn, passive=passive)
        boards = [s.endpoint.name for s in sessions]
        counts.update(dict.fromkeys(boards, 0))
        metadata = {"ports": " ".join(f"{s.endpoint.name}={s.endpoint.url}" for s in sessions),
                    "baud": str(conn.baud), "started": f"{started:.6f}",
                    "clocks": "log_time: host receive time; publish_time: the board's t_us "
                              "mapped onto the host clock (anchored at the first sample)",
                    **identity_metadata({s.endpoint.name: (s.link.identification.identity,
                                                           s.link.identification.known)
                                         for s in sessions})}
        sink: Sink = (CsvSink(path, force=force) if as_csv else
                      McapSink(path, boards, metadata, force=force))

        def guarded(write: Any) -> Any:
            """Run a sink write; a write error stops the recording (the sink says, when it
            is closed, what is on disk)."""
            def call(*args: Any) -> None:
                if failure:
                    return
                try:
                    write(*args)
                except RecordingError as exc:
                    failure.append(exc)
                    stop.set()
            return call

        on_parameter = guarded(sink.parameter)
        on_event = guarded(sink.event)
        on_telemetry = guarded(sink.telemetry)
        on_stats = guarded(sink.stats)
        tasks: list[asyncio.Task[None]] = []
        for session in sessions:
            _tap_parameters(session, on_parameter)
            tasks.append(asyncio.ensure_future(session.follow(
                functools.partial(on_event, session.endpoint.name))))
        subs = [s.link.stamped_telemetry(maxsize=65536) for s in sessions]
        ended = False
        try:
            on_event(boards[0], "recording_started", metadata["ports"], time.time())
            if not passive:
                for session in sessions:
                    await session.link.read_params()  # the PA replies are the snapshot
            await start_streaming(sessions, passive)
            for session, sub in zip(sessions, subs, strict=True):
                tasks.append(asyncio.ensure_future(
                    _record_telemetry(session, sub, on_telemetry, counts, to_epoch)))
                tasks.append(asyncio.ensure_future(_record_stats(session, on_stats)))
            await _progress(stop, duration, counts, path)
            ended = True
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            with contextlib.suppress(Exception):
                await restore_streaming(sessions, passive)
            if not failure:
                on_event(boards[0], "recording_stopped", "", time.time())
            if not ended:
                # Whatever ends the command (a board that never answered, …), what was
                # recorded is finished and put in place; that error is the one said.
                with contextlib.suppress(RecordingError):
                    sink.close()
    total = sum(counts.values())
    elapsed = time.time() - started
    sink.close()  # a recording stopped early: its one line, exit 1
    note(f"recorded {total} telemetry samples from {len(counts)} board(s) in "
         f"{elapsed:.1f} s to {path}")
    check_boards_answered(sessions, started)
    return stop_exit_code(stop)


def _record_rosbag(conn: ConnectionOptions, path: Path, duration: float | None,
                   robot_file: Path | None, surface: str | None,
                   truth_url: str | None, force: bool) -> int:
    from fpgalink.cli.robotsession import RobotRun

    session = RobotRun(conn, robot_file, surface, truth_url, None, None, path, force=force)

    async def recording() -> int:
        async with session.opened():
            await wait_or_stop(session.stop, duration)
        return stop_exit_code(session.stop)

    started = time.monotonic()
    code = run(recording())
    if session.bag is not None and session.bag.path in session.recorded:
        note(f"recorded {session.bag.messages} ROS messages in "
             f"{time.monotonic() - started:.1f} s to the bag {path}")
    return code


def _tap_parameters(session: BoardSession, write: Any) -> None:
    name = session.endpoint.name

    def on_message(message: Parsed) -> None:
        rec = parameter_record(message, time.time())
        if rec is not None:
            write(name, rec)

    on_messages(session.link, on_message)


async def _record_telemetry(session: BoardSession, sub: Subscription[Stamped], write: Any,
                            counts: dict[str, int], to_epoch: float) -> None:
    name = session.endpoint.name
    async for received, sample in sub:
        received += to_epoch
        sampled = session.clock.seconds(sample.t_us, received)
        row = json_safe({k: compact(v) for k, v in telemetry_row(sample, 0.0).items()})
        row["timestamp"] = round(sampled, 6)
        write(name, row, received, sampled)
        counts[name] += 1


async def _record_stats(session: BoardSession, write: Any) -> None:
    while True:
        await asyncio.sleep(STATS_PERIOD_S)
        session.update_rate(time.monotonic())
        stats = session.link.stats
        rec: dict[str, Any] = {"timestamp": time.time(), "telemetry_rate": session.rate}
        for name in STATS_FIELDS[1:]:
            rec[name] = getattr(stats, name)
        write(session.endpoint.name, rec)


async def _progress(stop: asyncio.Event, duration: float | None, counts: dict[str, int],
                    path: Path) -> None:
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from fpgalink.cli.output import console as plain_console

    console = plain_console(stderr=True)
    columns: list[Any] = [SpinnerColumn(),
                          TextColumn("recording to {task.fields[path]}", markup=False)]
    if duration is not None:
        columns.append(BarColumn())
    columns += [TimeElapsedColumn(), TextColumn("{task.fields[samples]} samples")]
    started = time.monotonic()
    deadline = None if duration is None else started + duration
    with Progress(*columns, console=console, disable=not console.is_terminal) as progress:
        task = progress.add_task("record", total=duration, path=str(path), samples=0)
        while not stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            progress.update(task, completed=now - started, samples=sum(counts.values()))
            wait = 0.1 if deadline is None else min(0.1, max(0.0, deadline - now))
            await wait_or_stop(stop, wait)
        progress.update(task, completed=time.monotonic() - started,
                        samples=sum(counts.values()))
