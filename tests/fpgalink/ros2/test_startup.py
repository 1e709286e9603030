"""Where ``fpgalink-ros2`` finds its boards: the command line, then the environment, then
``fpgalink.toml`` — the CLI's order (fpgalink.cli.settings) — else the emulated robot.
The resolution needs no ROS; one run of the console script (in tests/ros2/netns.sh, as
everything that may start DDS) shows the node using a config file's ports."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import pytest

from fpgalink.config import ConfigError
from fpgalink.ros2.__main__ import _parser, resolve

ROOT = Path(__file__).resolve().parents[3]
NETNS = ROOT / "tests" / "ros2" / "netns.sh"


@pytest.fixture(autouse=True)
def nowhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory and a user config directory of the test's own, no variables."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    for name in ("FPGALINK_CONFIG", "FPGALINK_PORT", "FPGALINK_BAUD", "FPGALINK_WIRE_CRC"):
        monkeypatch.delenv(name, raising=False)
    return tmp_path


def startup(*args: str) -> tuple[dict[str, str], int, str | None, dict[str, str]]:
    found = resolve(_parser().parse_args(list(args)))
    return found.ports, found.baud, found.robot, found.sources


def test_nothing_anywhere_is_the_emulated_robot() -> None:
    ports, baud, robot, sources = startup()
    assert ports == {} and baud == 1_000_000 and robot is None
    assert sources == {"port": "default", "baud": "default", "wire_crc": "default",
                       "robot": "default"}
    assert resolve(_parser().parse_args([])).wire_crc is False


def test_the_wire_crc_from_the_option_the_environment_or_the_file(
        nowhere: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """As the CLI takes it: ``--wire-crc``, then ``FPGALINK_WIRE_CRC``, then the file's
    ``wire_crc`` (the robot's links were opened without it whatever was asked)."""
    (nowhere / "fpgalink.toml").write_text("wire_crc = true\n", encoding="utf-8")
    found = resolve(_parser().parse_args([]))
    assert found.wire_crc is True
    assert found.sources["wire_crc"] == f"config file {nowhere / 'fpgalink.toml'}"
    monkeypatch.setenv("FPGALINK_WIRE_CRC", "0")
    assert resolve(_parser().parse_args([])).wire_crc is False
    assert resolve(_parser().parse_args(["--wire-crc"])).wire_crc is True
    monkeypatch.setenv("FPGALINK_WIRE_CRC", "yes")
    with pytest.raises(ConfigError, match="FPGALINK_WIRE_CRC: 'yes' is not 0 or 1"):
        resolve(_parser().parse_args([]))
    monkeypatch.delenv("FPGALINK_WIRE_CRC")
    (nowhere / "fpgalink.toml").write_text('wire_crc = "on"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="wire_crc must be true or false, got 'on'"):
        resolve(_parser().parse_args([]))


def test_the_config_files_ports_baud_and_robot_are_used(nowhere: Path) -> None:
    (nowhere / "fpgalink.toml").write_text(
        'baud = 2000000\nrobot = "robots/sap.toml"\n'
        '[ports]\nL = "/dev/ttyUSB0"\nR = "socket://127.0.0.1:7001"\n', encoding="utf-8")
    ports, baud, robot, sources = startup()
    assert ports == {"L": "/dev/ttyUSB0", "R": "socket://127.0.0.1:7001"}
    assert baud == 2_000_000
    # Relative to the file, as the CLI takes it.
    assert robot == str(nowhere / "robots" / "sap.toml")
    assert sources["port"] == sources["baud"] == sources["robot"] == \
        f"config file {nowhere / 'fpgalink.toml'}"


def test_an_explicit_port_wins_over_the_environment_and_the_file(
        nowhere: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (nowhere / "fpgalink.toml").write_text('[ports]\nL = "/dev/a"\nR = "/dev/b"\n',
                                           encoding="utf-8")
    monkeypatch.setenv("FPGALINK_PORT", "L=/dev/env-a R=/dev/env-b")
    monkeypatch.setenv("FPGALINK_BAUD", "500000")
    ports, baud, _, sources = startup()
    assert ports == {"L": "/dev/env-a", "R": "/dev/env-b"} and baud == 500_000
    assert sources["port"] == "environment FPGALINK_PORT"
    ports, baud, _, sources = startup("--port", "L=emu://robot/L", "--port", "R=emu://robot/R",
                                      "--baud", "115200")
    assert ports == {"L": "emu://robot/L", "R": "emu://robot/R"} and baud == 115_200
    assert sources["port"] == sources["baud"] == "command line"


def test_config_names_a_file_and_the_user_directory_is_searched(nowhere: Path) -> None:
    (nowhere / "xdg" / "fpgalink").mkdir(parents=True)
    (nowhere / "xdg" / "fpgalink" / "fpgalink.toml").write_text(
        '[ports]\nL = "/dev/user-a"\nR = "/dev/user-b"\n', encoding="utf-8")
    assert startup()[0] == {"L": "/dev/user-a", "R": "/dev/user-b"}
    (nowhere / "other.toml").write_text('[ports]\nL = "/dev/o-a"\nR = "/dev/o-b"\n',
                                        encoding="utf-8")
    assert startup("--config", "other.toml")[0] == {"L": "/dev/o-a", "R": "/dev/o-b"}


@pytest.mark.parametrize(("text", "says"), [
    ('prot = "/dev/x"\n', "unknown key 'prot'"),
    ('port = "/dev/x"\n[ports]\nL = "/dev/y"\n', "give port or [ports], not both"),
    ("baud = 12\n", "baud must be a whole number"),
    ("[ports\n", "fpgalink.toml"),
])
def test_a_config_file_that_cannot_be_used_says_why(nowhere: Path, text: str,
                                                    says: str) -> None:
    (nowhere / "fpgalink.toml").write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=says.replace("[", r"\[")):
        startup()


def _node_env() -> dict[str, str]:
    """A node started from this checkout, finding its peers on this host only."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
                ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


def _foreground() -> None:
    """A child as a shell starts it in the foreground: SIGINT neither ignored nor blocked,
    whatever this test process inherited or was left with by the tests before it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _why_no_console_run() -> str | None:
    if importlib.util.find_spec("rclpy") is None:
        return "rclpy is not installed"
    probe = subprocess.run([str(NETNS), "true"], capture_output=True, text=True, check=False)
    return None if probe.returncode == 0 else f"no network namespace: {probe.stderr.strip()}"


def test_the_node_opens_the_config_files_ports(nowhere: Path) -> None:
    missing = _why_no_console_run()
    if missing is not None:
        pytest.skip(missing)
    (nowhere / "fpgalink.toml").write_text(
        '[ports]\nL = "/dev/fpgalink-test-no-such-L"\nR = "/dev/fpgalink-test-no-such-R"\n',
        encoding="utf-8")
    env = _node_env()
    done = subprocess.run([str(NETNS), sys.executable, "-m", "fpgalink.ros2"], cwd=nowhere,
                          env=env, capture_output=True, text=True, timeout=120, check=False)
    # Those ports, not the emulated robot: they do not exist, so exit 5 (port missing).
    assert done.returncode == 5, done
    assert "/dev/fpgalink-test-no-such-L" in done.stderr, done.stderr


@pytest.mark.timeout(240)
def test_a_ctrl_c_while_the_node_loads_is_one_line_not_a_traceback(nowhere: Path) -> None:
    """SIGINT before the event loop's handler is in place (rclpy, the robot and DDS load for
    seconds): ``interrupted``, exit 130; or, where it landed after, the clean stop (0). The
    signal is sent as main begins, so it lands at some point of the loading; never a
    traceback."""
    missing = _why_no_console_run()
    if missing is not None:
        pytest.skip(missing)
    env = _node_env()
    # As the console script's entry point: its module imported (light: the heavy imports are
    # main's), then main. The line is said as main's body begins (a profile hook), so the
    # signal lands in what main guards, at some point of the loading.
    code = textwrap.dedent("""
        import faulthandler, signal, sys
        # A node that does not end: where each thread waits, said on SIGUSR1 (below).
        faulthandler.register(signal.SIGUSR1, all_threads=True)
        from fpgalink.ros2.__main__ import main
        def said(frame, event, arg):
            if event == "call" and frame.f_code.co_name == "_main":
                sys.setprofile(None)
                print("python up", file=sys.stderr, flush=True)
        sys.argv[0] = "fpgalink-ros2"
        sys.setprofile(said)
        main()
    """)
    node = subprocess.Popen([str(NETNS), sys.executable, "-c", code], cwd=nowhere, env=env,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_foreground)
    assert node.stderr is not None
    first = node.stderr.readline()
    assert first == "python up\n", first
    node.send_signal(signal.SIGINT)
    try:
        _, said = node.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        node.send_signal(signal.SIGUSR1)
        try:
            _, said = node.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
            _, said = node.communicate()
        mine = (signal.getsignal(signal.SIGINT),
                signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, set()))
        raise AssertionError(f"the node did not end on SIGINT (this test's process: SIGINT "
                             f"{mine[0]!r}, blocked {mine[1]}): {said[-6000:]}") from None
    assert "Traceback" not in said, said[-3000:]
    assert node.returncode in (0, 130), (node.returncode, said[-3000:])
    if node.returncode == 130:
        assert said.strip().splitlines()[-1] == "fpgalink-ros2: interrupted", said[-3000:]


def _blocked() -> None:
    """A child started with SIGINT blocked, as a thread that blocked it for a while (a
    campaign starting its pool's workers does) would start it."""
    _foreground()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


@pytest.mark.parametrize("started", [_foreground, _blocked], ids=["foreground", "blocked"])
def test_an_import_a_ctrl_c_cut_short_reads_as_the_interrupt_not_as_ros2_missing(
        started: Callable[[], None]) -> None:
    """A SIGINT inside rclpy's C extension's initialisation comes out of the import as an
    ``ImportError`` (seen 2 times in 60 imports interrupted at random points), with no
    KeyboardInterrupt in its chain: the node must say ``interrupted`` (exit 130), not that
    ROS 2 is missing (exit 8, the install hint). Here the import is stood in for: the
    signal arrives, and the check of ROS 2's packages answers what such an import gives."""
    env = _node_env()
    code = textwrap.dedent("""
        import os, signal, sys, time
        import fpgalink.ros2.__main__ as node
        def interrupted_import():
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)
            except KeyboardInterrupt:
                return False  # caught as the ImportError an interrupted extension gives
            os._exit(3)  # the signal never came: end here, before ROS 2 (and DDS) would load
        node.available = interrupted_import
        sys.argv[0] = "fpgalink-ros2"
        node.main()
    """)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60, check=False, preexec_fn=started)
    assert done.returncode == 130, done
    assert done.stderr.strip().splitlines() == ["fpgalink-ros2: interrupted"], done.stderr


def test_a_ctrl_c_as_the_nodes_event_loop_begins_ends_it_whatever_takes_the_cancel(
        nowhere: Path) -> None:
    """SIGINT after ROS 2 is loaded but before the node's own handler is in place (its event
    loop's first step): the node ends, ``interrupted``, 130. It is not left to asyncio.run's
    handler, which only cancels the node's task: here the task takes each cancellation for
    its own and goes on, as a start that swallowed it would, and the node would run until
    the end of its work (0) instead of stopping."""
    missing = _why_no_console_run()
    if missing is not None:
        pytest.skip(missing)
    env = _node_env()
    code = textwrap.dedent("""
        import asyncio, os, signal, sys
        import fpgalink.ros2.__main__ as node
        async def takes_the_cancel(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(30):
                try:
                    await asyncio.sleep(0.1)
                except asyncio.CancelledError:
                    pass
            return 0
        node._run = takes_the_cancel
        sys.argv[0] = "fpgalink-ros2"
        node.main()
    """)
    done = subprocess.run([str(NETNS), sys.executable, "-c", code], cwd=nowhere, env=env,
                          capture_output=True, text=True, timeout=120, check=False,
                          preexec_fn=_foreground)
    assert done.returncode == 130, done
    assert done.stderr.strip().splitlines()[-1] == "fpgalink-ros2: interrupted", done.stderr
