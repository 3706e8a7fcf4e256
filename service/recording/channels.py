"""The recording's channels: each one's JSON schema and how its messages are written.

A recording and the live view (service/live.py, service/live_rest.py) carry the same messages, so
each channel's schema and encoding live here once. Foxglove's own schemas where one fits
(``foxglove.Log``, ``foxglove.FrameTransforms``, sensor_msgs/JointState's and std_msgs/String's
fields), pvtflow's for the rest. The frequent messages (CAN frames, per-SYNC samples, the planned
samples) are formatted directly rather than through ``json.dumps`` of a dict: they are most of what
the writer does per SYNC.
"""

from __future__ import annotations

from collections.abc import Sequence

import can
import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.master.bus.faults import FaultKind
from pvtflow.axes.master.group.outcome import Result

# Foxglove's schemas (https://docs.foxglove.dev/docs/visualization/message-schemas), JSON flavour
_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
}
_VECTOR3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
LOG_SCHEMA = {
    "title": "foxglove.Log",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {"type": "integer", "enum": [0, 1, 2, 3, 4, 5]},
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    },
}
FRAME_TRANSFORMS_SCHEMA = {
    "title": "foxglove.FrameTransforms",
    "type": "object",
    "properties": {
        "transforms": {
            "type": "array",
            "items": {
                "title": "foxglove.FrameTransform",
                "type": "object",
                "properties": {
                    "timestamp": _TIME,
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": _VECTOR3,
                    "rotation": _QUATERNION,
                },
            },
        }
    },
}
_INT_OR_NULL = {"type": ["integer", "null"]}
_NUM_OR_NULL = {"type": ["number", "null"]}
JOINT_STATE_SCHEMA = {
    "title": "pvtflow.JointState",
    "description": "sensor_msgs/JointState's fields: joint names and positions (rad or m)",
    "type": "object",
    "properties": {
        "header": {"type": "object", "properties": {"stamp": _TIME, "frame_id": {"type": "string"}}},
        "name": {"type": "array", "items": {"type": "string"}},
        "position": {"type": "array", "items": _NUM_OR_NULL},
    },
}
PLANNED_SCHEMA = {
    "title": "pvtflow.PlannedSample",
    "description": "the drive's reconstruction of its records at program time t_ms (counts, ms)",
    "type": "object",
    "properties": {
        "t_ms": {"type": "number"},
        "position_qc": {"type": "number"},
        "velocity_qc_per_ms": {"type": "number"},
        "acceleration_qc_per_ms2": {"type": "number"},
        "position": {"type": "number"},
    },
}
ACTUAL_SCHEMA = {
    "title": "pvtflow.AxisSample",
    "description": "what the drive answered to one SYNC; planned and following error (planned - actual) in a run",
    "type": "object",
    "properties": {
        "sync": {"type": "integer"},
        "elapsed_ms": _NUM_OR_NULL,
        "position_qc": _INT_OR_NULL,
        "position": _NUM_OR_NULL,
        "planned_qc": _NUM_OR_NULL,
        "following_error_qc": _NUM_OR_NULL,
        "statusword": {"type": "integer"},
        "state": {"type": "string"},
        "status_sync": {"type": "integer", "description": "the SYNC the position and statusword are as of"},
    },
}
BUFFERS_SCHEMA = {
    "title": "pvtflow.BufferLevels",
    "type": "object",
    "properties": {
        "sync": {"type": "integer"},
        "joints": {"type": "array", "items": {"type": "string"}},
        "levels": {"type": "array", "items": _INT_OR_NULL},
    },
}
SYNC_SCHEMA = {
    "title": "pvtflow.Sync",
    "type": "object",
    "properties": {"sync": {"type": "integer"}, "interval_ms": _NUM_OR_NULL},
}
FAULT_SCHEMA = {
    "title": "pvtflow.Fault",
    "type": "object",
    "properties": {
        "kind": {"type": "string"},
        "node_id": _INT_OR_NULL,
        "joint": {"type": ["string", "null"]},
        "message": {"type": "string"},
        "code": {"type": "integer"},
    },
}
CAN_SCHEMA = {
    "title": "pvtflow.CanFrame",
    "type": "object",
    "properties": {
        "id": {"type": "integer"},
        "extended": {"type": "boolean"},
        "remote": {"type": "boolean"},
        "error": {"type": "boolean"},
        "rx": {"type": "boolean", "description": "false: sent by the master"},
        "dlc": {"type": "integer"},
        "data": {"type": "string", "description": "hex"},
    },
}

ROBOT_DESCRIPTION_SCHEMA = {
    "title": "std_msgs/msg/String",
    "description": "the robot's URDF, for a 3D panel's URDF layer (topic source)",
    "type": "object",
    "properties": {"data": {"type": "string"}},
}

# foxglove.Log levels
DEBUG, INFO, WARNING, ERROR = 1, 2, 3, 4
# a fault's or an event's kind as a log level: a fault is an error, a stop or a refusal a warning
FAULT_LEVEL = {k.value: (WARNING if k.warning else ERROR) for k in FaultKind}
FAULT_LEVEL.update({r.value: ERROR for r in Result if not r.ok})
FAULT_LEVEL.update({Result.STOPPED.value: WARNING, Result.REJECTED.value: WARNING, "halted": WARNING})

_JSON_BOOL = {True: "true", False: "false"}


def log_time(stamp_s: float) -> dict[str, int]:
    """A bus time as Foxglove's time (seconds and nanoseconds)."""
    ns = max(0, round(stamp_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _number(x: float | None) -> str:
    """A JSON number, null for None or NaN."""
    return "null" if x is None or x != x else repr(float(x))


def encode_can(msg: can.Message) -> bytes:
    """/can (CAN_SCHEMA) as JSON."""
    return (
        f'{{"id":{msg.arbitration_id},"extended":{_JSON_BOOL[msg.is_extended_id]},'
        f'"remote":{_JSON_BOOL[msg.is_remote_frame]},"error":{_JSON_BOOL[msg.is_error_frame]},'
        f'"rx":{_JSON_BOOL[bool(msg.is_rx)]},"dlc":{msg.dlc},"data":"{bytes(msg.data).hex()}"}}'
    ).encode()


def encode_sync(sync: int, interval_ms: float | None) -> bytes:
    """/sync (SYNC_SCHEMA) as JSON."""
    return f'{{"sync":{sync},"interval_ms":{_number(interval_ms)}}}'.encode()


def encode_buffers(sync: int, joints_json: str, levels: Sequence[int | None]) -> bytes:
    """/buffers (BUFFERS_SCHEMA) as JSON."""
    text = ",".join("null" if v is None else str(int(v)) for v in levels)
    return f'{{"sync":{sync},"joints":{joints_json},"levels":[{text}]}}'.encode()


def encode_planned(t_ms: float, qc: float, velocity: float, acceleration: float, position: float) -> bytes:
    """/axis/<joint>/planned (PLANNED_SCHEMA) as JSON."""
    return (
        f'{{"t_ms":{t_ms!r},"position_qc":{qc!r},"velocity_qc_per_ms":{velocity!r},'
        f'"acceleration_qc_per_ms2":{acceleration!r},"position":{position!r}}}'
    ).encode()


def encode_actual(
    sync: int,
    elapsed_ms: float | None,
    qc: int | None,
    position: float | None,
    planned: float | None,
    following: float | None,
    statusword: int,
    state: str,
    status_sync: int,
) -> bytes:
    """/axis/<joint>/actual (ACTUAL_SCHEMA) as JSON; NaN and None are null."""
    return (
        f'{{"sync":{sync},"elapsed_ms":{_number(elapsed_ms)},"position_qc":{"null" if qc is None else int(qc)},'
        f'"position":{_number(position)},"planned_qc":{_number(planned)},"following_error_qc":{_number(following)},'
        f'"statusword":{statusword},"state":"{state}","status_sync":{status_sync}}}'
    ).encode()


def encode_joint_states(stamp_s: float, joints_json: str, positions: Sequence[float | None]) -> bytes:
    """/joint_states (JOINT_STATE_SCHEMA) as JSON; NaN positions are null."""
    ns = max(0, round(stamp_s * 1e9))
    values = ",".join(_number(v) for v in positions)
    return (
        f'{{"header":{{"stamp":{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}},"frame_id":""}},'
        f'"name":{joints_json},"position":[{values}]}}'
    ).encode()


def encode_transforms(
    stamp_s: float, frames: Sequence[str], translations: NDArray[np.float64], rotations: NDArray[np.float64]
) -> bytes:
    """/tf (foxglove.FrameTransforms) as JSON: every frame's placement in ``world``."""
    ns = max(0, round(stamp_s * 1e9))
    stamp = f'{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}}'
    parts = []
    for name, (tx, ty, tz), (x, y, z, w) in zip(frames, translations.tolist(), rotations.tolist(), strict=True):
        parts.append(
            f'{{"timestamp":{stamp},"parent_frame_id":"world","child_frame_id":"{name}",'
            f'"translation":{{"x":{tx!r},"y":{ty!r},"z":{tz!r}}},"rotation":{{"x":{x!r},"y":{y!r},"z":{z!r},"w":{w!r}}}}}'
        )
    return ('{"transforms":[' + ",".join(parts) + "]}").encode()
