"""``calibrate``: the robot's odometry against a reference — the wheel radius from a straight
run, the surface's χ (effective track) from a turn in place — printed before and after and
written into the robot file (docs/hardware.md, "Bring-up checklist"; docs/robot.md)."""

from __future__ import annotations

import asyncio
import datetime
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fpgalink.cli.bringup import Recorder, recording, write_text
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.formats import emit_document, format_option
from fpgalink.cli.options import ConnectionOptions
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    SignedNumbers,
    echo_out,
    note,
)
from fpgalink.cli.robotsession import RobotRun, load_description, robot_options
from fpgalink.cli.session import run, stop_exit_code
from fpgalink.recording import RecordingError

if TYPE_CHECKING:
    from fpgalink.bringup.calibration import Motion, Result, Sample
    from fpgalink.protocol.robot import RobotDescription
    from fpgalink.robot.robot import Robot

__all__ = ["calibrate"]

#: How often the robot is sampled (the served truth comes every 20 ms).
SAMPLE_S = 0.02
STILL_S = 1.0  #: standing still before each motion (the gyro's bias is taken then)
REST_SPEED = 1e-3  #: m/s and rad/s: odometry at rest
REST_FOR_S = 0.3
REST_TIMEOUT_S = 5.0
SAMPLE_TOPIC = "/calibrate/sample"
CHECK = "check:"  #: the phases of a --check's motions begin with this
SAMPLE_SCHEMA = {"title": "fpgalink.CalibrationSample", "type": "object",
                 "description": "the robot during fpgalink-cli calibrate: host time, phase, "
                                "odometry and (emulated) truth poses (m, rad), an IMU's yaw "
                                "rate (its time s, rad/s)"}


@dataclass
class Run:
    """One calibration: what it ran with, its samples."""

    surface: str
    chi: float
    wheel_radius: float
    samples: list[Sample]


@click.command(cls=SignedNumbers, epilog=EXIT_CODES_HELP)
@click.option("--turn", "turn_deg", type=FiniteRange(-3600, 3600), default=360.0,
              show_default=True,
              help="Turn in place until odometry says this many degrees (counter-clockwise "
                   "positive); 0: no turn.")
@click.option("--omega", type=FiniteRange(min=1, max=90), default=20.0, show_default=True,
              help="The turn's rate, deg/s.")
@click.option("--distance", type=FiniteRange(-100, 100), default=0.0, show_default=True,
              help="First drive straight until odometry says this many metres (backwards "
                   "negative), for the wheel radius; 0: no run.")
@click.option("--v", "speed", type=FiniteRange(min=0.01, max=1), default=0.15,
              show_default=True, help="The straight run's speed, m/s.")
@click.option("--reference", type=click.Choice(["truth", "imu", "measured"]),
              help="What odometry is held to: an emulated robot's truth, its IMU's yaw rate, "
                   "or your measurement  [default: truth where there is one, else measured]")
@click.option("--measured-angle", type=FiniteRange(-36000, 36000), metavar="DEG",
              help="The angle the robot really turned (with --from: in that recording's "
                   "turn); without it a measured reference is asked for once the motions "
                   "are done.")
@click.option("--measured-distance", type=FiniteRange(-1000, 1000), metavar="M",
              help="The way the robot really went in the straight run.")
@click.option("--from", "from_file", type=click.Path(exists=True, dir_okay=False,
                                                     path_type=Path),
              help="Calibrate from a recording (calibrate --record) instead of driving.")
@click.option("--record", type=click.Path(dir_okay=False, path_type=Path),
              help="Record the run (MCAP) to calibrate from again with --from.")
@click.option("--check", is_flag=True,
              help="Then make the same motions again with the new values and print "
                   "odometry's error against the same reference.")
@click.option("--save", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the new χ (into [surfaces]) and wheel radius into this robot "
                   "file, edited in place (made from the robot in use when it is new).")
@force_option
@format_option
@robot_options
def calibrate(turn_deg: float, omega: float, distance: float, speed: float,
              reference: str | None, measured_angle: float | None,
              measured_distance: float | None, from_file: Path | None, record: Path | None,
              check: bool, save: Path | None, force: bool, fmt: str, robot_file: Path | None,
              surface: str | None, truth_url: str | None, conn: ConnectionOptions) -> int:
    """Calibrate odometry: χ from a turn in place, the wheel radius from a straight run.

    Drives on the ground, so keep a hand on the stop: --distance m straight first (if given),
    then --turn degrees in place, each measured by odometry with the robot file's values and
    by the reference, from rest to rest. Prints each value before and after; --save writes
    them into the robot file. --record is refused if it exists (checked before the robot
    moves) unless --force; a full disk stops the robot (exit 1, the recording complete up
    to there). --from reads a recording with every chunk checked: damage is named, what is
    intact used, and the exit is 9.
    """
    measured = measured_angle is not None or measured_distance is not None
    if measured and reference not in (None, "measured"):
        raise CliError(f"--measured-angle/--measured-distance and --reference {reference}: "
                       "one reference at a time", ExitCode.BAD_INPUT)
    if turn_deg == 0 and distance == 0 and from_file is None:
        raise CliError("nothing to do: give --turn or --distance", ExitCode.BAD_INPUT)
    if from_file is not None:
        if record is not None or check:
            raise CliError("--from calibrates a recording: no --record or --check with it",
                           ExitCode.BAD_INPUT)
        calibration, damaged = _read(from_file)
        reference = "measured" if measured else reference or "truth"
    else:
        damaged = 0
        if record is not None:
            check_output(record, force=force)
        description = load_description(conn, robot_file, surface)
        if reference is None:
            reference = "measured" if measured else (
                "truth" if truth_url is not None or conn.settings.emulated else "measured")
        if reference == "measured" and not measured and not sys.stdin.isatty():
            raise CliError("a measured reference: give --measured-angle (and "
                           "--measured-distance), or run on a terminal to be asked, or "
                           "choose --reference truth|imu; nothing was driven",
                           ExitCode.BAD_INPUT)
        if reference == "imu" and distance and turn_deg == 0:
            raise CliError("an IMU gives a turn, not a distance: --reference imu needs --turn",
                           ExitCode.BAD_INPUT)
        session = RobotRun(conn, robot_file, surface, truth_url, None, None)
        runs, stopped = run(_calibrate(session, description, distance, speed, turn_deg,
                                       omega, reference, measured_angle, measured_distance,
                                       record, check, force))
        if stopped:
            note("interrupted: the robot was stopped and disabled; nothing calibrated")
            return stopped
        calibration, checked = runs
    results, refs = _results(calibration, reference, measured_angle, measured_distance)
    document = _document(calibration, reference, results, refs)
    if from_file is None and check and checked is not None:
        document["check"] = _check_document(checked, reference, refs)
    _print(fmt, document)
    if save is not None and results:
        _save(save, calibration, results, conn, robot_file)
    if damaged:
        raise CliError(f"{from_file}: damaged: {damaged} part(s) skipped (named above); "
                       "calibrated from what is intact", ExitCode.DAMAGED)
    return ExitCode.OK


# --- driving ------------------------------------------------------------------------------


class _Sampler:
    """The robot every :data:`SAMPLE_S`: odometry, truth, the IMU's yaw rate."""

    def __init__(self, robot: Robot, session: RobotRun, recorder: Recorder | None) -> None:
        self.robot = robot
        self.session = session
        self.recorder = recorder
        self.phase = "idle"
        self.samples: list[Sample] = []

    def take(self) -> None:
        from fpgalink.bringup.calibration import Sample

        pose = self.robot.pose
        truth = self.session.truth()
        true_pose = gyro = None
        if truth is not None:
            true_pose = (float(truth["x"]), float(truth["y"]), float(truth["theta"]))
            imu = truth.get("imu")
            if isinstance(imu, dict):
                rate = imu.get("angular_velocity")
                at = imu.get("t")
                if isinstance(rate, list) and len(rate) == 3 and isinstance(at, int | float):
                    gyro = (float(at), float(rate[2]))
        sample = Sample(time.monotonic(), self.phase, (pose.x, pose.y, pose.theta), true_pose,
                        gyro)
        self.samples.append(sample)
        if self.recorder is not None:
            self.recorder.add(SAMPLE_TOPIC, {"t": sample.t, "phase": sample.phase,
                                             "odometry": list(sample.odometry),
                                             "truth": None if true_pose is None
                                             else list(true_pose),
                                             "gyro": None if gyro is None else list(gyro)},
                              time.time())

    async def run(self) -> None:
        while True:
            self.take()
            await asyncio.sleep(SAMPLE_S)


async def _record_board(robot: Robot, name: str, recorder: Recorder) -> None:
    """Every sample of board ``name`` into ``/board/NAME/telemetry``, as ``record`` writes it
    (``plot`` of a calibration shows each wheel)."""
    write = recorder.on_sample(name)
    async for _, sample in robot.boards.stamped_telemetry(name, maxsize=65536):
        write(sample)


async def _motion(robot: Robot, sampler: _Sampler, stop: asyncio.Event, name: str, v: float,
                  omega: float, done: Any) -> bool:
    """Stand still, move until ``done()``, stop and wait for rest; False when stopped."""
    from fpgalink.robot.supervision import State

    loop = asyncio.get_running_loop()
    sampler.phase = f"{name}-still"
    await asyncio.sleep(STILL_S)
    sampler.phase = f"{name}-moving"
    async with robot.enabled():
        while not done():
            if stop.is_set() or robot.state is not State.ENABLED:
                return False
            robot.drive(v, omega)
            await asyncio.sleep(robot.control_period)
        robot.stop()
        sampler.phase = f"{name}-settling"
        quiet_since, deadline = None, loop.time() + REST_TIMEOUT_S
        while loop.time() < deadline and not stop.is_set():
            state = robot.odometry_state
            if abs(state.v) < REST_SPEED and abs(state.omega) < REST_SPEED:
                quiet_since = quiet_since or loop.time()
                if loop.time() - quiet_since >= REST_FOR_S:
                    break
            else:
                quiet_since = None
            await asyncio.sleep(SAMPLE_S)
    sampler.take()
    sampler.phase = "idle"
    return not stop.is_set()


async def _motions(robot: Robot, sampler: _Sampler, stop: asyncio.Event, distance: float,
                   speed: float, turn_deg: float, omega: float, prefix: str = "") -> bool:
    """The straight run, then the turn (a check: the turn first, where the calibration's
    turn was made — on a patchy ground χ is the spot's — then the run); their samples'
    phases named ``prefix`` + the motion."""
    from fpgalink.bringup.calibration import unwrapped_change

    async def straight() -> bool:
        start = robot.odometry_state.distance

        def travelled() -> bool:
            return robot.odometry_state.distance - start >= abs(distance)

        return await _motion(robot, sampler, stop, f"{prefix}straight",
                             math.copysign(speed, distance), 0.0, travelled)

    async def turn() -> bool:
        headings = [robot.pose.theta]

        def turned() -> bool:
            headings.append(robot.pose.theta)
            return abs(unwrapped_change(headings)) >= abs(math.radians(turn_deg))

        rate = math.copysign(math.radians(omega), turn_deg)
        return await _motion(robot, sampler, stop, f"{prefix}turn", 0.0, rate, turned)

    order = [(turn_deg, turn), (distance, straight)]
    for wanted, motion in order if prefix == CHECK else reversed(order):
        if wanted and not await motion():
            return False
    return True


async def _calibrate(session: RobotRun, description: RobotDescription, distance: float,
                     speed: float, turn_deg: float, omega: float, reference: str,
                     measured_angle: float | None, measured_distance: float | None,
                     record: Path | None, check: bool, force: bool
                     ) -> tuple[tuple[Run, Run | None], int]:
    checked: Run | None = None
    async with session.opened() as robot:
        # Opened once the boards said who they are (the file says it); a write that fails
        # stops the robot as a signal would, and the file's one line ends the command.
        recorder = None if record is None else Recorder(
            record, list(description.boards),
            {"command": "calibrate", "robot": description.name,
             "surface": description.surface, **session.identity_metadata()},
            session.stop, force=force, extra_topics={SAMPLE_TOPIC: SAMPLE_SCHEMA})
        with recording(recorder):
            model = robot.kinematics
            sampler = _Sampler(robot, session, recorder)
            boards = [] if recorder is None else [
                _record_board(robot, name, recorder) for name in description.boards]
            sampling = asyncio.gather(sampler.run(), *boards)
            try:
                if recorder is not None:
                    recorder.metadata("calibrate", {
                        "surface": description.surface, "chi": repr(model.chi),
                        "wheel_radius": repr(model.wheel_radius), "reference": reference})
                finished = await _motions(robot, sampler, session.stop, distance, speed,
                                          turn_deg, omega)
                first = Run(description.surface, model.chi, model.wheel_radius,
                            list(sampler.samples))
                if finished and check:
                    # a measured value is asked on the terminal: off the loop, which keeps
                    # the links served meanwhile
                    results, _ = await asyncio.to_thread(_results, first, reference,
                                                         measured_angle, measured_distance)
                    values = {r.name: r.after for r in results}
                    robot.set_kinematics(chi=values.get("chi"),
                                         wheel_radius=values.get("wheel_radius"))
                    sampler.samples.clear()
                    await _motions(robot, sampler, session.stop, distance, speed, turn_deg,
                                   omega, CHECK)
                    checked = Run(description.surface, robot.kinematics.chi,
                                  robot.kinematics.wheel_radius, list(sampler.samples))
            finally:
                sampling.cancel()
                await asyncio.gather(sampling, return_exceptions=True)
    if session.stop.is_set():
        return (first, None), stop_exit_code(session.stop)
    if not finished:
        stop = robot.last_stop
        raise CliError(f"the robot was {stop.describe() if stop else 'stopped'}; nothing "
                       "calibrated", ExitCode.STOPPED)
    return (first, checked), 0


# --- reading a recording -----------------------------------------------------------------


def _read(path: Path) -> tuple[Run, int]:
    """A calibration recording (``calibrate --record``), read with every chunk checked
    (:class:`fpgalink.recording.RecordingReader`, as ``plot`` reads): its run, and how many
    damaged parts were skipped (each named on stderr)."""
    from fpgalink.bringup.calibration import Sample
    from fpgalink.recording import RecordingReader

    def pose(value: object) -> tuple[float, float, float] | None:
        if isinstance(value, list) and len(value) == 3 and all(
                isinstance(v, int | float) and math.isfinite(v) for v in value):
            return (float(value[0]), float(value[1]), float(value[2]))
        return None

    samples: list[Sample] = []
    try:
        with RecordingReader(path) as reader:
            for _, _, message in reader.messages(topics=[SAMPLE_TOPIC]):
                try:
                    data = json.loads(message.data)
                except (ValueError, RecursionError):
                    continue
                odometry = pose(data.get("odometry")) if isinstance(data, dict) else None
                if odometry is None or not isinstance(data.get("phase"), str) or \
                        not isinstance(data.get("t"), int | float):
                    continue
                gyro = data.get("gyro")
                samples.append(Sample(
                    float(data["t"]), data["phase"], odometry, pose(data.get("truth")),
                    (float(gyro[0]), float(gyro[1])) if isinstance(gyro, list)
                    and len(gyro) == 2 and all(isinstance(v, int | float) for v in gyro)
                    else None))
            meta = reader.metadata.get("calibrate", {})
            damage = [d.describe(reader.origin_ns) for d in reader.damage]
            orphans = reader.skipped_messages
    except RecordingError as exc:  # not MCAP at all
        raise CliError(f"--from {exc}", ExitCode.BAD_INPUT) from None
    except OSError as exc:
        raise CliError(f"--from {path}: cannot read: {exc.strerror or exc}",
                       ExitCode.FAILURE) from None
    for part in damage:
        note(f"damaged: {path}: {part}; skipped")
    if orphans:
        note(f"damaged: {path}: skipped {orphans} message(s) of intact chunks whose channel "
             "was defined in a damaged one")
    damaged = len(damage) + (1 if orphans else 0)
    try:
        return Run(meta["surface"], float(meta["chi"]), float(meta["wheel_radius"]),
                   samples), damaged
    except (KeyError, ValueError):
        what = ("its calibrate metadata is in a damaged part" if damaged else
                "no calibrate metadata; make one with calibrate --record")
        raise CliError(f"--from {path}: not a calibration recording ({what})",
                       ExitCode.DAMAGED if damaged else ExitCode.BAD_INPUT) from None


# --- results --------------------------------------------------------------------------------


def _reference_turn(motion: Motion, reference: str, measured: float | None) -> float | None:
    if reference == "truth":
        return motion.truth_turn
    if reference == "imu":
        return motion.gyro_turn
    return None if measured is None else math.radians(measured)


def _results(calibration: Run, reference: str, measured_angle: float | None,
             measured_distance: float | None) -> tuple[list[Result], dict[str, float]]:
    """Each value the run calibrates, and the references used (deg, m)."""
    from fpgalink.bringup.calibration import (
        CalibrationError,
        chi_from_turn,
        motion_of,
        radius_from_run,
    )

    results: list[Result] = []
    used: dict[str, float] = {}
    phases = {s.phase.split("-")[0] for s in calibration.samples}
    radius = calibration.wheel_radius
    try:
        if "straight" in phases:
            straight = motion_of(calibration.samples, "straight")
            distance = (straight.truth_distance if reference == "truth" else measured_distance
                        if reference == "measured" else None)
            if distance is None and reference == "measured":
                distance = _ask("the distance the robot really went, m",
                                straight.odometry_distance)
            if distance is None:
                raise CliError(f"the straight run has no {reference} distance",
                               ExitCode.FAILURE)
            result = radius_from_run(radius, straight.odometry_distance, distance)
            results.append(result)
            used["distance_m"] = distance
            radius = result.after
        if "turn" in phases:
            turn = motion_of(calibration.samples, "turn")
            angle = _reference_turn(turn, reference, measured_angle)
            if angle is None and reference == "measured":
                angle = math.radians(_ask("the angle the robot really turned, deg",
                                          math.degrees(turn.odometry_turn)))
            if angle is None:
                raise CliError(f"the turn has no {reference} angle"
                               + (" (the IMU is read from an emulated robot's truth: give "
                                  "--truth)" if reference == "imu" else ""), ExitCode.FAILURE)
            # odometry's turn is proportional to the radius: with the new radius it is
            odometry = turn.odometry_turn * radius / calibration.wheel_radius
            results.append(chi_from_turn(calibration.chi, odometry, angle))
            used["angle_deg"] = math.degrees(angle)
    except CalibrationError as exc:
        raise CliError(f"cannot calibrate: {exc}", ExitCode.FAILURE) from None
    return results, used


def _ask(what: str, odometry: float) -> float:
    value: float = click.prompt(f"odometry says {odometry:.3f}; {what}?", type=float,
                                err=True)
    if not math.isfinite(value):
        raise CliError(f"{what}: {value} is not a number", ExitCode.BAD_INPUT)
    return value


def _document(calibration: Run, reference: str, results: list[Result],
              refs: dict[str, float]) -> dict[str, Any]:
    out: dict[str, Any] = {"surface": calibration.surface, "reference": reference,
                           "results": []}
    for r in results:
        angle = r.name == "chi"
        out["results"].append({
            "name": r.name, "before": r.before, "after": r.after,
            "odometry_deg" if angle else "odometry_m":
                math.degrees(r.odometry) if angle else r.odometry,
            "reference_deg" if angle else "reference_m":
                math.degrees(r.reference) if angle else r.reference,
            "error_before_percent": 100 * r.error_before})
    return out


def _check_document(checked: Run, reference: str, refs: dict[str, float]) -> dict[str, Any]:
    from fpgalink.bringup.calibration import motion_of

    out: dict[str, Any] = {"chi": checked.chi, "wheel_radius": checked.wheel_radius}
    phases = {s.phase.split("-")[0] for s in checked.samples}
    if f"{CHECK}turn" in phases and reference in ("truth", "imu"):
        turn = motion_of(checked.samples, f"{CHECK}turn")
        angle = _reference_turn(turn, reference, None)
        if angle:
            out["turn"] = {"odometry_deg": math.degrees(turn.odometry_turn),
                           "reference_deg": math.degrees(angle),
                           "error_percent": 100 * (turn.odometry_turn - angle) / angle}
    if f"{CHECK}straight" in phases and reference == "truth":
        straight = motion_of(checked.samples, f"{CHECK}straight")
        if straight.truth_distance:
            out["straight"] = {"odometry_m": straight.odometry_distance,
                               "reference_m": straight.truth_distance,
                               "error_percent": 100 * (straight.odometry_distance
                                                       - straight.truth_distance)
                               / straight.truth_distance}
    return out


_REFERENCES = {"truth": "the emulated robot's truth", "imu": "the IMU's yaw rate",
               "measured": "your measurement"}


def _print(fmt: str, document: dict[str, Any]) -> None:
    if fmt != "table":
        if fmt == "json":
            emit_document(document)
            return
        from fpgalink.cli.formats import Column, emit_rows

        keys = ["name", "before", "after", "error_before_percent"]
        emit_rows(fmt, [Column(k, k) for k in keys], document["results"])
        return
    echo_out(f"Calibration on {document['surface']} against "
             f"{_REFERENCES[document['reference']]}")
    for r in document["results"]:
        if r["name"] == "chi":
            echo_out(f"  turn      odometry {r['odometry_deg']:.1f}°, reference "
                     f"{r['reference_deg']:.1f}° ({r['error_before_percent']:+.1f} %): "
                     f"χ {document['surface']} {r['before']:.4f} → {r['after']:.4f}")
        else:
            echo_out(f"  straight  odometry {r['odometry_m']:.3f} m, reference "
                     f"{r['reference_m']:.3f} m ({r['error_before_percent']:+.1f} %): "
                     f"wheel_radius {r['before']:.4f} → {r['after']:.4f} m")
    check = document.get("check")
    if check:
        for name, unit in (("turn", "deg"), ("straight", "m")):
            part = check.get(name)
            if part:
                echo_out(f"  check     {name} again with the new values: odometry "
                         f"{part[f'odometry_{unit}']:.3f}, reference "
                         f"{part[f'reference_{unit}']:.3f} ({part['error_percent']:+.2f} %)")


def _save(path: Path, calibration: Run, results: list[Result], conn: ConnectionOptions,
          robot_file: Path | None) -> None:
    from fpgalink.bringup.robotfile import EditError, set_values
    from fpgalink.protocol.robot import SEED_ROBOT_TOML, DescriptionError, parse_robot

    if path.is_file():
        text = path.read_text(encoding="utf-8")
    else:
        source = robot_file or conn.settings.robot
        text = Path(source).read_text(encoding="utf-8") if source else SEED_ROBOT_TOML
    values: dict[tuple[str, str], float] = {}
    for r in results:
        key = ("surfaces", calibration.surface) if r.name == "chi" else ("", "wheel_radius")
        values[key] = r.after
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    try:
        edited = set_values(text, values, str(path))
        parse_robot(edited, str(path))
    except (EditError, DescriptionError) as exc:
        raise CliError(f"--save {exc}", ExitCode.FAILURE) from None
    write_text(path, edited, force=True)  # an edit in place (or a new file)
    note(f"saved to {path} ({', '.join(f'{r.name} {r.after:.4f}' for r in results)}; "
         f"fpgalink-cli calibrate, {when})")
