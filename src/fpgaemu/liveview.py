"""``fpgaemu serve --robot --foxglove [HOST:]PORT``: the emulated robot as it really moves,
for Foxglove — what no host can know (the host's own live view, ``fpgalink-cli drive
--foxglove``, shows what it measures).

Decision: the emulator serves its truth itself, with foxglove-sdk (optional, imported only
here, as MuJoCo is in physics/), rather than asking a host to relay the truth port: the
truth is the emulator's to tell, a served robot may have no host attached, and fpgaemu may
import nothing of fpgalink but its protocol package (which has the shared schemas,
:mod:`fpgalink.protocol.viewschemas`). A host's view shows truth too, in odometry's frame;
this one is in ``world``, the frame the emulator started the body in.

Topics: ``/emulator/truth`` (the truth stream's record: pose, speeds, distance, surface,
each board as the emulator sees it), ``/emulator/pose`` (foxglove.PoseInFrame),
``/emulator/path`` (foxglove.PosesInFrame), ``/tf`` (world → base_link, and each wheel), and
``/robot_description`` (the URDF). The SDK bounds what waits for each client (the oldest
dropped first); nothing here waits on a client."""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable
from typing import Any

from fpgalink.protocol.exitcodes import NotInstalled
from fpgalink.protocol.robot import RobotDescription
from fpgalink.protocol.urdf import robot_urdf
from fpgalink.protocol.viewschemas import (
    FRAME_TRANSFORMS_SCHEMA,
    POSE_IN_FRAME_SCHEMA,
    POSES_IN_FRAME_SCHEMA,
    STRING_SCHEMA,
    pose,
    stamp,
)

__all__ = ["TRUTH_SCHEMA", "EmulatorLiveView"]

#: How often the pose goes out; the path and the URDF once a second.
POSE_S = 0.02
SLOW_S = 1.0
#: The path keeps a pose every centimetre, at most this many.
PATH_POSES = 5000
#: Messages that may wait for one client (the SDK's backlog).
BACKLOG = 1024
INSTALL_HINT = "--foxglove needs foxglove-sdk: pip install 'fpgalink[foxglove]'"

TRUTH_SCHEMA: dict[str, Any] = {
    "title": "fpgaemu.Truth", "type": "object",
    "description": "the emulated body's true state (docs/emulator.md, the truth stream)",
    "properties": {k: {"type": "number"} for k in ("t", "x", "y", "theta", "v", "omega",
                                                   "distance")},
}


class EmulatorLiveView:
    """A Foxglove WebSocket server showing ``truth()`` (the served robot's truth record)."""

    def __init__(self, host: str, port: int, description: RobotDescription,
                 truth: Callable[[], dict[str, Any]]) -> None:
        self.host, self.requested_port = host, port
        self.description = description
        self.truth = truth
        self.port = 0
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self._task: asyncio.Task[None] | None = None
        self._path: list[tuple[float, float, float]] = []
        self._urdf = ""
        self._slow_at = 0.0
        self.published = 0

    def start(self) -> None:
        """Listen; :class:`NotInstalled` without foxglove-sdk, ``OSError`` when it cannot."""
        try:
            import foxglove
        except ImportError:
            raise NotInstalled(INSTALL_HINT) from None
        # Kept: the server holds its context weakly, and without it advertises nothing.
        self._context = context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name="fpgaemu serve --robot", host=self.host, port=self.requested_port,
                context=context, message_backlog_size=BACKLOG)
        except RuntimeError as exc:
            raise OSError(str(exc)) from None
        self.port = int(self._server.port)
        for topic, schema in (("/emulator/truth", TRUTH_SCHEMA),
                              ("/emulator/pose", POSE_IN_FRAME_SCHEMA),
                              ("/emulator/path", POSES_IN_FRAME_SCHEMA),
                              ("/tf", FRAME_TRANSFORMS_SCHEMA),
                              ("/robot_description", STRING_SCHEMA)):
            self._channels[topic] = foxglove.Channel(
                topic, schema=foxglove.Schema(name=str(schema["title"]), encoding="jsonschema",
                                              data=json.dumps(schema).encode()),
                message_encoding="json", context=context)
        self._task = asyncio.get_running_loop().create_task(self._run())

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _publish(self, topic: str, make: Callable[[], dict[str, Any]], now: float) -> None:
        channel = self._channels[topic]
        if channel.has_sinks():  # encoded only when someone watches
            channel.log(json.dumps(make(), allow_nan=False).encode(), log_time=int(now * 1e9))
            self.published += 1

    async def _run(self) -> None:
        self._urdf = robot_urdf(self.description)
        self._slow_at = 0.0
        while True:
            self._tick(time.time())
            await asyncio.sleep(POSE_S)

    def _tick(self, now: float) -> None:
        record = self.truth()
        x, y, theta = record["x"], record["y"], record["theta"]
        if not self._path or math.hypot(x - self._path[-1][0],
                                        y - self._path[-1][1]) >= 0.01:
            self._path.append((x, y, theta))
            del self._path[:-PATH_POSES]
        self._publish("/emulator/truth", lambda: {
            k: record[k] for k in TRUTH_SCHEMA["properties"] if k in record}
            | {"surface": record.get("surface"), "boards": record.get("boards")}, now)
        self._publish("/emulator/pose", lambda: {
            "timestamp": stamp(now), "frame_id": "world", "pose": pose(x, y, theta)}, now)
        self._publish("/tf", lambda: self._transforms(now, x, y, theta), now)
        if now - self._slow_at >= SLOW_S:
            self._slow_at = now
            self._publish("/robot_description", lambda: {"data": self._urdf}, now)
            self._publish("/emulator/path", lambda: {
                "timestamp": stamp(now), "frame_id": "world",
                "poses": [pose(*p) for p in self._path]}, now)

    def _transforms(self, now: float, x: float, y: float, theta: float) -> dict[str, Any]:
        body = pose(x, y, theta)
        at = stamp(now)
        return {"transforms": [
            {"timestamp": at, "parent_frame_id": "world", "child_frame_id": "base_link",
             "translation": body["position"], "rotation": body["orientation"]},
            *({"timestamp": at, "parent_frame_id": "base_link",
               "child_frame_id": f"{w.name}_link",
               "translation": {"x": w.x, "y": w.y, "z": 0.0},
               "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
              for w in self.description.wheels)]}

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        if self._server is not None:
            self._server.stop()
