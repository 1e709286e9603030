"""The live view for Foxglove, at the protocol level: a client speaking Foxglove's WebSocket
protocol (tests/support/foxglove.py) subscribes to every channel of a command's live view
while the robot drives on the emulator and decodes each; a client that stops reading is let
go with the command's memory flat; the emulator's own view of the truth."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import re
import select
import socket
import struct
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from fpgalink.live.clients import Connection, StallJudge, parse_proc_net_tcp
from fpgalink.protocol.exitcodes import ExitCode
from tests.support.flood import rss_kb
from tests.support.foxglove import Received, watch
from tests.support.scripts import BIN, script, script_env, start_script, without
from tests.support.serving import served

pytest.importorskip("foxglove")

URL = re.compile(r"live view for Foxglove on (ws://[^ ]+)")
BOARD_TOPICS = {f"/board/{b}/{t}" for b in "LR"
                for t in ("telemetry", "params", "parameters", "events", "stats")}
ROBOT_TOPICS = {"/robot/odometry", "/robot/truth", "/robot/pose", "/robot/truth_pose",
                "/robot/path", "/robot/truth_path", "/tf", "/robot_description",
                "/robot/command", "/robot/supervision", "/robot/health"}


def _live_url(proc: subprocess.Popen[str], timeout: float = 30) -> str:
    """The URL the command says its live view is on (stderr)."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stderr], [], [], 0.2)
        if ready:
            line = proc.stderr.readline()
            found = URL.search(line)
            if found:
                return found.group(1)
            if not line and proc.poll() is not None:
                break
    proc.kill()
    raise AssertionError(f"no live view line: {proc.communicate(timeout=5)}")


def _drive(*args: str) -> subprocess.Popen[str]:
    return start_script("fpgalink-cli", "drive", "--v", "0.2", "--omega", "10", *args,
                        "--foxglove", "0")


def _check_every_channel(got: Received) -> None:
    assert got.server_info["op"] == "serverInfo"
    assert got.topics() >= BOARD_TOPICS | ROBOT_TOPICS, got.topics()
    for channel in got.channels.values():
        assert channel["encoding"] == "json", channel
        assert channel["schemaEncoding"] == "jsonschema", channel
        json.loads(channel["schema"])  # a JSON Schema, as advertised
    names = {c["topic"]: c["schemaName"] for c in got.channels.values()}
    assert names["/robot/pose"] == "foxglove.PoseInFrame"
    assert names["/robot/path"] == "foxglove.PosesInFrame"
    assert names["/tf"] == "foxglove.FrameTransforms"
    assert names["/board/L/events"] == "foxglove.Log"
    assert names["/robot_description"] == "std_msgs/msg/String"
    for topic in (BOARD_TOPICS | ROBOT_TOPICS) - {"/board/L/events", "/board/R/events",
                                                "/board/L/params", "/board/R/params",
                                                "/robot/supervision"}:
        assert got.messages[topic], f"nothing decoded on {topic}"
    for board in "LR":
        samples = [m for _, m in got.messages[f"/board/{board}/telemetry"]]
        assert len(samples) > 100
        counters = [s["counter"] for s in samples]
        assert counters == sorted(counters) or max(counters) > 60000  # in order (or wrapped)
        assert all(isinstance(s["a_speed"], int | float) for s in samples)
        stats = got.latest(f"/board/{board}/stats")
        assert stats["telemetry_rate"] > 0 and stats["lost"] == 0
        assert "Kp_Wheel_PidA" in got.latest(f"/board/{board}/parameters")
    pose = got.latest("/robot/pose")
    assert pose["frame_id"] == "odom" and pose["pose"]["position"]["x"] > 0
    frames = {t["child_frame_id"] for t in got.latest("/tf")["transforms"]}
    assert frames == {"base_link", "FL_link", "BL_link", "FR_link", "BR_link"}
    assert "<robot" in got.latest("/robot_description")["data"]
    truth, odometry = got.latest("/robot/truth"), got.latest("/robot/odometry")
    assert abs(truth["x"] - odometry["x"]) < 0.2  # one frame: the start pose
    assert got.latest("/robot/command")["v"] == pytest.approx(0.2)
    statuses = got.latest("/robot/health")["statuses"]
    assert {s["name"] for s in statuses} >= {"board L", "board R", "supervision"}


def test_every_channel_decodes_while_the_robot_drives() -> None:
    proc = _drive("--for", "8")
    try:
        got = asyncio.run(watch(_live_url(proc), 4.0))
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    _check_every_channel(got)
    assert "live view: 1 client(s)" in err


def test_a_fault_reaches_the_log_channels() -> None:
    """A board restart: its link's event and supervision's stop, as foxglove.Log, once each."""
    # The log channels keep their last messages for a client that subscribes later
    # (fpgalink.live.latch, tests/fpgalink/live/test_latch.py): however late this client
    # subscribes (beside two busy loops one did after the restart, 6 s into the boards'
    # time, and saw nothing), it is sent the restart's messages, each once.
    fault = "fault=L:restart=6"
    proc = _drive("--for", "10", "--port", f"L=emu://robot/L?{fault}",
                  "--port", f"R=emu://robot/R?{fault}")
    try:
        # Watched until the command ends (its view closes): the restart comes 6 s into the
        # boards' own time, which a loaded machine stretches well past that of this one's.
        got = asyncio.run(watch(_live_url(proc), 120.0))
    finally:
        _, err = proc.communicate(timeout=60)
    assert got.closed and proc.returncode == ExitCode.STOPPED, err
    stops = [m for _, m in got.messages["/robot/supervision"] if m["level"] == 4]
    assert len([m for m in stops if "restarted" in m["message"]]) == 1, stops
    events = [m["message"] for _, m in got.messages["/board/L/events"]]
    assert len([e for e in events if e.startswith("board_restarted")]) == 1, events


def _ws_frame(text: str) -> bytes:
    """A client's text frame (masked, as a client must)."""
    data = text.encode()
    mask = os.urandom(4)
    head = bytes([0x81]) + (bytes([0x80 | len(data)]) if len(data) < 126
                            else bytes([0x80 | 126]) + struct.pack(">H", len(data)))
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data))


def _read_text_frames(sock: socket.socket, wanted: str, timeout: float) -> list[dict[str, Any]]:
    """Server frames (unmasked) until a text frame with op ``wanted``."""
    buffer = b""
    found: list[dict[str, Any]] = []
    deadline = time.monotonic() + timeout
    sock.settimeout(0.5)
    while time.monotonic() < deadline:
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            continue
        assert chunk, "the server closed"
        buffer += chunk
        while len(buffer) >= 2:
            length, at = buffer[1] & 0x7F, 2
            if length == 126:
                length, at = struct.unpack_from(">H", buffer, 2)[0], 4
            elif length == 127:
                length, at = struct.unpack_from(">Q", buffer, 2)[0], 10
            if len(buffer) < at + length:
                break
            text = buffer[0] & 0x0F == 0x1
            payload, buffer = buffer[at:at + length], buffer[at + length:]
            if not text:
                continue
            try:
                message = json.loads(payload)
            except (ValueError, UnicodeDecodeError):
                continue
            found.append(message)
            if message.get("op") == wanted:
                return found
    raise AssertionError(f"no {wanted} frame")


def _stalled_client(url: str) -> socket.socket:
    """A client that subscribes to every channel, then never reads again."""
    host, port = url.removeprefix("ws://").rsplit(":", 1)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((host, int(port)))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET / HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                  "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
                  ).encode())
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)
    assert response.startswith(b"HTTP/1.1 101"), response
    frames = _read_text_frames(sock, "advertise", 10)
    advertised = [c for f in frames if f.get("op") == "advertise" for c in f["channels"]]
    sock.sendall(_ws_frame(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": c["id"], "channelId": c["id"]} for c in advertised]})))
    return sock


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="the stall watch is Linux's")
@pytest.mark.timeout(180)
def test_a_client_that_stops_reading_is_let_go_with_memory_flat() -> None:
    proc = _drive("--for", "40")
    client = None
    try:
        url = _live_url(proc)
        client = _stalled_client(url)
        rss: list[tuple[float, int]] = []
        let_go_at = None
        lines: list[str] = []
        assert proc.stderr is not None
        fd = proc.stderr.fileno()
        os.set_blocking(fd, False)
        while proc.poll() is None:
            try:
                rss.append((time.monotonic(), rss_kb(proc.pid)))
            except ProcessLookupError:
                break  # it ended between the poll and the reading
            with contextlib.suppress(BlockingIOError):
                lines += os.read(fd, 65536).decode(errors="replace").splitlines()
            if let_go_at is None and any("let go of the Foxglove client" in x for x in lines):
                let_go_at = time.monotonic()
            time.sleep(0.5)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        if client is not None:
            client.close()
    err = "\n".join(lines) + (err or "")
    assert proc.returncode == 0, err
    assert let_go_at is not None, err
    assert "1 let go for not reading" in err
    # Memory flat from the moment it was let go: what waited for it was bounded and freed.
    after = [k for t, k in rss if t >= let_go_at + 2]
    assert len(after) >= 20, "run long enough after the drop to see it"
    assert max(after) - min(after) < 8 * 1024, after
    # And bounded before: the backlog (messages), not everything published.
    assert max(k for _, k in rss) - rss[0][1] < 64 * 1024


def test_the_stall_judge_waits_for_bytes_standing_still() -> None:
    judge = StallJudge(stall_s=5)
    moving = [Connection(1, "a", 100)]
    assert judge.stalled(moving, 0) == []
    assert judge.stalled([Connection(1, "a", 900)], 3) == []  # it moved: still reading
    assert judge.stalled([Connection(1, "a", 900)], 7) == []  # 4 s still
    assert judge.stalled([Connection(1, "a", 900)], 8.5) == [Connection(1, "a", 900)]
    assert judge.stalled([Connection(2, "b", 0)], 100) == []  # nothing waiting: idle


def test_proc_net_tcp_is_read_for_the_servers_port() -> None:
    table = (
        "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  "
        "timeout inode\n"
        "   0: 0100007F:1F90 00000000:0000 0A 00000000:00000000 00:00000000 00000000     0  "
        "      0 111 1\n"
        "   1: 0100007F:1F90 0100007F:D431 01 0001A000:00000000 00:00000000 00000000     0  "
        "      0 222 1\n"
        "   2: 0100007F:D431 0100007F:1F90 01 00000000:00000000 00:00000000 00000000     0  "
        "      0 333 1\n")
    assert parse_proc_net_tcp(table, 0x1F90) == [Connection(222, "127.0.0.1:54321", 0x1A000)]


def test_the_address_is_loopback_unless_given_and_checked() -> None:
    assert script("fpgalink-cli", "drive", "--foxglove", "70000").returncode == 2
    assert script("fpgalink-cli", "drive", "--foxglove", "x:y").returncode == 2


def test_without_foxglove_sdk_it_says_how_to_install(tmp_path: Path) -> None:
    env = without(tmp_path, "foxglove")
    for args in (["fpgalink-cli", "drive", "--foxglove", "0"],
                 ["fpgalink-cli", "monitor", "--foxglove", "0"],
                 ["fpgaemu", "serve", "--robot", "--pty", "--foxglove", "0"]):
        done = script(*args, env=env)
        assert done.returncode == ExitCode.NOT_INSTALLED, (args, done.stderr)
        assert "pip install 'fpgalink[foxglove]'" in done.stderr


def test_step_and_monitor_stream_their_board() -> None:
    proc = start_script("fpgalink-cli", "monitor", "--duration", "6", "--format", "csv",
                        "--foxglove", "0", stdout=subprocess.DEVNULL)
    try:
        got = asyncio.run(watch(_live_url(proc), 3.0))
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert {"/board/0/telemetry", "/board/0/stats"} <= got.topics()
    assert len(got.messages["/board/0/telemetry"]) > 100


def test_identify_streams_the_board_it_excites() -> None:
    # Issue 41: --foxglove on identify (it had none): the board's telemetry live while the
    # wheel is excited, its duty changing as the sequence steps.
    proc = start_script("fpgalink-cli", "identify", "-c", "A", "--wheels", "air",
                        "--max-duty", "50", "--duration", "6", "--port", "emu://",
                        "--format", "json", "--foxglove", "0", stdout=subprocess.DEVNULL)
    try:
        got = asyncio.run(watch(_live_url(proc), 4.0))
    finally:
        _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert {"/board/0/telemetry", "/board/0/stats"} <= got.topics()
    duties = {row["a_pwm"] for _, row in got.messages["/board/0/telemetry"]}
    assert len(duties) > 1, duties


def test_serve_robot_streams_the_true_body(tmp_path: Path) -> None:
    with served("--robot", "--body", "kinematic", "--pty", "--link", f"L={tmp_path / 'L'}",
                "--link", f"R={tmp_path / 'R'}", "--foxglove", "0",
                command=(str(BIN / "fpgaemu"),), env=script_env()) as serve:
        assert serve.foxglove is not None
        # A host drives the body 0.3 m/s for 2 s; the emulator's view shows where it went.
        drive = script("fpgalink-cli", "drive", "--v", "0.3", "--for", "2", "--port",
                       f"L={serve.ready['L']}", "--port", f"R={serve.ready['R']}", timeout=120)
        got = asyncio.run(watch(serve.foxglove, 3.0))
    assert {"/emulator/truth", "/emulator/pose", "/emulator/path", "/tf",
            "/robot_description"} <= got.topics()
    assert drive.returncode in (0, 7), drive.stderr  # 7: a loaded machine's own stall
    moved = got.latest("/emulator/truth")
    assert moved["x"] > 0.05, moved  # the body moved, as the emulator sees it
    assert len(got.latest("/emulator/path")["poses"]) > 5
    assert got.latest("/emulator/pose")["frame_id"] == "world"
    assert set(got.latest("/emulator/truth")["boards"]) == {"L", "R"}
