"""Generate tf2_msgs (TFMessage, for /tf and /tf_static) into this Python's environment.

ROS 2 Jazzy's tf2_msgs has no PyPI wheel, but the rosidl generators and the ament CMake
machinery do: this installs those (pinned, ``tf2_msgs_source/requirements.txt``), builds
the package's ``tf2_msgs_source`` with CMake and the system C compiler (about 10 s) and
installs it beside the other message wheels (``sys.prefix``: lib/, share/, site-packages).
The result is checked before it is kept: its type hash must be Jazzy's (``EXPECTED_HASH``,
the same as rosbags' Jazzy store), and it must import and serialise. No checkout needed:

    fpgalink-ros2 --install-tf2          (a pip user, after pip install 'fpgalink[ros2]')
    python -m fpgalink.ros2.tf2build     (the same; ``make tf2-msgs`` runs it, its
                                          requirements installed with the checkout's pins)

Exit 0 when tf2_msgs is installed and checked; 8 when cmake or a C compiler is missing
(the message says which Debian package); 1 with the reason otherwise. ``--check`` only
checks what is installed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from importlib import resources
from pathlib import Path

from fpgalink.protocol.exitcodes import ExitCode

__all__ = ["EXPECTED_HASH", "check_installed", "install", "main"]

TYPE = "tf2_msgs/msg/TFMessage"
#: tf2_msgs/msg/TFMessage in ROS 2 Jazzy (REP-2011 type hash).
EXPECTED_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
PROG = "fpgalink-ros2 --install-tf2"
#: The tools the build runs, and the Debian package of each.
TOOLS = {"cmake": "cmake", "cc": "gcc"}
#: Import and round-trip one message, in a fresh interpreter (the ROS wheels set their
#: library path as Python starts).
CHECK = ("from geometry_msgs.msg import TransformStamped\n"
         "from rclpy.serialization import serialize_message, deserialize_message\n"
         "from tf2_msgs.msg import TFMessage\n"
         "m = TFMessage(transforms=[TransformStamped(child_frame_id='base_link')])\n"
         "assert deserialize_message(serialize_message(m), TFMessage) == m\n")


def _say(text: str) -> None:
    print(f"{PROG}: {text}", file=sys.stderr, flush=True)


def check_installed(prefix: Path) -> str | None:
    """Why the tf2_msgs installed under ``prefix`` is not Jazzy's working one (``None``:
    it is)."""
    description = prefix / "share" / "tf2_msgs" / "msg" / "TFMessage.json"
    try:
        hashes = {entry["type_name"]: entry["hash_string"]
                  for entry in json.loads(description.read_text())["type_hashes"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"no usable {description}: {exc}"
    if hashes.get(TYPE) != EXPECTED_HASH:
        return f"{TYPE} has hash {hashes.get(TYPE)}, Jazzy's is {EXPECTED_HASH}"
    done = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True,
                          check=False)
    if done.returncode != 0:
        return f"it does not import and serialise: {done.stderr.strip()[-500:]}"
    return None


def install(requirements: bool = True) -> int:
    """Build and install tf2_msgs into ``sys.prefix``; the exit code."""
    prefix = Path(sys.prefix)
    missing = [f"{tool} (Debian: apt install {package})" for tool, package in TOOLS.items()
               if shutil.which(tool) is None]
    if missing:
        _say(f"needs {' and '.join(missing)}")
        return ExitCode.NOT_INSTALLED
    source = resources.files("fpgalink.ros2") / "tf2_msgs_source"
    with resources.as_file(source) as tree, tempfile.TemporaryDirectory(
            prefix="fpgalink-tf2-msgs-") as scratch:
        if requirements:
            pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "-r",
                                  str(tree / "requirements.txt")], check=False)
            if pip.returncode != 0:
                _say("could not install the build's requirements (above)")
                return ExitCode.FAILURE
        build = Path(scratch) / "build"
        configure = ["cmake", "-S", str(tree), "-B", str(build),
                     f"-DCMAKE_PREFIX_PATH={prefix}", f"-DCMAKE_INSTALL_PREFIX={prefix}",
                     f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF",
                     "-DCMAKE_BUILD_TYPE=Release"]
        for step in (configure, ["cmake", "--build", str(build), "-j",
                                 str(os.cpu_count() or 1)],
                     ["cmake", "--install", str(build)]):
            done = subprocess.run(step, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                print(done.stdout[-4000:] + done.stderr[-4000:], file=sys.stderr)
                _say(f"{' '.join(step[:2])} failed (exit {done.returncode})")
                return ExitCode.FAILURE
        why = check_installed(prefix)
        if why is not None:
            _remove(prefix, build)
            _say(f"{why}: not kept")
            return ExitCode.FAILURE
    _say(f"{TYPE} {EXPECTED_HASH[:15]}… installed in {prefix}; the node publishes /tf")
    return ExitCode.OK


def _remove(prefix: Path, build: Path) -> None:
    """Take out what the install put in (its manifest lists every file)."""
    manifest = build / "install_manifest.txt"
    if manifest.exists():
        for line in manifest.read_text().splitlines():
            Path(line).unlink(missing_ok=True)
    shutil.rmtree(Path(sysconfig.get_paths()["purelib"]) / "tf2_msgs", ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fpgalink.ros2.tf2build",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="check the tf2_msgs installed here; build nothing")
    parser.add_argument("--no-requirements", action="store_true",
                        help="the build's requirements are installed already")
    args = parser.parse_args(argv)
    if args.check:
        why = check_installed(Path(sys.prefix))
        _say(why or f"{TYPE} installed in {sys.prefix} is Jazzy's")
        return ExitCode.FAILURE if why else ExitCode.OK
    return install(requirements=not args.no_requirements)


if __name__ == "__main__":
    sys.exit(main())
