"""What ``drive`` and ``goto`` share: the robot options, opening the robot (the emulated one
when no port is given), the live view, the path (odometry, and truth when the robot is
emulated), its plot and its recording."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import math
import sys
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar
from urllib.parse import quote

import click

from fpgalink.boardclock import BoardClock
from fpgalink.cli.figures import check_plot_path, new_figure, save_figure
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.liveview import foxglove_option, opened_live
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import CliError, ExitCode, classify, echo_out, note
from fpgalink.protocol import (
    IdentityMatch,
    compare_identity,
    describe_identity,
    identity_metadata,
)
from fpgalink.recording import COMMAND_SCHEMA, POSE_SCHEMA, RecordingError

if TYPE_CHECKING:
    from fpgalink.aio import Subscription
    from fpgalink.aio.link import Stamped
    from fpgalink.cli.rosbag import RosbagWriter
    from fpgalink.live import LiveAddress
    from fpgalink.protocol.robot import RobotDescription
    from fpgalink.robot.feed import SetFeed
    from fpgalink.robot.robot import Robot
    from fpgalink.robot.supervision import SupervisionEvent

__all__ = ["PathLog", "RobotRun", "description_options", "output_options", "robot_options",
           "rosbag_option"]

T = TypeVar("T")

#: How often the path is sampled and the live view refreshed.
SAMPLE_S = 0.05
#: The bag's /truth at most this often (a path plot's resolution, not the wheels').
BAG_TRUTH_PERIOD_S = 0.01
#: How often the bag gets /diagnostics.
BAG_DIAGNOSTICS_S = 1.0


def robot_options(func: Callable[..., T]) -> Callable[..., T]:
    """``--robot FILE``, ``--surface NAME``, ``--truth URL`` and the connection options."""
    return description_options(connection_options(multi=True, announce=False)(func))


def output_options(func: Callable[..., T]) -> Callable[..., T]:
    """``--plot FILE``, ``--record FILE``, ``--rosbag2 DIR``, ``--force`` and ``--foxglove
    [HOST:]PORT``: what a robot command leaves behind, and its live view."""
    func = foxglove_option(force_option(rosbag_option(func)))
    for option in (  # innermost first: --help lists --plot, --record, --rosbag2
        click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
                     callback=_a_file, help="Save the path (odometry, and truth when "
                     "emulated) to a .png/.svg/.pdf."),
        click.option("--record", type=click.Path(dir_okay=False, path_type=Path),
                     callback=_a_file,
                     help="Record odometry, truth and commands into an MCAP file."),
    )[::-1]:
        func = option(func)
    return func


def _a_file(ctx: click.Context, param: click.Parameter, value: Path | None) -> Path | None:
    """``-`` is not stdout here: these write binary files (a file named ``-`` was made)."""
    if value is not None and str(value) == "-":
        raise click.BadParameter("a file name, not '-': this writes a file, not stdout (for "
                                 "telemetry on stdout use monitor --format csv|jsonl)",
                                 ctx, param)
    return value


def rosbag_option(func: Callable[..., T]) -> Callable[..., T]:
    return click.option(
        "--rosbag2", "rosbag", type=click.Path(file_okay=False, path_type=Path),
        callback=_a_file,
        metavar="DIR", help="Also record joint_states, odom, diagnostics (and truth when "
        "emulated) into a new rosbag2 DIR (MCAP, CDR), as the ROS 2 node publishes them. "
        "Needs the ros2 extra's rosbags.")(func)


def description_options(func: Callable[..., T]) -> Callable[..., T]:
    """``--robot FILE``, ``--surface NAME``, ``--truth URL``."""
    for option in reversed([
        click.option("--robot", "robot_file", type=click.Path(dir_okay=False, path_type=Path),
                     help="Robot description (TOML; the config file's `robot`; default: the "
                          "seed's robot)."),
        click.option("--surface", metavar="NAME",
                     help="The surface it drives on, for the skid-steer χ (the seed's robot: "
                          "ideal, gravel, marble, grass)  [default: the description's]"),
        click.option("--truth", "truth_url", metavar="URL",
                     help="An emulated robot's truth endpoint (socket://HOST:PORT, printed by "
                          "fpgaemu serve --robot); built in for the in-process robot."),
    ]):
        func = option(func)
    return func


def load_description(conn: ConnectionOptions, robot_file: Path | None,
                     surface: str | None) -> RobotDescription:
    from fpgalink.protocol.robot import DescriptionError, load_robot, seed_robot

    path = robot_file or conn.settings.robot
    try:
        description = load_robot(str(path)) if path else seed_robot()
        if surface is not None:
            description = description.on_surface(surface)
    except DescriptionError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    return description


def _physics_installed() -> bool:
    """Whether the emulated robot can have its physics body (the ``physics`` extra); the
    emulator, in this process, imports MuJoCo next when it can."""
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return False
    return True


def robot_ports(conn: ConnectionOptions, description: RobotDescription,
                robot_file: Path | None) -> dict[str, str]:
    """Board name → URL: the configured ports, or the in-process emulated robot."""
    settings = conn.settings
    if settings.emulated:
        query = f"surface={quote(description.surface)}"
        path = robot_file or settings.robot
        if path:
            query += f"&robot={quote(str(path))}"
        body = ""
        if not _physics_installed():  # said here, in the one line
            query += "&body=kinematic"
            body = (", the kinematic body: MuJoCo is not installed, pip install "
                    "'fpgalink[physics]' for the physics body")
        note(f"no --port given: using the built-in emulated robot (emu://robot/…, surface "
             f"{description.surface}{body}); it lives only for this command")
        return {b: f"emu://robot/{b}?{query}" for b in description.boards}
    given = {e.name: e.url for e in settings.endpoints}
    missing = [b for b in description.boards if b not in given]
    if missing:
        ports = " ".join(f"--port {b}=…" for b in description.boards)
        raise CliError(f"the robot's boards are {', '.join(description.boards)}; no port "
                       f"for {', '.join(missing)} (give {ports}, or [ports] in the config "
                       "file)", ExitCode.BAD_INPUT)
    return {b: given[b] for b in description.boards}


def stopped_error(stop: SupervisionEvent | None, fallback: str) -> CliError:
    """A fault stop as the command's last line (exit 7): what stopped the robot, said once.
    A restart's detail is the board's status, which repeats the reason's "restarted"."""
    if stop is None or stop.reason is None:
        return CliError(fallback, ExitCode.STOPPED)
    from fpgalink.robot.supervision import StopReason

    detail = stop.detail
    if stop.reason is StopReason.BOARD_RESTARTED:
        detail = detail.removeprefix("restarted: ")
    which = f" (board {stop.board})" if stop.board else ""
    tail = f": {detail}" if detail else ""
    return CliError(f"the robot was stopped: {stop.reason.value}{which}{tail}",
                    ExitCode.STOPPED)


@dataclass
class PathLog:
    """The path as it was driven: odometry, and truth when known."""

    t: list[float] = field(default_factory=list)
    odometry: list[tuple[float, float, float]] = field(default_factory=list)
    truth: list[tuple[float, float, float] | None] = field(default_factory=list)

    def add(self, t: float, odometry: tuple[float, float, float],
            truth: tuple[float, float, float] | None) -> None:
        self.t.append(t)
        self.odometry.append(odometry)
        self.truth.append(truth)

    def plot(self, path: Path, title: str, goal: tuple[float, float] | None = None, *,
             force: bool) -> None:
        figure = new_figure((7, 7))
        ax = figure.subplots()
        ax.plot([p[0] for p in self.odometry], [p[1] for p in self.odometry],
                label="odometry", linewidth=1.5)
        truth = [p for p in self.truth if p is not None]
        if truth:
            ax.plot([p[0] for p in truth], [p[1] for p in truth], "--", label="truth (emulator)",
                    linewidth=1.2)
        if self.odometry:
            ax.plot(*self.odometry[0][:2], "o", color="tab:green", label="start")
        if goal is not None:
            ax.plot(*goal, "x", color="tab:red", markersize=10, label="goal")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x, m (forward at start)")
        ax.set_ylabel("y, m (left)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        save_figure(figure, path, force=force)


#: The fields a truth line must hold as finite numbers to be used (the path, the live
#: view and the summary read them).
TRUTH_FIELDS = ("x", "y", "theta", "v", "omega")
#: How long the start waits for a served robot's first truth pose (it streams at 100 Hz).
TRUTH_FIRST_S = 2.0
#: The longest truth line read (a served robot's is about 1.5 KiB); a longer one is skipped.
TRUTH_LINE_LIMIT = 1 << 16


def truth_pose(record: object) -> dict[str, Any] | None:
    """``record`` if it is a truth line this command can use — a JSON object whose
    :data:`TRUTH_FIELDS` are finite numbers — else ``None``."""
    if not isinstance(record, dict):
        return None
    pose: dict[str, float] = {}
    for key in TRUTH_FIELDS:
        value = record.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            return None
        try:
            pose[key] = float(value)
        except OverflowError:  # an integer beyond any float
            return None
        if not math.isfinite(pose[key]):
            return None
    return {**record, **pose}


class TruthFrame:
    """Truth in the frame odometry counts in: the pose at this command's start. A served
    robot's body may have moved before (an earlier ``drive``), so its truth, in the frame
    where serve started it, is turned into this one (``world`` keeps it as it came)."""

    def __init__(self) -> None:
        self.origin: tuple[float, float, float] | None = None

    def anchor(self, record: dict[str, Any]) -> None:
        """The start pose: odometry's zero."""
        self.origin = (record["x"], record["y"], record["theta"])

    def relative(self, record: dict[str, Any]) -> dict[str, Any]:
        from fpgalink.protocol.robot import wrap_angle

        if self.origin is None:  # no pose before the start: the first one is the start
            self.anchor(record)
        assert self.origin is not None
        x0, y0, theta0 = self.origin
        dx, dy = record["x"] - x0, record["y"] - y0
        cos, sin = math.cos(theta0), math.sin(theta0)
        return {**record, "x": cos * dx + sin * dy, "y": cos * dy - sin * dx,
                "theta": wrap_angle(record["theta"] - theta0),
                "world": {"x": record["x"], "y": record["y"], "theta": record["theta"]}}


class _TruthReader:
    """The latest line of a served robot's truth endpoint (JSON lines over TCP). A line
    that is not a pose (not JSON, nesting too deep, a field missing or not a finite number,
    too long) is skipped and counted; an ``{"error": …}`` line (serve turning a reader
    away) is kept to be said."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.latest: dict[str, Any] | None = None
        self.skipped = 0  #: lines that were not a usable pose
        self.refusal: str | None = None  #: what the endpoint said when it turned us away
        self.first = asyncio.Event()  #: set with the first pose (or when the stream ends)
        self._task: asyncio.Task[None] | None = None

    async def start(self) -> None:
        host, _, port = self.url.removeprefix("socket://").rpartition(":")
        host = host.strip("[]")
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_connection(
                host, int(port), limit=TRUTH_LINE_LIMIT), 5)
        except (OSError, ValueError, TimeoutError) as exc:
            raise CliError(f"--truth {self.url}: cannot connect: {exc}", ExitCode.PORT) from None
        self._task = asyncio.ensure_future(self._read(reader, writer))

    async def _read(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        skipping = False  # inside a line too long to be a pose: dropped up to its end
        try:
            while True:
                try:
                    line = await reader.readuntil(b"\n")
                except asyncio.IncompleteReadError as exc:
                    if exc.partial and not skipping:
                        self._take(exc.partial)
                    return
                except asyncio.LimitOverrunError as exc:
                    if not skipping:
                        self.skipped += 1
                        skipping = True
                    await reader.readexactly(exc.consumed)
                    continue
                if skipping:
                    skipping = False
                    continue
                self._take(line)
        except (OSError, asyncio.IncompleteReadError):
            return  # the endpoint went away: the run goes on without truth
        finally:
            self.first.set()
            writer.close()

    def _take(self, line: bytes) -> None:
        try:
            record = json.loads(line)
        except (ValueError, RecursionError):
            self.skipped += 1
            return
        if isinstance(record, dict) and isinstance(record.get("error"), str) and \
                len(record) == 1:
            self.refusal = record["error"][:200]
            return
        pose = truth_pose(record)
        if pose is None:
            self.skipped += 1
        else:
            self.latest = pose
            self.first.set()

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)


class RobotRun:
    """One command's robot: opened, shown live, its path kept; ``async with``."""

    def __init__(self, conn: ConnectionOptions, robot_file: Path | None, surface: str | None,
                 truth_url: str | None, plot: Path | None, record: Path | None,
                 rosbag: Path | None = None, foxglove: LiveAddress | None = None,
                 name: str = "fpgalink-cli", *, force: bool = False) -> None:
        # Every file it will write, checked before the robot moves (--force: replaced).
        if plot is not None:
            check_plot_path(plot, force=force)
        if record is not None:
            check_output(record, force=force)
        if rosbag is not None:
            check_output(rosbag, force=force, directory=True)
        self.force = force
        self.conn = conn
        self.description = load_description(conn, robot_file, surface)
        self.ports = robot_ports(conn, self.description, robot_file)
        self.plot_path = plot
        self.record_path = record
        self.rosbag_path = rosbag
        self.bag: RosbagWriter | None = None
        #: the recordings closed complete, as asked (only these are said to be recorded)
        self.recorded: list[Path] = []
        self.path = PathLog()
        self.stop = asyncio.Event()
        self._truth_reader = _TruthReader(truth_url) if truth_url else None
        self._sink: Any = None  #: the --record file while it is being written
        self._sink_opened: Any = None  #: … and once opened, to close it at the end
        self._started = 0.0
        self._bag_truth_at = -(1 << 62)  #: host time /truth was last written to the bag, ns
        self._bag_log_ns = 0  #: the latest log time written to the bag
        self.robot: Robot | None = None
        self.last_truth: dict[str, Any] | None = None
        self.truth_frame = TruthFrame()
        self.foxglove = foxglove
        self.name = name

    @contextlib.asynccontextmanager
    async def opened(self) -> AsyncIterator[Robot]:
        # The live view's modules, imported before any board is enabled: imported in the
        # middle of a run they stalled this host for about 0.3 s (rich's console), and the
        # boards' watchdog saw a host silent 297 ms at drive's start.
        import rich.console
        import rich.live  # noqa: F401

        from fpgalink.cli.session import install_stop_signals
        from fpgalink.cli.wirelog import log_wire
        from fpgalink.robot.robot import Robot, RobotError

        install_stop_signals(self.stop)
        robot = Robot.open(self.description, self.ports, baud=self.conn.baud,
                           wire_crc=self.conn.wire_crc, allow_mismatch=self.conn.allow_mismatch)
        for name in self.description.boards:
            log_wire(name, functools.partial(robot.boards.add_listener, name),
                     self.conn.verbose)
        try:
            await robot.start()
        except RobotError as exc:
            raise CliError(str(exc), ExitCode.NO_ANSWER if "not answering" in str(exc)
                           else ExitCode.FAILURE) from None
        self.robot = robot
        for name in self.description.boards:
            identity, known = robot.boards.identity(name)
            if known and compare_identity(identity) is IdentityMatch.MISMATCH:
                note(f"board {name}: {describe_identity(identity)}; going on "
                     "(--allow-mismatch)")
        try:
            if self._truth_reader is not None:
                await self._truth_reader.start()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._truth_reader.first.wait(), TRUTH_FIRST_S)
            start = self._world_truth()
            if start is not None:
                self.truth_frame.anchor(start)
            if self.record_path is not None:
                self._open_sink()
            feeds, writers, periodic = self._start_recorders(robot)
            try:
                async with opened_live(self.foxglove, self.name) as view:
                    if view is not None:
                        view.add_robot(robot, self.truth)
                    yield robot
            finally:
                await _drained(feeds, writers, periodic)
                self._sample_once()
        finally:
            await robot.close()
            if self._truth_reader is not None:
                await self._truth_reader.close()
                self._report_truth(self._truth_reader)
            self._close_recordings()

    def _start_recorders(self, robot: Robot) -> tuple[
            list[Subscription[Any]], list[asyncio.Task[None]], list[asyncio.Task[None]]]:
        """The recordings' writers, each reading a subscription of its own (closed at the
        end: see :func:`_drained`), and the periodic tasks (cancelled at the end)."""
        feeds: list[Subscription[Any]] = []
        writers: list[asyncio.Task[None]] = []
        periodic: list[asyncio.Task[None]] = []
        if self._sink is not None:
            to_epoch = time.time() - asyncio.get_running_loop().time()
            for name in self.description.boards:
                feed = robot.boards.stamped_telemetry(name, maxsize=65536)
                feeds.append(feed)
                writers.append(asyncio.ensure_future(self._record_board(feed, name, to_epoch)))
        if self.rosbag_path is not None:
            self._open_bag(robot)
            sets = self._bag_sets(robot)  # beside --record's, not instead of them
            feeds.append(sets)
            writers.append(asyncio.ensure_future(self._bag_telemetry(robot, sets)))
            periodic.append(asyncio.ensure_future(self._bag_diagnostics(robot)))
        self._started = time.monotonic()
        periodic.append(asyncio.ensure_future(self._sample()))
        return feeds, writers, periodic

    def _close_recordings(self) -> None:
        """Close the recordings: each put in place, complete up to where it got. A
        recording that stopped early, or cannot be finished, is one line (exit 1); when the
        run itself ends in an error, that error is the one raised, and the recordings' are
        said as notes."""
        failures: list[RecordingError] = []
        for recording in (self._sink_opened, self.bag):
            if recording is None:
                continue
            try:
                recording.close()
            except RecordingError as exc:
                failures.append(exc)
            else:
                self.recorded.append(recording.path)
        if not failures:
            return
        if sys.exc_info()[0] is not None:
            for failure in failures:
                note(str(failure))
            return
        for failure in failures[1:]:
            note(str(failure))
        raise classify(failures[0])

    @staticmethod
    def _report_truth(reader: _TruthReader) -> None:
        if reader.refusal is not None:
            note(f"--truth {reader.url}: the endpoint said: {reader.refusal}")
        if reader.skipped:
            note(f"--truth {reader.url}: skipped {reader.skipped} line(s) that were not a "
                 f"pose (JSON objects with finite numbers {', '.join(TRUTH_FIELDS)})")
        if reader.latest is None:
            note(f"--truth {reader.url}: no pose received; the path has no truth")

    def _world_truth(self) -> dict[str, Any] | None:
        if self._truth_reader is not None:
            return self._truth_reader.latest
        return self.robot.truth() if self.robot is not None else None

    def truth(self) -> dict[str, Any] | None:
        """The emulated body's pose in odometry's frame (the command's start), or None."""
        record = self._world_truth()
        return None if record is None else self.truth_frame.relative(record)

    def _open_sink(self) -> None:
        from fpgalink.cli.sinks import McapSink

        assert self.record_path is not None
        topics = {"/robot/odometry": POSE_SCHEMA, "/robot/truth": POSE_SCHEMA,
                  "/robot/command": COMMAND_SCHEMA}
        self._sink = self._sink_opened = McapSink(
            self.record_path, list(self.description.boards),
            {"robot": self.description.name, "surface": self.description.surface,
             **self.identity_metadata()}, topics, force=self.force)

    def identity_metadata(self) -> dict[str, str]:
        """Who the robot's boards said they are, and this host's declaration, for a
        recording's metadata (docs/protocol.md §8)."""
        assert self.robot is not None
        return identity_metadata({name: self.robot.boards.identity(name)
                                  for name in self.description.boards})

    def _recording_failed(self, *, sink: bool = False) -> None:
        """A recording stopped (its write raised; ``sink``: the ``--record`` one, written no
        more): the run stops; the recording says what is on disk when it is closed."""
        if sink:
            self._sink = None
        self.stop.set()

    async def _record_board(self, feed: Subscription[Stamped], name: str, to_epoch: float
                            ) -> None:
        """Every sample of one board into ``/board/NAME/telemetry``, as ``record`` writes it
        (so ``plot`` of a drive shows the wheels' speeds against their references), until
        ``feed`` is closed and drained."""
        from fpgalink.cli.session import compact, json_safe, telemetry_row

        clock = BoardClock()
        async for received, sample in feed:
            sink = self._sink
            if sink is None:
                return
            received += to_epoch
            sampled = clock.seconds(sample.t_us, received)
            row = json_safe({k: compact(v) for k, v in telemetry_row(sample, 0.0).items()})
            row["timestamp"] = round(sampled, 6)
            try:
                sink.telemetry(name, row, received, sampled)
            except RecordingError:
                self._recording_failed(sink=True)
                return

    # --- rosbag2 --------------------------------------------------------------------------

    def _open_bag(self, robot: Robot) -> None:
        from fpgalink.cli.rosbag import RosbagWriter

        assert self.rosbag_path is not None
        self.bag = RosbagWriter(
            self.rosbag_path, self.description, truth=self.truth() is not None,
            metadata={"robot": self.description.name, "surface": self.description.surface,
                      "ports": " ".join(f"{b}={u}" for b, u in self.ports.items()),
                      "clocks": "bag time: host receive time; header stamps: the boards' "
                                "sample times on the host clock",
                      **self.identity_metadata()},
            force=self.force)

    def _bag_sets(self, robot: Robot) -> SetFeed:
        # One truth clock for the whole bag: /truth at most every BAG_TRUTH_PERIOD_S.
        self._bag_truth_at = -(1 << 62)
        # One mapping of the loop's clock onto epoch time for every board: bag times of
        # different boards are then on one clock.
        to_epoch_ns = time.time_ns() - round(asyncio.get_running_loop().time() * 1e9)
        return robot.sample_sets(clock=lambda received: round(received * 1e9) + to_epoch_ns,
                                 maxsize=65536)

    async def _bag_telemetry(self, robot: Robot, sets: SetFeed) -> None:
        """Every set of samples (the robot's stamping: each sample on the host clock by its
        board's time, the odometry with its own stamp) into the bag."""
        bag = self.bag
        assert bag is not None
        with contextlib.closing(sets):
            async for stamped in sets:
                # When the host received it, never before what the bag already holds: a
                # bag read in log-time order must give the messages in the order written.
                now_ns = max(stamped.received, self._bag_log_ns)
                self._bag_log_ns = now_ns
                states = robot.joint_states(stamped.samples)
                try:
                    if states is not None:
                        bag.joint_states(states, stamped.stamp, now_ns)
                    bag.odometry(stamped.odometry, stamped.odometry_stamp, now_ns)
                    if now_ns - self._bag_truth_at >= round(BAG_TRUTH_PERIOD_S * 1e9):
                        truth = self.truth()
                        if truth is not None:
                            bag.truth(truth, now_ns, now_ns)
                            self._bag_truth_at = now_ns
                except RecordingError:
                    self._recording_failed()
                    return

    async def _bag_diagnostics(self, robot: Robot) -> None:
        bag = self.bag
        assert bag is not None
        while True:
            await asyncio.sleep(BAG_DIAGNOSTICS_S)
            now_ns = time.time_ns()
            try:
                bag.diagnostics(robot.health(), now_ns, now_ns)
            except RecordingError:
                self._recording_failed()
                return

    async def _sample(self) -> None:
        while True:
            self._sample_once()
            await asyncio.sleep(SAMPLE_S)

    def _sample_once(self) -> None:
        robot = self.robot
        if robot is None:
            return
        now = time.time()
        t = time.monotonic() - self._started
        state = robot.odometry_state
        pose = state.pose
        truth = self.truth()
        if truth is not None:
            self.last_truth = truth
        truth_pose = None if truth is None else (truth["x"], truth["y"], truth["theta"])
        self.path.add(t, (pose.x, pose.y, pose.theta), truth_pose)
        if self._sink is not None:
            try:
                self._sink.add("/robot/odometry", {"t": t, "x": pose.x, "y": pose.y,
                                                   "theta": pose.theta, "v": state.v,
                                                   "omega": state.omega}, now)
                if truth is not None:
                    self._sink.add("/robot/truth", truth, now)
                command = robot.command
                if command is not None:
                    self._sink.add("/robot/command", {
                        "v": command.v, "omega": command.omega, "left": command.left_dps,
                        "right": command.right_dps, "scale": command.scale}, now)
            except RecordingError:
                self._recording_failed(sink=True)

    def view(self, status: str) -> Any:
        """The live table (rich renderable)."""
        from rich.table import Table

        robot = self.robot
        assert robot is not None
        state = robot.odometry_state
        table = Table(title=status, title_justify="left")
        for column in ("", "x m", "y m", "θ deg", "v m/s", "ω deg/s"):
            table.add_column(column, justify="right" if column else "left", overflow="fold")
        p = state.pose
        table.add_row("odometry", f"{p.x:.3f}", f"{p.y:.3f}", f"{math.degrees(p.theta):.1f}",
                      f"{state.v:.3f}", f"{math.degrees(state.omega):.1f}")
        truth = self.truth()
        if truth is not None:
            table.add_row("truth", f"{truth['x']:.3f}", f"{truth['y']:.3f}",
                          f"{math.degrees(truth['theta']):.1f}", f"{truth['v']:.3f}",
                          f"{math.degrees(truth['omega']):.1f}")
        command = robot.command
        if command is not None:
            table.add_row("command", "", "", "", f"{command.v:.3f}",
                          f"{math.degrees(command.omega):.1f}")
        wheels = Table(title="wheels", title_justify="left")
        for column in ("wheel", "board", "ref deg/s", "speed deg/s", "pwm", "link"):
            wheels.add_column(column, justify="left" if column in ("wheel", "board", "link")
                              else "right", overflow="fold")
        for wheel in self.description.wheels:
            latest = robot.latest.get(wheel.board)
            channel = None if latest is None else (latest.a if wheel.channel == 1 else latest.b)
            wheels.add_row(
                wheel.name, f"{wheel.board}/{'AB'[wheel.channel - 1]}",
                "-" if channel is None else f"{channel.reference:.1f}",
                "-" if channel is None else f"{channel.speed:.1f}",
                "-" if channel is None else str(channel.pwm),
                "alive" if robot.boards.alive(wheel.board) else "SILENT")
        from rich.console import Group

        return Group(table, wheels)

    def summary(self) -> list[str]:
        robot = self.robot
        assert robot is not None
        state = robot.odometry_state
        p = state.pose
        lines = [f"odometry: x {p.x:.3f} m, y {p.y:.3f} m, θ {math.degrees(p.theta):.1f}°, "
                 f"{state.distance:.2f} m travelled"]
        truth = self.last_truth
        if truth is not None:
            error = math.hypot(truth["x"] - p.x, truth["y"] - p.y)
            lines.append(f"truth:    x {truth['x']:.3f} m, y {truth['y']:.3f} m, θ "
                         f"{math.degrees(truth['theta']):.1f}° (odometry off by "
                         f"{error * 100:.1f} cm)")
        return lines

    def summary_document(self) -> dict[str, Any]:
        """The summary as JSON has it: metres and degrees, in the keys."""
        robot = self.robot
        assert robot is not None
        state = robot.odometry_state
        p = state.pose
        document: dict[str, Any] = {
            "odometry": {"x_m": p.x, "y_m": p.y, "theta_deg": math.degrees(p.theta),
                         "distance_m": state.distance},
            "truth": None,
        }
        truth = self.last_truth
        if truth is not None:
            document["truth"] = {"x_m": truth["x"], "y_m": truth["y"],
                                 "theta_deg": math.degrees(truth["theta"]),
                                 "odometry_error_m": math.hypot(truth["x"] - p.x,
                                                                truth["y"] - p.y)}
        return document

    def print_summary(self, fmt: str, extra: dict[str, Any] | None = None) -> None:
        """The final odometry (and truth) in ``fmt``; ``extra`` goes into the JSON document
        (the command, the goal)."""
        from fpgalink.cli.formats import Column, emit_document, emit_rows

        if fmt == "table":
            for line in self.summary():
                echo_out(line)
            return
        document = {**(extra or {}), **self.summary_document()}
        if fmt == "json":
            emit_document(document)
            return
        rows = [{"source": "odometry", **document["odometry"]}]
        if document["truth"] is not None:
            rows.append({"source": "truth", **document["truth"]})
        emit_rows(fmt, [Column(k, k) for k in ("source", "x_m", "y_m", "theta_deg",
                                              "distance_m", "odometry_error_m")], rows)

    def finish(self, title: str, goal: tuple[float, float] | None = None) -> None:
        if self.plot_path is not None:
            self.path.plot(self.plot_path, title, goal, force=self.force)
            note(f"path plot saved to {self.plot_path}")
        if self.record_path is not None and self.record_path in self.recorded:
            note(f"recorded the path to {self.record_path}")
        if self.bag is not None and self.bag.path in self.recorded:
            note(f"recorded {self.bag.messages} ROS messages to the bag {self.rosbag_path}")


async def _drained(feeds: list[Subscription[Any]], writers: list[asyncio.Task[None]],
                   periodic: list[asyncio.Task[None]]) -> None:
    """The recordings' writers end once they wrote what their closed subscriptions still
    hold (cancelled, a writer one turn behind lost the samples it had not yet read); the
    periodic tasks are cancelled. A writer is cancelled only if this wait itself is."""
    for feed in feeds:
        feed.close()  # nothing more is put; the writer drains it and ends
    for task in periodic:
        task.cancel()
    try:
        await asyncio.gather(*writers, *periodic, return_exceptions=True)
    finally:
        for task in writers:
            task.cancel()


@contextlib.contextmanager
def live(run: RobotRun, status: Callable[[], str]) -> Any:
    """A live view on stderr while the block runs (only on a terminal)."""
    from rich.live import Live

    from fpgalink.cli.output import console as plain_console

    console = plain_console(stderr=True)
    if not console.is_terminal:
        yield lambda: None
        return
    with Live(console=console, refresh_per_second=10, transient=False) as display:
        yield functools.partial(lambda: display.update(run.view(status())))
