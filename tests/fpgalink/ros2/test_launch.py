"""The files for a system ROS 2: ``package.xml``, the ament index marker, the ``ros2 run``
wrapper, and the launch file. ROS 2's ``launch``/``launch_ros`` have no wheels on PyPI, so
the launch file runs here against stand-ins that record what it builds (the real
``ament_index_python`` decides whether robot_state_publisher is there); ``ros2 launch``
itself is not run here (docs/ros2.md says so)."""

from __future__ import annotations

import importlib.util
import os
import sys
import tomllib
import types
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[3]
PACKAGE = ROOT / "ros2" / "package"
LAUNCH = PACKAGE / "launch" / "fpgalink.launch.py"


class Recorded:
    """A stand-in for a launch class: keeps what it was built with."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class Configuration(Recorded):
    def perform(self, context: dict[str, str]) -> str:
        return context[self.args[0]]


def stand_ins() -> dict[str, types.ModuleType]:
    modules = {name: types.ModuleType(name) for name in (
        "launch", "launch.actions", "launch.substitutions", "launch_ros",
        "launch_ros.actions")}
    modules["launch"].LaunchDescription = Recorded  # type: ignore[attr-defined]
    modules["launch.actions"].DeclareLaunchArgument = Recorded  # type: ignore[attr-defined]
    modules["launch.actions"].OpaqueFunction = Recorded  # type: ignore[attr-defined]
    modules["launch.substitutions"].LaunchConfiguration = Configuration  # type: ignore[attr-defined]
    modules["launch_ros.actions"].Node = Recorded  # type: ignore[attr-defined]
    return modules


def launched(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, rsp_installed: bool,
             **given: str) -> list[Recorded]:
    """The nodes the launch file starts for ``given`` arguments (the rest at their
    defaults), with robot_state_publisher in the ament index or not."""
    pytest.importorskip("ament_index_python")
    for name, module in stand_ins().items():
        monkeypatch.setitem(sys.modules, name, module)
    prefix = tmp_path / "prefix"
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    if rsp_installed:
        (index / "robot_state_publisher").touch()
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    spec = importlib.util.spec_from_file_location("fpgalink_launch", LAUNCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    entities = description.args[0]
    defaults = {e.kwargs["name"] if "name" in e.kwargs else e.args[0]: e.kwargs["default_value"]
                for e in entities if e.kwargs.get("default_value") is not None}
    opaque = [e for e in entities if "function" in e.kwargs]
    assert len(opaque) == 1
    nodes: list[Recorded] = opaque[0].kwargs["function"]({**defaults, **given})
    return nodes


def test_the_node_alone_publishes_tf_static_itself(monkeypatch: pytest.MonkeyPatch,
                                                   tmp_path: Path) -> None:
    nodes = launched(monkeypatch, tmp_path, rsp_installed=False)
    assert len(nodes) == 1
    node = nodes[0].kwargs
    assert (node["package"], node["executable"], node["name"]) == (
        "fpgalink", "fpgalink-ros2", "fpgalink")
    assert node["arguments"] == []  # fpgalink.toml or the emulated robot, as the command
    assert node["parameters"] == [{"use_sim_time": False, "publish_static_tf": True}]


def test_with_robot_state_publisher_it_gets_the_nodes_urdf(monkeypatch: pytest.MonkeyPatch,
                                                           tmp_path: Path) -> None:
    from fpgalink.protocol.robot import seed_robot
    from fpgalink.protocol.urdf import robot_urdf

    nodes = launched(monkeypatch, tmp_path, rsp_installed=True, namespace="/bot",
                     ports="L=/dev/ttyUSB0 R=/dev/ttyUSB1", use_sim_time="true")
    ours, rsp = (n.kwargs for n in nodes)
    assert ours["arguments"] == ["--port=L=/dev/ttyUSB0", "--port=R=/dev/ttyUSB1"]
    assert ours["namespace"] == rsp["namespace"] == "/bot"
    # robot_state_publisher publishes /tf_static (and the wheels from joint_states): the
    # node does not as well.
    assert ours["parameters"] == [{"use_sim_time": True, "publish_static_tf": False}]
    assert rsp["executable"] == "robot_state_publisher"
    assert rsp["parameters"] == [{"robot_description": robot_urdf(seed_robot()),
                                  "frame_prefix": "bot/", "use_sim_time": True}]
    # Asked not to start it: not started.
    nodes = launched(monkeypatch, tmp_path / "again", rsp_installed=True,
                     robot_state_publisher="false")
    assert len(nodes) == 1


def test_package_xml_index_marker_and_run_wrapper_ship_in_the_wheel() -> None:
    root = ET.parse(PACKAGE / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "fpgalink"
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert root.findtext("version") == project["project"]["version"]
    shared = project["tool"]["hatch"]["build"]["targets"]["wheel"]["shared-data"]
    assert shared == {
        "ros2/package/package.xml": "share/fpgalink/package.xml",
        "ros2/package/launch/fpgalink.launch.py": "share/fpgalink/launch/fpgalink.launch.py",
        "ros2/package/resource/fpgalink": "share/ament_index/resource_index/packages/fpgalink",
        "ros2/package/fpgalink-ros2": "lib/fpgalink/fpgalink-ros2",
    }
    for source in shared:
        assert (ROOT / source).is_file(), source
    assert os.access(PACKAGE / "fpgalink-ros2", os.X_OK)
