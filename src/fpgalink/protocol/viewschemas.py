"""The live views' JSON Schemas beside the recordings' (:mod:`fpgalink.recording`): Foxglove's
well-known types its 3D panel draws (from foxglove/foxglove-sdk's schemas/jsonschema, the
fields used here), the URDF as ROS's ``std_msgs/String``, and a board's parameter table.
Data only, here so both the host's live view (:mod:`fpgalink.live`) and the emulator's
(``fpgaemu serve --robot --foxglove``) use them."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["FRAME_TRANSFORMS_SCHEMA", "PARAMETERS_SCHEMA", "POSES_IN_FRAME_SCHEMA",
           "POSE_IN_FRAME_SCHEMA", "STATUS_SCHEMA", "STRING_SCHEMA", "pose", "stamp"]

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_VECTOR3 = {"title": "foxglove.Vector3", "type": "object",
            "properties": {k: {"type": "number"} for k in "xyz"}, "required": list("xyz")}
_QUATERNION = {"title": "foxglove.Quaternion", "type": "object",
               "properties": {k: {"type": "number"} for k in "xyzw"},
               "required": list("xyzw")}
_POSE = {"title": "foxglove.Pose", "type": "object",
         "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}

POSE_IN_FRAME_SCHEMA: dict[str, Any] = {
    "title": "foxglove.PoseInFrame", "type": "object",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
}
POSES_IN_FRAME_SCHEMA: dict[str, Any] = {
    "title": "foxglove.PosesInFrame", "type": "object",
    "description": "An array of timestamped poses for an object or reference frame",
    "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                   "poses": {"type": "array", "items": _POSE}},
}
FRAME_TRANSFORMS_SCHEMA: dict[str, Any] = {
    "title": "foxglove.FrameTransforms", "type": "object",
    "description": "An array of FrameTransform messages",
    "properties": {"transforms": {"type": "array", "items": {
        "title": "foxglove.FrameTransform", "type": "object",
        "properties": {"timestamp": _TIME, "parent_frame_id": {"type": "string"},
                       "child_frame_id": {"type": "string"}, "translation": _VECTOR3,
                       "rotation": _QUATERNION}}}},
}
#: ROS's std_msgs/String, which Foxglove's 3D panel reads a URDF from (``/robot_description``).
STRING_SCHEMA: dict[str, Any] = {
    "title": "std_msgs/msg/String", "type": "object",
    "properties": {"data": {"type": "string"}},
}
PARAMETERS_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.Parameters", "type": "object",
    "description": "every parameter value this host has seen the board confirm (PA), by name",
    "additionalProperties": {"type": "number"},
}
STATUS_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.Health", "type": "object",
    "description": "one status per board and one for supervision (0 OK, 1 WARN, 2 ERROR)",
    "properties": {"statuses": {"type": "array", "items": {
        "type": "object", "properties": {"name": {"type": "string"},
                                         "level": {"type": "integer"},
                                         "message": {"type": "string"}}}}},
}


def stamp(at: float) -> dict[str, int]:
    """Host epoch seconds as foxglove's ``time``."""
    whole = int(at)
    return {"sec": whole, "nsec": min(int((at - whole) * 1e9), 999_999_999)}


def pose(x: float, y: float, theta: float, z: float = 0.0) -> dict[str, Any]:
    """A planar pose as foxglove.Pose (a rotation about z by ``theta``)."""

    return {"position": {"x": x, "y": y, "z": z},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2),
                            "w": math.cos(theta / 2)}}
