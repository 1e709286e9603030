"""Generate tf2_msgs (TFMessage, for /tf and /tf_static) into this Python's prefix.

ROS 2 Jazzy's tf2_msgs has no PyPI wheel, but the rosidl generators and the ament CMake
machinery do: CMake and the system C compiler build ros2/tf2_msgs with them (about 10 s)
and install it beside the other message wheels (``sys.prefix``: lib/, share/,
site-packages). The result is checked before it is kept: its type hash must be Jazzy's
(``EXPECTED_HASH``, the same as rosbags' Jazzy store), and it must import and serialise.

    python ros2/build_tf2_msgs.py        (run by ``make tf2-msgs``, part of ``make test``)

Exit 0 when tf2_msgs is installed and checked; 1 with the reason otherwise.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "tf2_msgs"
BUILD = HERE.parent / "build" / "tf2_msgs"
TYPE = "tf2_msgs/msg/TFMessage"
#: tf2_msgs/msg/TFMessage in ROS 2 Jazzy (REP-2011 type hash).
EXPECTED_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


def main() -> int:
    prefix = Path(sys.prefix)
    for tool in ("cmake", "cc"):
        if shutil.which(tool) is None:
            print(f"build_tf2_msgs: {tool} not found (make tf2-msgs installs it)",
                  file=sys.stderr)
            return 1
    shutil.rmtree(BUILD, ignore_errors=True)
    configure = ["cmake", "-S", str(SOURCE), "-B", str(BUILD), f"-DCMAKE_PREFIX_PATH={prefix}",
                 f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DPython3_EXECUTABLE={sys.executable}",
                 "-DBUILD_TESTING=OFF", "-DCMAKE_BUILD_TYPE=Release"]
    for step in (configure, ["cmake", "--build", str(BUILD), "-j", str(os.cpu_count() or 1)],
                 ["cmake", "--install", str(BUILD)]):
        done = subprocess.run(step, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(done.stdout[-4000:] + done.stderr[-4000:], file=sys.stderr)
            print(f"build_tf2_msgs: {' '.join(step[:2])} failed (exit {done.returncode})",
                  file=sys.stderr)
            return 1
    description = prefix / "share" / "tf2_msgs" / "msg" / "TFMessage.json"
    hashes = {entry["type_name"]: entry["hash_string"]
              for entry in json.loads(description.read_text())["type_hashes"]}
    if hashes.get(TYPE) != EXPECTED_HASH:
        _remove(prefix)
        print(f"build_tf2_msgs: {TYPE} generated with hash {hashes.get(TYPE)}, Jazzy's is "
              f"{EXPECTED_HASH}: not kept", file=sys.stderr)
        return 1
    # Import and round-trip one message, in a fresh interpreter (the ROS wheels set their
    # library path as Python starts).
    check = ("from geometry_msgs.msg import TransformStamped\n"
             "from rclpy.serialization import serialize_message, deserialize_message\n"
             "from tf2_msgs.msg import TFMessage\n"
             "m = TFMessage(transforms=[TransformStamped(child_frame_id='base_link')])\n"
             "assert deserialize_message(serialize_message(m), TFMessage) == m\n")
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True,
                          check=False)
    if done.returncode != 0:
        _remove(prefix)
        print(done.stderr[-2000:], file=sys.stderr)
        print("build_tf2_msgs: the generated tf2_msgs does not work: not kept",
              file=sys.stderr)
        return 1
    print(f"build_tf2_msgs: {TYPE} {EXPECTED_HASH[:15]}… installed in {prefix}")
    return 0


def _remove(prefix: Path) -> None:
    """Take out what the install put in (its manifest lists every file)."""
    manifest = BUILD / "install_manifest.txt"
    if manifest.exists():
        for line in manifest.read_text().splitlines():
            Path(line).unlink(missing_ok=True)
    shutil.rmtree(Path(sysconfig.get_paths()["purelib"]) / "tf2_msgs", ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
