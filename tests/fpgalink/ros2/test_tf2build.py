"""41.8: a pip user gets /tf without a checkout: ``fpgalink-ros2 --install-tf2`` builds
tf2_msgs from sources that ship inside the package (fpgalink.ros2.tf2build)."""

from __future__ import annotations

import importlib.util
from importlib import resources

import pytest

from fpgalink.protocol.exitcodes import ExitCode
from tests.support.scripts import script, script_env


def test_the_sources_ship_in_the_package() -> None:
    source = resources.files("fpgalink.ros2") / "tf2_msgs_source"
    for name in ("CMakeLists.txt", "package.xml", "requirements.txt"):
        assert (source / name).is_file(), name
    pins = [line for line in (source / "requirements.txt").read_text().splitlines()
            if line and not line.startswith("#")]
    assert pins and all("==" in line for line in pins)  # pinned: reproducible


@pytest.mark.skipif(importlib.util.find_spec("rclpy") is None, reason="needs the ros2 extra")
def test_without_cmake_or_a_compiler_it_says_what_to_install() -> None:
    env = script_env()
    env["PATH"] = "/nonexistent"
    done = script("fpgalink-ros2", "--install-tf2", env=env)
    assert done.returncode == ExitCode.NOT_INSTALLED, done.stderr
    assert "apt install cmake" in done.stderr and "apt install gcc" in done.stderr


@pytest.mark.skipif(importlib.util.find_spec("tf2_msgs") is None,
                    reason="tf2_msgs is not generated here")
def test_the_installed_tf2_msgs_is_checked_as_jazzys() -> None:
    done = script("python", "-m", "fpgalink.ros2.tf2build", "--check", timeout=60)
    assert done.returncode == 0, done.stderr
    assert "is Jazzy's" in done.stderr


def test_help_offers_it() -> None:
    done = script("fpgalink-ros2", "--help")
    assert done.returncode == 0
    assert "--install-tf2" in done.stdout
