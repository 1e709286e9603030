"""``fpgalink-ros2``: the robot as the ROS 2 node ``fpgalink``.

    fpgalink-ros2 [--robot robot.toml] [--surface gravel] [--port L=URL --port R=URL]
                  [--baud 1000000] [--ros-args -r __ns:=/robot -p joint_state_rate:=200]

The boards' ports, line rate and robot description come from the command line, else the
environment (``FPGALINK_PORT``, ``FPGALINK_BAUD``), else the config file ``fpgalink.toml``
(``[ports]``, ``port``, ``baud``, ``robot``; :mod:`fpgalink.config`), as the CLI reads them.
With no port anywhere it runs against the emulated robot in this process
(``emu://robot/L``, ``R``), as the CLI does. Standard ROS arguments go after
``--ros-args``; this command's own options go before it (or after a ``--`` that ends the
ROS arguments).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn
from urllib.parse import quote

from fpgalink.protocol.exitcodes import ExitCode, exit_codes_help
from fpgalink.ros2 import ROS2_INSTALL_HINT, available

if TYPE_CHECKING:
    from fpgalink.protocol.robot import RobotDescription
    from fpgalink.ros2.bag import NodeBag

PROG = "fpgalink-ros2"


def _fail(message: str, code: int = ExitCode.BAD_INPUT) -> NoReturn:
    print(f"{PROG}: error: {' '.join(message.split())}", file=sys.stderr, flush=True)
    sys.exit(code)


#: The exit codes it can end with, from the one table every console script shares (0: stopped
#: by SIGINT or SIGTERM, the robot stopped and the boards disabled; docs/ros2.md).
EXIT_CODES_TABLE = exit_codes_help((
    ExitCode.OK, ExitCode.FAILURE, ExitCode.BAD_INPUT, ExitCode.NO_ANSWER, ExitCode.PORT,
    ExitCode.NOT_INSTALLED, ExitCode.MISMATCH, ExitCode.INTERRUPTED))


def _parser() -> argparse.ArgumentParser:
    from fpgalink import __version__

    parser = argparse.ArgumentParser(
        prog=PROG, description="The robot as the ROS 2 node 'fpgalink': joint_states, odom, "
        "diagnostics, cmd_vel, wheel_refs, goal_pose, enable, and the boards' parameters.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="ROS arguments go after --ros-args (-r __ns:=/robot, -p joint_state_rate:=200,\n"
        "-p L.Kp_Wheel_Pid.A:=400.0). See docs/ros2.md.\n\n"
        + textwrap.fill(EXIT_CODES_TABLE, 79))
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    parser.add_argument("--install-tf2", action="store_true",
                        help="build tf2_msgs (for /tf and /tf_static: Jazzy has no wheel of "
                             "it) into this environment with cmake and a C compiler, then "
                             "exit; see docs/ros2.md")
    parser.add_argument("--robot", metavar="FILE", help="robot description (TOML); default: "
                        "the config file's robot, else the seed's robot")
    parser.add_argument("--surface", metavar="NAME", help="the surface the robot is on "
                        "(its skid-steer chi)")
    parser.add_argument("--port", action="append", default=[], metavar="NAME=URL",
                        help="a board's port, once per board (default: FPGALINK_PORT, the "
                        "config file's [ports], else the emulated robot)")
    parser.add_argument("--baud", type=int, default=None,
                        help="the boards' line rate (default: FPGALINK_BAUD, the config "
                        "file's baud, else 1000000)")
    parser.add_argument("--wire-crc", action="store_true", default=None,
                        help="the boards' frames carry the wire CRC (docs/protocol.md §7; "
                        "default: FPGALINK_WIRE_CRC, the config file's wire_crc, else off)")
    parser.add_argument("--bag", metavar="DIR", type=Path,
                        help="record the node's inputs and outputs into a new rosbag2 DIR "
                        "(MCAP, CDR; with the rosbags library)")
    parser.add_argument("--foxglove", metavar="[HOST:]PORT",
                        help="also a live view for Foxglove without ROS (foxglove-sdk's "
                        "WebSocket server, loopback unless HOST is given; the foxglove "
                        "extra): the boards' telemetry, parameters, events, the robot's "
                        "pose, path, truth, URDF and supervision; docs/live.md")
    parser.add_argument("--force", action="store_true",
                        help="replace the --bag DIR if it exists")
    parser.add_argument("--allow-mismatch", action="store_true",
                        help="go on with boards whose firmware was built from another "
                        "protocol declaration than this host's (refused otherwise, exit 10; "
                        "shown in /diagnostics either way)")
    parser.add_argument("--lifecycle", action="store_true",
                        help="a managed (lifecycle) node: configure opens the boards, "
                        "activate publishes and takes commands, deactivate disables the boards")
    parser.add_argument("--config", metavar="FILE", help="the config file (default: "
                        "FPGALINK_CONFIG, else ./fpgalink.toml, else "
                        "~/.config/fpgalink/fpgalink.toml)")
    return parser


#: Exit codes: 0 stopped by a signal, 1 stdout failed, 2 usage, 3 ROS 2 not installed, 4
#: boards not reached.
EXIT_STDOUT = ExitCode.FAILURE


@dataclass
class Startup:
    """Where the node's boards are, as resolved from the command line, the environment and
    the config file; ``ports`` empty: the emulated robot in this process."""

    robot: str | None
    ports: dict[str, str]
    baud: int
    wire_crc: bool
    #: where the ports came from (``command line``, ``environment FPGALINK_PORT``,
    #: ``config file PATH``, ``default``), and the same for baud, wire_crc and robot
    sources: dict[str, str] = field(default_factory=dict)


def resolve(options: argparse.Namespace) -> Startup:
    """The CLI's order (:mod:`fpgalink.cli.settings`) for what the node uses of it: the
    command line, then the environment, then the config file, then the default.
    :class:`~fpgalink.config.ConfigError` for a file or value that cannot be used."""
    from fpgalink.config import (
        CONFIG_KEYS,
        ConfigError,
        config_ports,
        load_config,
        parse_ports,
        whole,
    )
    from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

    env = os.environ
    config, path = load_config(options.config)  # --config, FPGALINK_CONFIG, or the search
    where = f"config file {path}"
    unknown = sorted(set(config) - CONFIG_KEYS)
    if unknown:
        raise ConfigError(f"config {path}: unknown key {unknown[0]!r} (known: "
                          f"{', '.join(sorted(CONFIG_KEYS))})")
    sources: dict[str, str] = {}
    if options.port:
        endpoints, sources["port"] = parse_ports(options.port), "command line"
    elif env.get("FPGALINK_PORT", "").strip():
        endpoints = parse_ports(env["FPGALINK_PORT"].split(), "FPGALINK_PORT")
        sources["port"] = "environment FPGALINK_PORT"
    elif path is not None and (endpoints := config_ports(config, path)):
        sources["port"] = where
    else:
        endpoints, sources["port"] = (), "default"
    if options.baud is not None:
        baud, sources["baud"] = options.baud, "command line"
    elif env.get("FPGALINK_BAUD", "").strip():
        try:
            baud = int(env["FPGALINK_BAUD"])
        except ValueError:
            raise ConfigError(f"environment FPGALINK_BAUD: {env['FPGALINK_BAUD']!r} is not a "
                              "whole number") from None
        sources["baud"] = "environment FPGALINK_BAUD"
    elif "baud" in config:
        baud, sources["baud"] = config["baud"], where
    else:
        baud, sources["baud"] = 1_000_000, "default"
    baud = whole(baud, "baud", sources["baud"], MIN_BAUD, MAX_BAUD)
    wire_crc = _wire_crc(options, config, where, sources)
    robot: str | None = options.robot
    sources["robot"] = "command line" if robot else "default"
    if robot is None and config.get("robot") is not None:
        if not isinstance(config["robot"], str) or not config["robot"].strip():
            raise ConfigError(f"{where}: robot must be a non-empty string, got "
                              f"{config['robot']!r}")
        robot_path = Path(config["robot"])
        # Relative to the file, as the CLI takes it.
        robot = str(robot_path if robot_path.is_absolute() or path is None
                    else path.parent / robot_path)
        sources["robot"] = where
    return Startup(robot, {e.name: e.url for e in endpoints}, baud, wire_crc, sources)


def _wire_crc(options: argparse.Namespace, config: dict[str, Any], where: str,
              sources: dict[str, str]) -> bool:
    """``--wire-crc``, else ``FPGALINK_WIRE_CRC`` (0 or 1), else the file's ``wire_crc``."""
    from fpgalink.config import env_switch, switch

    text = os.environ.get("FPGALINK_WIRE_CRC", "").strip()
    if options.wire_crc:
        sources["wire_crc"] = "command line"
        return True
    if text:
        sources["wire_crc"] = "environment FPGALINK_WIRE_CRC"
        return env_switch(text, sources["wire_crc"])
    if "wire_crc" in config:
        sources["wire_crc"] = where
        return switch(config["wire_crc"], "wire_crc", where)
    sources["wire_crc"] = "default"
    return False


EXIT_USAGE = ExitCode.BAD_INPUT
EXIT_NO_ROS2 = ExitCode.NOT_INSTALLED


def _say(text: str) -> None:
    """``text`` on stdout, then exit 0; a stdout that cannot take it is one line and exit 1
    (argparse's own printing would drop the error and exit 0)."""
    import os

    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except OSError as exc:
        # What is still buffered goes to /dev/null: the interpreter's last flush is quiet.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        if isinstance(exc, BrokenPipeError):  # the reader went away (| head): done
            sys.exit(0)
        _fail(f"cannot write to stdout: {exc.strerror or exc}", EXIT_STDOUT)
    sys.exit(0)


class _LoadingInterrupts:
    """Ctrl-C while the node loads, until the node's own handler takes SIGINT over (the first
    thing its event loop does): raised as KeyboardInterrupt where it lands, and noted, for an
    import it cuts short fails as an ``ImportError`` (a C extension's initialisation
    interrupted: rclpy's, measured), which must read as the interrupt, not as ROS 2 missing
    nor as a traceback. Being SIGINT's handler, it also keeps asyncio.run's own from being
    put in place, which would only cancel the node's task: a cancellation the robot's start
    could take for its own, leaving a node that never ends."""

    def __init__(self) -> None:
        self.seen = False

    def __call__(self, signum: int, frame: Any) -> None:
        self.seen = True
        signal.default_int_handler(signum, frame)

    def install(self) -> None:
        # The node stops on SIGINT and SIGTERM: neither may stay blocked in the mask it was
        # started with (inherited across fork and exec from whatever started it, a thread
        # of a process that blocked them for a while among them), or it would never stop.
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, self)


_loading = _LoadingInterrupts()


def main(argv: list[str] | None = None) -> None:
    _loading.install()
    try:
        _main(argv)
    except (KeyboardInterrupt, Exception) as exc:
        # Ctrl-C before the event loop's own handler is in place (rclpy and the robot take a
        # few seconds to load), or what it cut short failed after it (an interrupted
        # import): asyncio.run has closed what it opened. One line, not a traceback, as
        # fpgalink-cli says it.
        if not (isinstance(exc, KeyboardInterrupt) or _loading.seen):
            raise
        print(f"{PROG}: interrupted", file=sys.stderr, flush=True)
        sys.exit(ExitCode.INTERRUPTED)


def _main(argv: list[str] | None) -> None:
    argv = list(sys.argv if argv is None else argv)
    _answer_without_ros(argv)
    if not available():
        if _loading.seen:
            raise KeyboardInterrupt
        _fail(ROS2_INSTALL_HINT, EXIT_NO_ROS2)
    import rclpy

    options = _own_options(argv)
    startup, description = _robot(options)
    ports = _ports(startup, description)
    live = _live_address(options)
    bag = _open_bag(options, ports, description)
    from rclpy.signals import SignalHandlerOptions

    # SIGINT and SIGTERM are the node's own (the event loop's handlers end it cleanly);
    # rclpy's would shut its context down under a node still being made.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    code = 0
    try:
        opening = {"baud": startup.baud, "wire_crc": startup.wire_crc,
                   "allow_mismatch": options.allow_mismatch}
        code = asyncio.run(_run(description, ports, opening, startup.sources["port"], bag,
                                options.lifecycle, live, argv))
    finally:
        if bag is not None:
            code = _close_bag(bag, code)
        with contextlib.suppress(Exception):
            rclpy.shutdown()
    sys.exit(code)


def _answer_without_ros(argv: list[str]) -> None:
    """``--help``, ``--install-tf2`` and ``--version`` (before any ``--ros-args``): answered,
    then exit, whether ROS 2 is there or not."""
    before_ros = argv[1:argv.index("--ros-args")] if "--ros-args" in argv else argv[1:]
    if "-h" in before_ros or "--help" in before_ros:
        _say(f"{_parser().format_help()}\nROS 2: {ROS2_INSTALL_HINT}.\n")
    if "--install-tf2" in before_ros:  # a pip user's /tf, without a checkout
        from fpgalink.ros2.tf2build import main as build_tf2

        if not available():
            _fail(ROS2_INSTALL_HINT, EXIT_NO_ROS2)
        sys.exit(build_tf2([]))
    if "--version" in before_ros:  # answers without ROS 2, as --help does
        from fpgalink import __version__

        _say(f"{PROG} {__version__}\n")


def _own_options(argv: list[str]) -> argparse.Namespace:
    """This command's options: ``argv`` without the ROS arguments."""
    from rclpy.utilities import remove_ros_args

    try:
        own = remove_ros_args(argv)[1:]
    except Exception as exc:  # rclpy's own error for unknown ROS arguments
        _fail(f"{exc} (this command's options go before --ros-args, or after a --)")
    return _parser().parse_args(own)


def _robot(options: argparse.Namespace) -> tuple[Startup, RobotDescription]:
    """Where the boards are, and the robot on its surface; a bad config file or robot file
    is one line, exit 2."""
    from fpgalink.config import ConfigError
    from fpgalink.protocol.robot import DescriptionError, load_robot, seed_robot

    try:
        startup = resolve(options)
    except ConfigError as exc:
        _fail(str(exc))
    try:
        description = load_robot(startup.robot) if startup.robot else seed_robot()
        if options.surface:
            description = description.on_surface(options.surface)
    except DescriptionError as exc:
        _fail(str(exc))
    return startup, description


def _ports(startup: Startup, description: RobotDescription) -> dict[str, str]:
    """Board name → URL: one for each of the robot's boards, or the emulated robot's."""
    ports = startup.ports
    if not ports:
        query = f"surface={quote(description.surface)}" + (
            f"&robot={quote(startup.robot)}" if startup.robot else "")
        return {b: f"emu://robot/{b}?{query}" for b in description.boards}
    if set(ports) != set(description.boards):
        _fail(f"the robot's boards are {', '.join(description.boards)}; give a port for "
              f"each, --port NAME=URL or [ports] NAME = URL (got "
              f"{', '.join(sorted(ports))} from {startup.sources['port']})")
    return ports


def _live_address(options: argparse.Namespace) -> Any:
    """``--foxglove``'s address (``None`` without it), the SDK checked before ROS starts."""
    if options.foxglove is None:
        return None
    if options.lifecycle:
        _fail("--foxglove does not go with --lifecycle yet")
    live, error = _parse_live("--foxglove", options.foxglove)
    if error is not None:
        _fail(*error)
    return live


def _parse_live(what: str, text: str) -> tuple[Any, tuple[str, int] | None]:
    """A live view's ``[HOST:]PORT`` and the SDK there to serve it; else the error's line and
    exit code."""
    from fpgalink.live import parse_address, require_sdk
    from fpgalink.protocol.exitcodes import NotInstalled

    try:
        live = parse_address(text)
        require_sdk()
    except ValueError as exc:
        return None, (f"{what} {exc}", ExitCode.BAD_INPUT)
    except NotInstalled as exc:
        return None, (str(exc), ExitCode.NOT_INSTALLED)
    return live, None


def _open_bag(options: argparse.Namespace, ports: dict[str, str],
              description: RobotDescription) -> NodeBag | None:
    """``--bag DIR``'s recording, opened before the node starts (``None`` without it)."""
    if options.bag is None:
        return None
    from fpgalink.ros2.bag import BagError, NodeBag

    try:
        return NodeBag(options.bag, {"ports": " ".join(f"{b}={u}" for b, u in ports.items()),
                                     "robot": description.name}, force=options.force)
    except BagError as exc:
        _fail(str(exc), exc.code)


def _close_bag(bag: NodeBag, code: int) -> int:
    """The bag closed and said in one line; the exit code, a failure to close it included."""
    from fpgalink.ros2.bag import BagError

    try:
        bag.close()
    except BagError as exc:  # stopped early: complete up to there, or not finished
        print(f"{PROG}: error: {exc}", file=sys.stderr, flush=True)
        return code or exc.code
    print(f"{PROG}: bag {bag.path}: {bag.messages} messages", file=sys.stderr, flush=True)
    return code


async def _run(description: object, ports: dict[str, str], opening: dict[str, Any],
               source: str, bag: Any = None, lifecycle: bool = False, live: Any = None,
               argv: list[str] | None = None) -> int:
    """The node until SIGINT/SIGTERM; ``opening``: how ``Robot.open`` takes the boards
    (``baud``, ``wire_crc``, ``allow_mismatch``)."""
    from rclpy.exceptions import ParameterException
    from rclpy.node import Node

    from fpgalink.errors import FpgalinkError, exit_code
    from fpgalink.protocol.robot import RobotDescription
    from fpgalink.robot import Robot, RobotError
    from fpgalink.ros2.node import NODE_NAME, BadOverride, RosBridge, spin_in_thread
    from fpgalink.ros2.parameters import overrides_in

    assert isinstance(description, RobotDescription)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    overrides = overrides_in(argv or [], NODE_NAME)
    if lifecycle:
        from fpgalink.ros2.managed import run_managed

        return await run_managed(description, ports, opening, bag, stop, overrides)
    robot = Robot.open(description, ports, **opening)
    try:
        await robot.start()
    except (RobotError, FpgalinkError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr, flush=True)
        return _start_failed(exc)
    node = Node(NODE_NAME, start_parameter_services=False)
    try:
        try:
            bridge = RosBridge(robot, node, loop, bag=bag, overrides=overrides)
            await bridge.declare_board_parameters()
        except (ParameterException, BadOverride) as exc:  # a -p value out of range, …
            print(f"{PROG}: error: --ros-args -p: {_parameter_error(exc)}", file=sys.stderr,
                  flush=True)
            return EXIT_USAGE
        bridge.serve_parameters()
        if live is None and bridge.params.foxglove:  # the node parameter's route
            live, error = _parse_live("-p foxglove:=", bridge.params.foxglove)
            if error is not None:
                print(f"{PROG}: error: {error[0]}", file=sys.stderr, flush=True)
                return error[1]
        # Before ROS's executor thread: twice beside two busy loops a node said "up" and then
        # not its live view line for 120 s, the view started beside that thread (not pinned).
        view = await _live_view(live, robot)
        executor, thread = spin_in_thread(node)
        bridge.executor = executor
        node.get_logger().info(
            f"up: boards {', '.join(f'{b}={u}' for b, u in ports.items())}"
            + (" (emulated robot)" if robot.truth() is not None else "")
            + (f" (ports from {source})" if source not in ("command line", "default") else ""))
        running = asyncio.ensure_future(bridge.run())
        waiting = asyncio.ensure_future(stop.wait())
        await asyncio.wait({running, waiting}, return_when=asyncio.FIRST_COMPLETED)
        for task in (running, waiting):
            task.cancel()
        await asyncio.gather(running, waiting, return_exceptions=True)
        executor.shutdown(timeout_sec=1.0)
        thread.join(timeout=2.0)
        if view is not None:
            await view.close()
    except FpgalinkError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr, flush=True)
        return exit_code(exc)
    finally:
        await robot.close()
        with contextlib.suppress(Exception):
            node.destroy_node()
    return 0


async def _live_view(address: Any, robot: Any) -> Any:
    """The ROS-less route: the robot on a Foxglove live view beside the ROS topics."""
    if address is None:
        return None
    from fpgalink.live import LiveView

    view = LiveView(address, PROG, say=lambda text: print(f"{PROG}: {text}",
                                                           file=sys.stderr, flush=True))
    try:
        view.start()
    except OSError as exc:
        print(f"{PROG}: error: --foxglove: cannot listen: {exc}", file=sys.stderr, flush=True)
        raise SystemExit(ExitCode.PORT) from None
    view.add_robot(robot, robot.truth)
    print(f"{PROG}: live view for Foxglove on {view.url}", file=sys.stderr, flush=True)
    return view


def _start_failed(exc: Exception) -> ExitCode:
    """The boards could not be started: a port missing or busy (5), not answering (4), …
    as the CLI says it."""
    from fpgalink.errors import exit_code

    code = exit_code(exc)
    if code is ExitCode.FAILURE and "not answering" in str(exc):
        return ExitCode.NO_ANSWER
    return code


def _parameter_error(exc: Exception) -> str:
    """rclpy's "Invalid parameter value (V) for parameter. Reason: R: NAME" as
    "NAME: R" (the reason names the range), on one line."""
    text = " ".join(str(exc).split())
    head, _, name = text.rpartition(": ")
    reason = head.split("Reason: ", 1)[-1]
    return f"{name}: {reason}" if name and "Reason: " in head else text


if __name__ == "__main__":
    main()
