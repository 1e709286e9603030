"""The house rules of docs/architecture.md, read from every module's imports: each layer
imports only the layers below it, and the two packages meet only in fpgalink.protocol (and
fpgalink.ports, the operating system's side of serving a board, which both servers share)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def imports_of(path: Path, lazy: bool = True) -> set[str]:
    """Every module ``path`` imports, at any depth (lazy imports inside functions too; with
    ``lazy=False`` only those at import time: the module's top level, outside functions)."""
    found: set[str] = set()
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = ast.walk(tree) if lazy else (n for top in tree.body if not isinstance(
        top, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef) for n in ast.walk(top))
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def modules(package: str) -> list[tuple[str, Path]]:
    root = SRC / package.replace(".", "/")
    files = [root.with_suffix(".py")] if root.with_suffix(".py").exists() else sorted(
        root.rglob("*.py"))
    return [(str(f.relative_to(SRC)), f) for f in files]


def first_party(names: set[str]) -> set[str]:
    return {n for n in names if n.split(".")[0] in ("fpgalink", "fpgaemu")}


def within(name: str, *allowed: str) -> bool:
    return any(name == a or name.startswith(a + ".") for a in allowed)


@pytest.mark.parametrize(("where", "path"), modules("fpgaemu"))
def test_the_emulator_imports_only_the_public_protocol_package(where: str, path: Path) -> None:
    # And fpgalink.ports: the pty, its --link and the ready lines, which fpgaemu serve shares
    # with fpgalink-cli router.
    crossing = {n for n in first_party(imports_of(path))
                if n.startswith("fpgalink") and not within(n, "fpgalink.protocol",
                                                           "fpgalink.ports")}
    assert not crossing, f"{where} imports {sorted(crossing)}"


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.ports"))
def test_the_ports_package_stands_on_the_standard_library_alone(where: str, path: Path
                                                                ) -> None:
    # Both servers import it, the emulator among them: it may lean on nothing of fpgalink
    # that the emulator may not import, and on nothing outside the standard library.
    names = imports_of(path)
    assert not {n for n in first_party(names) if not within(n, "fpgalink.ports")}, where
    outside = {n for n in names if n.split(".")[0] not in sys.stdlib_module_names
               and n.split(".")[0] not in ("__future__", "fpgalink")}
    assert not outside, f"{where} imports {sorted(outside)}"


#: The router's parts that decide without I/O or a clock: what waits for a line, a client's
#: accounting, who controls the board.
ROUTER_SANS_IO = ("router/linequeue.py", "router/stats.py", "router/arbitration.py")


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.router"))
def test_the_router_stands_on_the_transports_beside_the_robot(where: str, path: Path) -> None:
    # The router's daemon moves frames between a board's port (fpgalink.aio's transports)
    # and its clients; the CLI's router command stands on it, never the reverse, and it
    # needs neither the robot nor a link's connection.
    names = imports_of(path)
    allowed = ("fpgalink.protocol", "fpgalink.ports", "fpgalink.errors",
               "fpgalink.aio.transport", "fpgalink.router")
    assert not {n for n in first_party(names) if not within(n, *allowed)}, where
    if where.endswith(ROUTER_SANS_IO):
        assert not names & {"asyncio", "time", "socket", "select", "os", "threading"}, where
        assert not {n for n in first_party(names)
                    if not within(n, "fpgalink.protocol", *(
                        "fpgalink." + m.removesuffix(".py").replace("/", ".")
                        for m in ROUTER_SANS_IO))}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink"))
def test_fpgalink_never_imports_the_emulator(where: str, path: Path) -> None:
    assert not {n for n in imports_of(path) if n.split(".")[0] == "fpgaemu"}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.protocol"))
def test_the_protocol_stands_on_nothing_else(where: str, path: Path) -> None:
    names = imports_of(path)
    assert not {n for n in first_party(names) if not within(n, "fpgalink.protocol")}, where
    assert not names & {"asyncio", "time", "socket", "serial", "os"}, where


SANS_IO = ("fpgalink.connection", "fpgalink.events", "fpgalink.errors", "fpgalink.boardclock")


@pytest.mark.parametrize(("where", "path"),
                         [m for package in SANS_IO for m in modules(package)])
def test_the_sans_io_layer_has_no_io_and_no_clock(where: str, path: Path) -> None:
    names = imports_of(path)
    assert not names & {"asyncio", "time", "socket", "serial", "os", "threading"}, where
    assert not {n for n in first_party(names)
                if not within(n, "fpgalink.protocol", *SANS_IO)}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.aio"))
def test_the_asyncio_layer_stands_on_the_sans_io_layer(where: str, path: Path) -> None:
    above = {n for n in first_party(imports_of(path))
             if within(n, "fpgalink.cli", "fpgalink.robot", "fpgalink.ros2",
                       "fpgalink.router")}
    assert not above, f"{where} imports {sorted(above)}"


#: The robot's modules that run on asyncio (over the links); the rest of it is sans-I/O.
ROBOT_ON_ASYNCIO = ("robot.py", "boards.py", "setup.py", "recovery.py", "goal.py", "timers.py",
                    "feed.py", "following.py")


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.robot"))
def test_the_robot_stands_on_the_asyncio_layer_and_below(where: str, path: Path) -> None:
    names = imports_of(path)
    above = {n for n in first_party(names) if within(n, "fpgalink.cli", "fpgalink.ros2",
                                                      "fpgalink.campaign", "fpgalink.live",
                                                      "fpgalink.router")}
    assert not above, f"{where} imports {sorted(above)}"
    if path.name not in ROBOT_ON_ASYNCIO:  # the sans-I/O parts: no I/O, no clock
        assert not names & {"asyncio", "time", "socket", "serial", "os", "threading"}, where
        assert not {n for n in first_party(names) if within(n, "fpgalink.aio")}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.bringup"))
def test_bring_up_stands_beside_the_robot(where: str, path: Path) -> None:
    # identify/autotune/calibrate's library: fitting, design and calibration sans-I/O on the
    # protocol and the robot's sans-I/O parts; only its session runs experiments on links.
    names = imports_of(path)
    above = {n for n in first_party(names) if within(n, "fpgalink.cli", "fpgalink.ros2",
                                                      "fpgalink.campaign")}
    assert not above, f"{where} imports {sorted(above)}"
    if not where.endswith("bringup/session.py"):
        assert not names & {"asyncio", "time", "socket", "serial", "os", "threading"}, where
        assert not {n for n in first_party(names)
                    if within(n, "fpgalink.aio", "fpgalink.robot.robot")}, where


def status_events_named(path: Path) -> set[str]:
    """The link's status events (:class:`fpgalink.events.StatusEvent` and its kinds) that
    ``path`` imports by name."""
    from fpgalink import events

    kinds = {name for name in events.__all__
             if isinstance(kind := getattr(events, name), type)
             and issubclass(kind, events.StatusEvent)}
    named: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module in ("fpgalink", "fpgalink.events"):
            named.update(alias.name for alias in node.names if alias.name in kinds)
    return named


@pytest.mark.parametrize(("where", "path"),
                         [m for package in ("fpgalink.ros2", "fpgalink.campaign", "fpgalink.cli",
                                          "fpgalink.live")
                          for m in modules(package)])
def test_above_the_robot_link_events_are_the_robots(where: str, path: Path) -> None:
    # The node, the campaigns and the CLI's robot commands reach the boards through the
    # robot (its arbiter drives them; its notices say what their links noticed), so the
    # link's events are read in one place (fpgalink.robot.recovery). The CLI's one-board
    # commands (monitor, record, step, param…) stand on a Link of their own.
    one_board = ("cli/session.py", "cli/step.py", "cli/monitor.py", "cli/record.py",
                 "cli/options.py", "cli/param.py", "cli/send.py", "cli/budget.py",
                 "cli/ports.py", "cli/router.py", "cli/liveview.py")
    if where.endswith(one_board):
        return
    text = path.read_text(encoding="utf-8")
    read = status_events_named(path)
    assert not read and ".watch(" not in text, \
        f"{where} reads link events ({sorted(read)}): ask the robot (on_notice)"
    assert ".links[" not in text and ".links." not in text, \
        f"{where} reaches into the robot's links: use the robot's own methods"


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.campaign"))
def test_campaigns_stand_on_the_robot_and_below(where: str, path: Path) -> None:
    # Beside the CLI and the node: the CLI's campaign and tune commands stand on it.
    above = {n for n in first_party(imports_of(path))
             if within(n, "fpgalink.cli", "fpgalink.ros2")}
    assert not above, f"{where} imports {sorted(above)}"


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.live"))
def test_the_live_view_stands_on_the_robot_beside_the_cli(where: str, path: Path) -> None:
    # The CLI and the ROS 2 node both open it; it may import neither, nor any ROS package;
    # foxglove-sdk only when a view starts (the extra), never at import.
    names = imports_of(path, lazy=False)
    assert not {n for n in first_party(imports_of(path))
                if within(n, "fpgalink.cli", "fpgalink.ros2", "fpgaemu")}, where
    assert not {n for n in imports_of(path) if within(n, "rclpy")}, where
    assert not {n for n in names if within(n, "foxglove")}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.config"))
def test_the_config_file_reader_stands_on_the_protocol_alone(where: str, path: Path) -> None:
    # The CLI and the ROS 2 node both read fpgalink.toml through it; the node may not
    # import the CLI.
    assert not {n for n in first_party(imports_of(path))
                if not within(n, "fpgalink.protocol")}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.recording"))
def test_the_recording_writer_stands_on_the_protocol_alone(where: str, path: Path) -> None:
    # The CLI's record, drive, goto and --rosbag2, the campaigns and the node's --bag write
    # (and plot reads) through it, and the campaigns and the node may not import the CLI:
    # it sits below all of them, beside the sans-I/O layer.
    names = imports_of(path)
    assert not {n for n in first_party(names)
                if not within(n, "fpgalink.protocol", "fpgalink.recording")}, where
    assert not names & {"asyncio", "socket", "serial", "threading"}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.cli"))
def test_the_cli_never_imports_the_ros2_node(where: str, path: Path) -> None:
    # Both stand on the robot; a recording in rosbag2 form uses rosbags, not the node.
    assert not {n for n in imports_of(path) if within(n, "fpgalink.ros2", "rclpy")}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.ros2"))
def test_the_ros2_node_stands_on_the_robot_and_below(where: str, path: Path) -> None:
    above = {n for n in first_party(imports_of(path)) if within(n, "fpgalink.cli")}
    assert not above, f"{where} imports {sorted(above)}"


@pytest.mark.parametrize(("where", "path"),
                         [m for package in ("fpgalink.protocol", "fpgalink.connection",
                                            "fpgalink.aio", "fpgalink.robot",
                                            "fpgalink.recording")
                          for m in modules(package)])
def test_only_the_ros2_package_knows_ros(where: str, path: Path) -> None:
    ros = {n for n in imports_of(path)
           if n.split(".")[0] in ("rclpy", "rosbags") or n.endswith("_msgs")
           or n.split(".")[0].endswith("_msgs")}
    assert not ros, f"{where} imports {sorted(ros)}"


@pytest.mark.parametrize("package", ["fpgalink", "fpgalink.protocol", "fpgalink.robot",
                                     "fpgaemu", "fpgaemu.physics"])
def test_every_public_name_of_a_package_resolves(package: str) -> None:
    # The packages load their names on first use: every name listed must be there.
    import importlib

    module = importlib.import_module(package)
    missing = [name for name in module.__all__ if not hasattr(module, name)]
    assert not missing, f"{package} lists {missing} but cannot give them"


@pytest.mark.parametrize(("where", "path"), modules("fpgaemu"))
def test_mujoco_stays_in_the_physics_body_and_loads_when_a_body_is_made(where: str,
                                                                       path: Path) -> None:
    # The physics extra is optional: fpgaemu serve, the surfaces and why_unavailable() work
    # without it, so no module imports MuJoCo at import time, and only the physics body's
    # modules import it at all.
    assert "mujoco" not in runtime_imports(path), where
    if not where.startswith("fpgaemu/physics/"):
        assert not {n for n in imports_of(path) if within(n, "mujoco")}, where


@pytest.mark.parametrize(("where", "path"), [
    m for m in modules("fpgaemu.physics")
    if not m[0].endswith(("physics/__init__.py", "physics/body.py", "physics/render.py"))])
def test_the_physics_bodys_parts_stand_below_the_body(where: str, path: Path) -> None:
    # Surfaces, the model, the drives, the tyres and the IMU are each handed what they
    # need; none reaches back into the body that holds them.
    assert not {n for n in first_party(imports_of(path))
                if n == "fpgaemu.physics" or within(n, "fpgaemu.physics.body")}, where


@pytest.mark.parametrize(("where", "path"), modules("fpgalink.codegen"))
def test_the_code_generator_stands_on_the_protocol_alone(where: str, path: Path) -> None:
    # A tool of fpgalink that reads the one declaration: nothing above the protocol, no I/O
    # but writing its files (pathlib), no clock.
    names = imports_of(path)
    assert not {n for n in first_party(names) if not within(n, "fpgalink.protocol",
                                                             "fpgalink.codegen")}, where
    assert not names & {"asyncio", "time", "socket", "serial", "threading"}, where


@pytest.mark.parametrize(("where", "path"), [*modules("fpgalink"), *modules("fpgaemu")])
def test_only_the_cli_command_imports_the_generator(where: str, path: Path) -> None:
    # The emulator builds the C firmware from the generator's output, running it as a
    # program (fpgaemu/cfirmware.py), never by import; the library does not need it.
    if where.startswith(("fpgalink/codegen/", "fpgalink/cli/codegen.py")):
        return
    assert not {n for n in imports_of(path) if within(n, "fpgalink.codegen")}, where


@pytest.mark.parametrize(("where", "path"), [*modules("fpgalink"), *modules("fpgaemu")])
def test_cffi_stays_in_the_emulators_c_build(where: str, path: Path) -> None:
    if where == "fpgaemu/cbuild.py":
        return
    assert "cffi" not in imports_of(path), where


# --- the connection's parts, the link's parts, import circles, the lazy packages ----------


@pytest.mark.parametrize(("where", "path"), [
    m for m in modules("fpgalink.connection")
    if not m[0].endswith(("connection/core.py", "connection/__init__.py"))])
def test_the_connections_parts_stand_below_its_facade(where: str, path: Path) -> None:
    # Each part has one concern and is handed what it needs: none reaches back into the
    # Connection that holds it.
    names = first_party(imports_of(path))
    assert "fpgalink.connection" not in names and "fpgalink.connection.core" not in names, where


@pytest.mark.parametrize(("where", "path"), [
    m for m in modules("fpgalink.aio") if m[0].endswith(
        ("aio/subscription.py", "aio/fanout.py", "aio/batching.py", "aio/clock.py",
         "aio/backlog.py", "aio/identity.py"))])
def test_the_links_parts_stand_below_the_link(where: str, path: Path) -> None:
    assert not {n for n in first_party(imports_of(path)) if within(n, "fpgalink.aio.link")}, where


def runtime_imports(path: Path) -> set[str]:
    """The modules ``path`` imports when it is imported: at its top level, not under ``if
    TYPE_CHECKING:`` and not inside functions (those import later, when called)."""
    found: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module)
                found.update(f"{node.module}.{alias.name}" for alias in node.names)
            elif isinstance(node, ast.If) and "TYPE_CHECKING" not in ast.unparse(node.test):
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                for block in (node.body, *(h.body for h in node.handlers), node.orelse,
                              node.finalbody):
                    visit(block)

    visit(ast.parse(path.read_text(encoding="utf-8")).body)
    return found


@pytest.mark.parametrize(("where", "path"), [*modules("fpgalink"), *modules("fpgaemu")])
def test_imports_are_absolute(where: str, path: Path) -> None:
    # The rules above and the circle below read absolute imports: a relative one would pass
    # unseen.
    relative = [node.lineno for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                if isinstance(node, ast.ImportFrom) and node.level]
    assert not relative, f"{where}: relative imports on lines {relative}"


def test_no_import_circle() -> None:
    # A module's package runs its __init__ before it, so that edge is no circle; every other
    # import at the top level of a module is (in fpgalink and fpgaemu alike). Imports under
    # ``if TYPE_CHECKING:`` are allowed to close a circle: they never run.
    graph: dict[str, set[str]] = {}
    for package in ("fpgalink", "fpgaemu"):
        for where, path in modules(package):
            name = where.removesuffix(".py").removesuffix("/__init__").replace("/", ".")
            graph[name] = set()
            for imported in first_party(runtime_imports(path)):
                if not name.startswith(imported + "."):
                    graph[name].add(imported)
    for name in graph:
        graph[name] &= graph.keys()
    done: set[str] = set()

    def walk(name: str, trail: list[str]) -> None:
        if name in trail:
            raise AssertionError("import circle: " + " -> ".join([*trail, name]))
        if name in done:
            return
        for imported in sorted(graph[name]):
            walk(imported, [*trail, name])
        done.add(name)

    for name in sorted(graph):
        walk(name, [])


LAZY_PACKAGES = ["fpgalink", "fpgalink.protocol", "fpgalink.robot"]


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_a_lazy_packages_names_agree_three_ways(package: str) -> None:
    # Its table of homes (what it imports at run time), its imports under TYPE_CHECKING
    # (what type checkers see) and __all__ name the same things, each from the same home.
    tree = ast.parse((SRC / package.replace(".", "/") / "__init__.py").read_text())
    homes: dict[str, str] = {}
    typed: dict[str, str] = {}
    listed: set[str] = set()
    own: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            target = node.targets[0].id
            if target == "_HOMES":
                homes = ast.literal_eval(node.value)
            elif target == "__all__":
                listed = set(ast.literal_eval(node.value))
            elif not target.startswith("_") or target.startswith("__"):
                own.add(target)
        elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for statement in node.body:
                assert isinstance(statement, ast.ImportFrom) and statement.module
                typed.update((alias.name, statement.module) for alias in statement.names)
    assert homes == typed
    assert listed == set(homes) | (own & listed) and own & listed <= {"__version__"}
