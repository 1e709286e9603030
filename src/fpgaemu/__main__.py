"""``fpgaemu serve``: emulated boards as devices (pty or TCP), paced to the wall clock.

Every failure is one line on stderr, ``fpgaemu: error: …``, and an exit code of the one
table every console script shares (:class:`fpgalink.protocol.exitcodes.ExitCode`): 2 for
bad input (usage, a parameter or fault spec, a config file), 5 when a board cannot be
served (an address in use or not valid here, a link path taken), 8 when a part it needs is
not installed (cffi for --firmware c). Options go before or after ``serve``.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import gc
import ipaddress
import math
import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path
from typing import Any, NoReturn

import click

from fpgaemu import timeline
from fpgaemu.build import UART_RX_MODES, build_board
from fpgaemu.faults import FAULT_HELP, parse_faults
from fpgaemu.liveview import INSTALL_HINT, EmulatorLiveView
from fpgaemu.physics import SURFACES
from fpgaemu.physics import SURFACES as PHYSICS_SURFACES
from fpgaemu.physics import why_unavailable as physics_missing
from fpgaemu.robot import BODIES, EmulatedRobot, check_body, default_body
from fpgaemu.serve import (
    IDLE_TIMEOUT_S,
    MAX_TRUTH_READERS,
    PacedBoard,
    PacedRobot,
    PtyEndpoint,
    RobotSide,
    TcpEndpoint,
    TruthEndpoint,
    serve_loop,
)
from fpgalink.ports import LinkError, LinkSpecError, make_link, pty_where, ready_line
from fpgalink.ports import parse_links as link_specs
from fpgalink.protocol import ParameterError
from fpgalink.protocol.exitcodes import ExitCode, NotInstalled, exit_codes_help
from fpgalink.protocol.paramfile import parse_parameter_table
from fpgalink.protocol.robot import DescriptionError, RobotDescription, load_robot, seed_robot
from fpgalink.protocol.tomlfile import TomlFileError, load_toml
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

__all__ = ["cli", "main"]

__version__ = "0.2.0"

#: The robot has two boards, one per side; the seed calls them L and R.
BOARD_NAMES = ("L", "R")

EXIT_BAD_INPUT = ExitCode.BAD_INPUT
EXIT_CANNOT_SERVE = ExitCode.PORT


class ServeError(click.ClickException):
    """One line on stderr and an exit code; no traceback."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(" ".join(message.split()))
        setattr(self, "exit_code", code)  # noqa: B010 - click declares it on the class

    def show(self, file: Any = None) -> None:
        click.echo(f"fpgaemu: error: {self.format_message()}", err=True)


def running_build() -> str:
    """Which build of the emulator runs: its modules compiled (mypyc) or pure Python."""
    compiled = timeline.__file__ is not None and timeline.__file__.endswith(
        tuple(EXTENSION_SUFFIXES))
    return "compiled (mypyc)" if compiled else "pure Python"


def board_names(count: int) -> list[str]:
    return [BOARD_NAMES[i] if i < len(BOARD_NAMES) else f"B{i + 1}" for i in range(count)]


def parse_tcp(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``:PORT`` (every interface)."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not port_text.isdigit() or int(port_text) > 65535:
        raise ServeError(f"--tcp {text!r}: expected HOST:PORT (port 0..65535; [ADDRESS]:PORT "
                         "for IPv6)", EXIT_BAD_INPUT)
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ServeError(f"--tcp {text!r}: {host!r} is not an IPv6 address",
                             EXIT_BAD_INPUT) from None
    elif ":" in host:
        raise ServeError(f"--tcp {text!r}: write an IPv6 address in brackets, e.g. "
                         "[::1]:0", EXIT_BAD_INPUT)
    return host, int(port_text)


def parse_settings(config: Path | None, assignments: tuple[str, ...]) -> dict[str, int | float]:
    """``--config`` (the format ``fpgalink-cli param dump`` writes) then ``--set`` values, as
    initial parameters by full name; every value validated as a ``PS`` would be."""
    settings: dict[str, int | float] = {}
    try:
        if config is not None:
            try:
                document = load_toml(str(config), f"--config {config}")
            except TomlFileError as exc:
                raise ServeError(str(exc), EXIT_BAD_INPUT) from None
            for param, channel, value in parse_parameter_table(document, str(config)):
                settings[param.full_name(channel)] = value
        table: dict[str, object] = {}
        for item in assignments:
            name, sep, raw = item.partition("=")
            if not sep or not name.strip():
                raise ServeError(f"--set {item!r}: expected NAME=VALUE", EXIT_BAD_INPUT)
            try:
                table[name.strip()] = int(raw) if raw.strip().lstrip("+-").isdigit() \
                    else float(raw)
            except ValueError:
                raise ServeError(f"--set {item!r}: {raw!r} is not a number",
                                 EXIT_BAD_INPUT) from None
        for param, channel, value in parse_parameter_table(table, "--set"):
            settings[param.full_name(channel)] = value
    except ParameterError as exc:
        raise ServeError(str(exc), EXIT_BAD_INPUT) from None
    return settings


def parse_links(values: tuple[str, ...], names: list[str]) -> dict[str, Path]:
    """``--link PATH`` (one board) or ``--link NAME=PATH`` per board (the router's grammar,
    :func:`fpgalink.ports.parse_links`); a board's one pty has one link."""
    links: dict[str, Path] = {}
    try:
        given = link_specs(values, names)
    except LinkSpecError as exc:
        raise ServeError(str(exc), EXIT_BAD_INPUT) from None
    for name, path in given:
        if name in links:
            raise ServeError(f"--link {path}: board {name} has one pty, linked at "
                             f"{links[name]} already; give each board one --link",
                             EXIT_BAD_INPUT)
        links[name] = path
    return links


@dataclass
class Options:
    """Options given before ``serve``, for the command to fall back on."""

    given: dict[str, Any] = field(default_factory=dict)


def _file_name(ctx: click.Context, param: click.Parameter, value: str | None) -> Path | None:
    """A file option's value as a path; an empty name is an error, not "no file"."""
    if value is None:
        return None
    if not value.strip():
        raise ServeError(f"--{(param.name or '').replace('_path', '').replace('_', '-')}: "
                         "empty file name", EXIT_BAD_INPUT)
    return Path(value)


SERVE_OPTIONS: list[Callable[[Callable[..., Any]], Callable[..., Any]]] = [
    click.option("--pty", "use_pty", is_flag=True, default=None,
                 help="Serve each board on a pseudo-terminal."),
    click.option("--tcp", "tcp", metavar="HOST:PORT",
                 help="Serve on TCP. Port 0: each board gets a free port; port N: boards "
                      "take N, N+1, … (the ready lines say which)."),
    click.option("--boards", type=click.IntRange(1, 8),
                 help="How many boards (2 = the robot's L and R)  [default: 1]"),
    click.option("--baud", type=click.IntRange(MIN_BAUD, MAX_BAUD),
                 help="Line rate  [default: 1000000]"),
    click.option("--seed", type=int, help="Seed for noise and faults  [default: 0]"),
    click.option("--gear", type=click.Choice(["high", "low"]),
                 help="Gearbox stage of the wheels  [default: high]"),
    click.option("--config", "config_path", callback=_file_name, metavar="FILE",
                 help="Initial parameter values: the TOML file `fpgalink-cli param dump` "
                      "writes (NAME = VALUE, tables [A] and [B])."),
    click.option("--set", "assignments", multiple=True, metavar="NAME=VALUE",
                 help="Initial parameter value, e.g. --set Kp_Wheel_PidA=9 (repeatable)."),
    click.option("--link", "links", multiple=True, metavar="[NAME=]PATH",
                 help="A stable symlink to the board's pty (per board: --link L=/tmp/fpga-L); "
                      "removed on exit."),
    click.option("--fault", "faults", multiple=True, metavar="[BOARD:]SPEC",
                 help="Fault injection, repeatable (BOARD: only that board, e.g. "
                      "L:wheel-stuck=A): the SPECs are in the table below, the long form in "
                      "docs/reliability.md."),
    click.option("--robot", "robot", is_flag=True, default=None,
                 help="Serve a robot: its boards (L, R) move one emulated body; the true "
                      "pose streams from a truth endpoint (see --truth)."),
    click.option("--robot-file", "robot_file", callback=_file_name, metavar="FILE",
                 help="The robot description (TOML; default: the seed's robot)."),
    click.option("--surface", metavar="NAME",
                 help="What the robot drives on: with --body mujoco one of "
                      f"{', '.join(SURFACES)}; with --body kinematic a surface of the robot "
                      "description (the seed's robot: ideal, gravel, marble, grass)  "
                      "[default: the description's]"),
    click.option("--body", "body", metavar="|".join(BODIES),
                 help="The robot's body: mujoco (a physics engine: the wheels slip, carry "
                      "the ground's load, an IMU feels it) or kinematic (the odometry's own "
                      "model: fast and exact)  [default: mujoco where MuJoCo is installed]"),
    click.option("--uart-rx", "uart_rx", metavar="|".join(UART_RX_MODES),
                 help="How each board's UART receiver finds a start bit: edge (LiteX's: a "
                      "falling edge) or level (verilog-uart's, a 16550's: a low level, "
                      "checked again at mid-bit)  [default: edge]"),
    click.option("--tx-gap", "tx_gap", type=click.IntRange(0, 10_000), metavar="CYCLES",
                 help="Idle cycles each board's UART leaves after a stop bit between "
                      "back-to-back bytes (2 = LiteX's PHY)  [default: 0]"),
    click.option("--truth", "truth", metavar="HOST:PORT",
                 help="With --robot: where the true pose streams as JSON lines, to up to "
                      f"{MAX_TRUTH_READERS} readers  [default: 127.0.0.1:0]"),
    click.option("--foxglove", "foxglove", metavar="[HOST:]PORT",
                 help="With --robot: a live view of the true body for Foxglove, a WebSocket "
                      "server on PORT (loopback unless HOST is given); needs the foxglove "
                      "extra (fpgaemu/liveview.py)"),
    click.option("--firmware", "firmware", type=click.Choice(["python", "c"]),
                 help="The MicroBlaze software: the Python model, or the C core of firmware/ "
                      "(built on first use with the system C compiler; docs/firmware.md)  "
                      "[default: python]"),
    click.option("--seed-protocol", "seed_protocol", is_flag=True, default=None,
                 help="Serve boards as the seed's firmware was: IQ is not known (counted, "
                      "unanswered), so a host sees \"seed protocol, identity unknown\" "
                      "(docs/protocol.md §8); the Python firmware only."),
    click.option("--declarations", "declarations", metavar="HEX",
                 help="Answer IQ with this protocol declaration hash (16 hex digits), as a "
                      "firmware generated from another declaration would: to try a host's "
                      "refusal (the wire it speaks is still this one); the Python firmware "
                      "only."),
    click.option("--idle-timeout", "idle_timeout", type=float, metavar="SECONDS",
                 help="With --tcp: disconnect a host that has sent nothing this long after "
                      "connecting; 0: never  [default: "
                      f"{IDLE_TIMEOUT_S:g}]"),
]
DEFAULTS: dict[str, Any] = {"use_pty": False, "tcp": None, "boards": 1, "baud": 1_000_000,
                            "seed": 0, "gear": "high", "config_path": None,
                            "assignments": (), "links": (), "faults": (), "robot": False,
                            "robot_file": None, "surface": None, "truth": None,
                            "firmware": "python", "idle_timeout": None,
                            "body": None, "uart_rx": "edge", "tx_gap": 0, "foxglove": None,
                            "seed_protocol": False, "declarations": None}


def with_serve_options(func: Callable[..., Any]) -> Callable[..., Any]:
    for option in reversed(SERVE_OPTIONS):
        func = option(func)
    return func


@click.group(context_settings={"help_option_names": ["-h", "--help"],
                               "max_content_width": 100})
@click.version_option(__version__, prog_name="fpgaemu",
                      message=f"%(prog)s, version %(version)s, {running_build()}")
@with_serve_options
@click.pass_context
def cli(ctx: click.Context, /, **given: Any) -> None:
    """Cycle-level emulator of the FPGA motor-controller board.

    Serve options may come before the command (fpgaemu --pty serve) or after it."""
    ctx.obj = Options({k: v for k, v in given.items() if v not in (None, ())})


#: The fault table kept as a table (``\b``: click does not rewrap the paragraph).
SERVE_EPILOG = ("\b\nFault SPECs (--fault [BOARD:]SPEC):\n" + FAULT_HELP.rstrip("\n")
                + "\n\n" + exit_codes_help((
                    ExitCode.OK, ExitCode.FAILURE, ExitCode.BAD_INPUT, ExitCode.PORT,
                    ExitCode.NOT_INSTALLED, ExitCode.INTERRUPTED)))


@cli.command(epilog=SERVE_EPILOG)
@with_serve_options
@click.pass_context
def serve(ctx: click.Context, /, **given: Any) -> None:
    """Serve emulated boards until SIGINT/SIGTERM. Prints `ready <board> <path-or-url>` per
    board, `ready <board> <link> -> <pty>` with --link, and with --robot `ready truth
    socket://HOST:PORT` (the true pose as JSON lines), all at once when every one is
    reachable; none if any cannot be served (exit 5)."""
    before = ctx.obj.given if isinstance(ctx.obj, Options) else {}
    value = {**DEFAULTS, **before, **{k: v for k, v in given.items() if v not in (None, ())}}
    use_pty, tcp = bool(value["use_pty"]), value["tcp"]
    if use_pty == (tcp is not None):
        raise ServeError("give exactly one of --pty or --tcp HOST:PORT", EXIT_BAD_INPUT)
    host, port = parse_tcp(tcp) if tcp is not None else ("127.0.0.1", 0)
    robot = _robot(value) if value["robot"] else None
    if robot is None and any(value[k] is not None
                             for k in ("robot_file", "surface", "truth", "body", "foxglove")):
        raise ServeError("--robot-file, --surface, --body, --truth and --foxglove go with "
                         "--robot", EXIT_BAD_INPUT)
    if value["uart_rx"] not in UART_RX_MODES:
        raise ServeError(f"--uart-rx {value['uart_rx']!r}: choose "
                         f"{' or '.join(UART_RX_MODES)}", EXIT_BAD_INPUT)
    declarations = _declarations(value["declarations"])
    if value["seed_protocol"] and declarations is not None:
        raise ServeError("--seed-protocol and --declarations: a seed board does not answer "
                         "IQ at all", EXIT_BAD_INPUT)
    if (value["seed_protocol"] or declarations is not None) and value["firmware"] == "c":
        raise ServeError("--seed-protocol and --declarations serve the Python firmware; the "
                         "C core (--firmware c) answers IQ with the hash it was generated "
                         "from", EXIT_BAD_INPUT)
    body = _body(value, robot) if robot is not None else None
    names = list(robot.boards) if robot else board_names(value["boards"])
    links = parse_links(value["links"], names)
    if links and not use_pty:
        raise ServeError("--link makes a symlink to a pty: use it with --pty", EXIT_BAD_INPUT)
    settings = parse_settings(value["config_path"], value["assignments"])
    faults = _board_faults(list(value["faults"]), names)
    truth = parse_tcp(value["truth"] or "127.0.0.1:0") if robot else None
    live = _live_view(value["foxglove"], robot)
    idle_timeout = value["idle_timeout"]
    if idle_timeout is None:
        idle_timeout = IDLE_TIMEOUT_S
    elif use_pty:
        raise ServeError("--idle-timeout goes with --tcp (a pty has no connection to drop)",
                         EXIT_BAD_INPUT)
    elif not (math.isfinite(idle_timeout) and idle_timeout >= 0):
        raise ServeError(f"--idle-timeout {idle_timeout!r}: expected seconds ≥ 0 (0: never)",
                         EXIT_BAD_INPUT)
    try:
        paced = _paced_boards(names, robot, value["baud"], value["seed"], value["gear"],
                              settings, faults, value["firmware"], body=body,
                              uart_rx=value["uart_rx"], tx_gap=value["tx_gap"],
                              surface=value["surface"],
                              identity=not value["seed_protocol"],
                              declarations=declarations)
    except ValueError as exc:
        raise ServeError(str(exc).splitlines()[0], ExitCode.NOT_INSTALLED if isinstance(
            exc, NotInstalled) else EXIT_BAD_INPUT) from None
    # What is made by now (the modules, numpy's and MuJoCo's among them, and the boards)
    # lives as long as serve: out of the collector's sight, a full collection while serving
    # walks only what serving made (it walked them all: 20-50 ms on a loaded machine, a
    # gap in telemetry a host may take for a board that stopped).
    gc.freeze()
    with asyncio.Runner(loop_factory=serve_loop) as runner:
        code = runner.run(_serve(use_pty, host, port, paced, links, truth, idle_timeout,
                                 live))
    sys.exit(code)


def _declarations(text: str | None) -> int | None:
    """``--declarations HEX``: a declaration hash as ``IA`` carries it (u64)."""
    if text is None:
        return None
    digits = text.strip().lower().removeprefix("0x")
    if not (1 <= len(digits) <= 16 and all(c in "0123456789abcdef" for c in digits)):
        raise ServeError(f"--declarations {text!r}: expected a hash of up to 16 hex digits "
                         "(as fpgalink-cli ports --identify shows one)", EXIT_BAD_INPUT)
    return int(digits, 16)


def _robot(value: dict[str, Any]) -> RobotDescription:
    try:
        description = load_robot(str(value["robot_file"])) if value["robot_file"] \
            else seed_robot()
    except DescriptionError as exc:
        raise ServeError(str(exc), EXIT_BAD_INPUT) from None
    if value["boards"] not in (1, len(description.boards)):
        raise ServeError(f"--robot serves the robot's {len(description.boards)} boards; "
                         "leave out --boards", EXIT_BAD_INPUT)
    return description


def _body(value: dict[str, Any], description: RobotDescription) -> str:
    """The body to serve, checked with the surface: one line and exit 2 otherwise; when
    MuJoCo is missing and no body was asked for, the kinematic one, said once."""
    body = value["body"]
    surface = value["surface"] or description.surface
    if body is None:
        if physics_missing() is not None and surface in PHYSICS_SURFACES:
            body = "kinematic"  # said here, once (default_body would say it again)
            print("fpgaemu: MuJoCo is not installed: the robot's body is the kinematic one "
                  "(pip install 'fpgalink[physics]' for the physics body)", file=sys.stderr,
                  flush=True)
        else:
            body = default_body(surface)
    try:
        check_body(body, surface, description)
    except ValueError as exc:
        flag = "--surface" if str(exc).startswith("surface") else "--body"
        raise ServeError(f"{flag}: {exc}", EXIT_BAD_INPUT) from None
    return str(body)


def _board_faults(specs: list[str], names: list[str]) -> dict[str, list[str]]:
    """``--fault SPEC`` (every board) or ``--fault BOARD:SPEC`` → specs per board."""
    faults: dict[str, list[str]] = {name: [] for name in names}
    for spec in specs:
        board, sep, rest = spec.partition(":")
        if sep and board in names and "=" not in board:
            targets, fault = [board], rest
        else:
            targets, fault = names, spec
        try:
            parse_faults([fault])
        except ValueError as exc:
            raise ServeError(str(exc).splitlines()[0], EXIT_BAD_INPUT) from None
        for target in targets:
            faults[target].append(fault)
    for name, specs in faults.items():  # and no board given more than the grammar allows
        try:
            parse_faults(specs)
        except ValueError as exc:
            raise ServeError(f"board {name}: {exc}", EXIT_BAD_INPUT) from None
    return faults


def _paced_boards(names: list[str], robot: RobotDescription | None, baud: int, seed: int,
                  gear: str, settings: dict[str, int | float],
                  faults: dict[str, list[str]], firmware: str = "python", *,
                  body: str | None = None, uart_rx: str = "edge", tx_gap: int = 0,
                  surface: str | None = None, identity: bool = True,
                  declarations: int | None = None) -> dict[str, PacedBoard]:
    if robot is not None:
        emulated = EmulatedRobot(robot, surface, baud=baud, seed=seed, gear=gear,
                                 faults=faults, settings=settings, body=body,
                                 uart_rx=uart_rx, tx_byte_gap=tx_gap, firmware=firmware,
                                 identity=identity, declarations=declarations)
        paced_robot = PacedRobot(emulated)
        return {name: paced_robot.side(name) for name in names}
    return {name: PacedBoard(build_board(baud=baud, seed=seed + index, gear=gear,
                                         settings=settings, faults=faults[name],
                                         firmware=firmware, uart_rx=uart_rx,
                                         tx_byte_gap=tx_gap, identity=identity,
                                         declarations=declarations))
            for index, name in enumerate(names)}


def _make_link(path: Path, target: str) -> None:
    """:func:`fpgalink.ports.make_link`; a path that is not ours to take, or that the system
    refuses, is a board that cannot be served (exit 5)."""
    try:
        make_link(path, target)
    except LinkError as exc:
        raise ServeError(str(exc), EXIT_CANNOT_SERVE) from None


async def _serve(use_pty: bool, host: str, port: int, paced: dict[str, PacedBoard],
                 links: dict[str, Path], truth: tuple[str, int] | None,
                 idle_timeout: float = IDLE_TIMEOUT_S,
                 live: Callable[[Callable[[], dict[str, Any]]], EmulatorLiveView] | None = None
                 ) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    endpoints: list[tuple[str, PtyEndpoint | TcpEndpoint]] = []
    truth_endpoint: TruthEndpoint | None = None
    loop.add_signal_handler(signal.SIGUSR1, lambda: _report_all(endpoints, truth_endpoint,
                                                                 final=False))
    # Printed once every endpoint is up: a script that connects on the first ready line
    # must not reach a board that is about to go because a later one could not be served.
    ready: list[str] = []
    served = False
    stack = contextlib.AsyncExitStack()
    try:
        for index, (name, board) in enumerate(paced.items()):
            if use_pty:
                pty = PtyEndpoint(board)
                pty.start()
                endpoints.append((name, pty))
                if name in links:
                    _make_link(links[name], pty.path)
                    pty.link = links[name]
                ready.append(ready_line(name, pty_where(pty.path, pty.link)))
            else:
                tcp = TcpEndpoint(board, host, port + index if port else 0,
                                  idle_timeout=idle_timeout)
                try:
                    await tcp.start()
                except OSError as exc:
                    raise ServeError(f"cannot serve board {name} on {tcp.url}: "
                                     f"{exc.strerror or exc}", EXIT_CANNOT_SERVE) from None
                endpoints.append((name, tcp))
                # One line per listening socket (IPv4 and IPv6 of a wildcard address), each
                # an address a client can use.
                ready += [ready_line(name, url) for url in tcp.urls]
        sides = [b for b in paced.values() if isinstance(b, RobotSide)]
        if truth is not None and sides:
            truth_endpoint = TruthEndpoint(sides[0].robot, *truth)
            try:
                await truth_endpoint.start()
            except OSError as exc:
                raise ServeError(f"cannot serve the truth on {truth_endpoint.url}: "
                                 f"{exc.strerror or exc}", EXIT_CANNOT_SERVE) from None
            ready += [ready_line("truth", url) for url in truth_endpoint.urls]
            if live is not None:
                view = live(sides[0].robot.truth_record)
                try:
                    view.start()
                except OSError as exc:
                    raise ServeError(f"--foxglove: cannot listen: {exc}",
                                     EXIT_CANNOT_SERVE) from None
                stack.push_async_callback(view.close)
                ready.append(ready_line("foxglove", view.url))
        try:
            print("\n".join(ready), flush=True)
        except BrokenPipeError:
            _quiet_stdout()  # nobody reads the ready lines (| head -0): serve on
        except OSError as exc:
            raise _stdout_failed(exc) from None
        served = True
        await stop.wait()
    finally:
        await stack.aclose()
        if truth_endpoint is not None:
            await truth_endpoint.close()
        for _, endpoint in endpoints:
            if isinstance(endpoint, PtyEndpoint):
                # Before the pty goes: its freed number may be given to another at once.
                endpoint.remove_own_link()
            await endpoint.close()
        if served:  # a serve that could not start says only why (one line)
            _report_all(endpoints, truth_endpoint, final=True)
    return 0


def _live_view(text: str | None, robot: RobotDescription | None
               ) -> Callable[[Callable[[], dict[str, Any]]], EmulatorLiveView] | None:
    """``--foxglove [HOST:]PORT``, checked before anything is served: what makes the live
    view once the robot's truth is there."""
    if text is None or robot is None:
        return None
    host, port = parse_tcp(text if ":" in text else f"127.0.0.1:{text}")
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise ServeError(INSTALL_HINT, ExitCode.NOT_INSTALLED) from None
    return functools.partial(EmulatorLiveView, host or "0.0.0.0", port, robot)


def _report_all(endpoints: list[tuple[str, PtyEndpoint | TcpEndpoint]],
                truth: TruthEndpoint | None, *, final: bool) -> None:
    """Each board's byte counts (and its troubles) on stderr: on exit, and on SIGUSR1."""
    for name, endpoint in endpoints:
        _report(name, endpoint)
    if truth is not None:
        notes = [f"{truth.readers} reader(s) now"] if not final else []
        if truth.turned_away:
            notes.append(f"{truth.turned_away} reader(s) turned away (at most "
                         f"{MAX_TRUTH_READERS} at once)")
        if truth.aborted:
            notes.append(f"{truth.aborted} reader(s) let go for not reading")
        if truth.listener.refused_no_descriptor:
            notes.append(f"{truth.listener.refused_no_descriptor} connection(s) turned away "
                         "for want of a file descriptor")
        if notes:
            print(f"truth: {'; '.join(notes)}", file=sys.stderr, flush=True)


def _report(name: str, endpoint: PtyEndpoint | TcpEndpoint) -> None:
    paced = endpoint.paced
    board = paced.board
    rx, command, tx = board.uartread.stats, board.uartcommand.stats, board.uartwrite.stats
    # What crossed the cable, both ways: the accounting a test or a user checks the
    # "nothing the host wrote is lost" promise against.
    counts = (f"host → board {rx.bytes_sent:,} bytes ({command.bytes_received:,} received: "
              f"{command.noise_bytes:,} noise between frames, {command.frames:,} frames; "
              f"held back {endpoint.flow.pauses:,} times; {paced.discarded_rx:,} discarded "
              f"when a host left); board → host {tx.bytes_sent:,} bytes")
    notes = [counts]
    if endpoint.dropped_tx:
        notes.append(f"dropped {endpoint.dropped_tx} TX bytes nobody read in time")
    if paced.lag.lag_events:
        notes.append(f"fell behind real time {paced.lag.lag_events} times, worst "
                     f"{paced.lag.worst_lag_s * 1000:.1f} ms (caught up, no bytes lost)")
    if paced.heartbeat.watchdog_lapses:
        notes.append(f"watchdog lapsed {paced.heartbeat.watchdog_lapses} times; the host "
                     "wrote nothing for up to "
                     f"{paced.heartbeat.longest_silence_s * 1000:.1f} ms while it was enabled")
    if endpoint.unplugs:
        lost = (f": {endpoint.unplugged_tx:,} TX bytes sent while unplugged, gone"
                if isinstance(endpoint, PtyEndpoint) and endpoint.unplugged_tx else "")
        notes.append(f"unplugged {endpoint.unplugs} time(s) (--fault unplug){lost}")
    if isinstance(endpoint, TcpEndpoint):
        if endpoint.turned_away:
            notes.append(f"{endpoint.turned_away} host(s) told busy")
        if endpoint.idle_closed:
            notes.append(f"{endpoint.idle_closed} host(s) disconnected for sending nothing")
        if endpoint.listener.refused_no_descriptor:
            notes.append(f"{endpoint.listener.refused_no_descriptor} connection(s) turned "
                         "away for want of a file descriptor")
    for note in notes:
        print(f"{name}: {note}", file=sys.stderr, flush=True)


EXIT_FAILURE = ExitCode.FAILURE


def _from_clicks_echo(exc: BaseException) -> bool:
    """Whether ``exc`` came out of click's own output (help, version): stdout failed, not
    one of serve's ports, which says so itself."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and tb.tb_frame.f_code is click.utils.echo.__code__


class StdoutError(ServeError):
    """stdout could not be written (``> /dev/full``)."""


def _stdout_failed(exc: OSError) -> StdoutError:
    return StdoutError(f"cannot write to stdout: {exc.strerror or exc}", EXIT_FAILURE)


def _quiet_stdout() -> None:
    """What is still buffered for a stdout that failed goes to /dev/null, so the
    interpreter's last flush prints no traceback."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True,
                               "help_option_names": []})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def campaign(args: tuple[str, ...]) -> None:
    """Run a campaign of scenarios on emulated robots: the same command as `fpgalink-cli
    campaign SPEC.toml` (its --help says more), which it runs."""
    # A campaign drives each emulated robot through the library's robot (supervision,
    # odometry, go-to), which the emulator never imports: it hands over to the library's
    # command, as a program, not by import.
    os.execv(sys.executable, [sys.executable, "-m", "fpgalink", "campaign", *args])


def main(argv: list[str] | None = None) -> NoReturn:
    try:
        cli.main(args=argv, prog_name="fpgaemu", standalone_mode=False)
        sys.stdout.flush()
    except BrokenPipeError:  # the reader went away (| head): nothing to say
        _quiet_stdout()
        sys.exit(0)
    except OSError as exc:
        if not _from_clicks_echo(exc):
            raise
        # > /dev/full: one line and exit 1, as fpgalink-cli, not a traceback.
        _stdout_failed(exc).show()
        _quiet_stdout()
        sys.exit(EXIT_FAILURE)
    except click.exceptions.NoArgsIsHelpError as exc:  # pragma: no cover - click >= 8.2
        click.echo(exc.ctx.get_help() if exc.ctx else str(exc))
        sys.exit(0)
    except click.ClickException as exc:
        if isinstance(exc, ServeError):
            if isinstance(exc, StdoutError):
                _quiet_stdout()
            exc.show()
        else:  # click's own usage errors, as one line
            click.echo(f"fpgaemu: error: {' '.join(exc.format_message().split())}", err=True)
        sys.exit(exc.exit_code)
    except click.Abort:
        sys.exit(ExitCode.INTERRUPTED)
    sys.exit(ExitCode.OK)


if __name__ == "__main__":
    main()

