"""The zenoh API of one cell: key expressions, request/reply payloads, JSON Schemas, error codes.

Every payload is JSON. A request is checked in this order, and the first problem found is the
answer (a :class:`ApiError`, sent with ``reply_err``): size (``too_large``), JSON syntax
(``malformed_json``), the request's JSON Schema (``invalid_request``, ``wrong_joint_count``,
``too_large``), then the values (``not_finite``, ``unknown_joint``, ``out_of_limits``). Only a
request that passes all of them reaches the planner or the drives, so a bad request changes nothing.

The schemas below are the one description of the payloads: the service validates with them,
docs/API.md prints them, and the tests check every reply against them.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cache
from typing import Any

import numpy as np
from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError
from numpy.typing import NDArray

from planner.cartesian import POSE_LENGTH, QUATERNION_TOLERANCE, Motion, check_poses
from planner.limits import JointLimits, check_max_jerk, check_scale
from planner.path import PlanError

API_VERSION = 1
PREFIX = "pvtflow"
QUERYABLES = ("plan", "validate", "execute", "stop", "status", "recover", "home")
PUBLICATIONS = ("state", "telemetry", "events")
LIVELINESS = "alive"

MAX_REQUEST_BYTES = 1 << 20  # 1 MiB: a program of ~60 000 records fits, a runaway client does not
MAX_WAYPOINTS = 500
MAX_RECENT = 100
MAX_TEXT = 200
ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
_KEY_CHUNK = re.compile(r"^[A-Za-z0-9_.-]+$")


class ErrorCode(StrEnum):
    """Stable error codes (``error.code`` of every ``reply_err``); docs/API.md explains each."""

    MALFORMED_JSON = "malformed_json"  # the payload is not UTF-8 JSON
    INVALID_REQUEST = "invalid_request"  # JSON, but not the request's schema (type, field, shape)
    WRONG_JOINT_COUNT = "wrong_joint_count"  # a joint vector without one value per joint of the cell
    NOT_FINITE = "not_finite"  # NaN or +-inf where a number is needed
    UNKNOWN_JOINT = "unknown_joint"  # joint_names do not name the cell's joints
    OUT_OF_LIMITS = "out_of_limits"  # a waypoint outside the joint position limits
    TOO_LARGE = "too_large"  # payload over MAX_REQUEST_BYTES, or too many waypoints
    UNKNOWN_PLAN = "unknown_plan"  # no plan with this id (never made, or forgotten)
    WRONG_CELL = "wrong_cell"  # a program made for another cell or other drives
    PLAN_FAILED = "plan_failed"  # the planner found no motion (details.result says why)
    VALIDATION_FAILED = "validation_failed"  # the program breaks its drives' rules
    BUSY = "busy"  # a motion is running on this cell: one at a time
    START_MISMATCH = "start_mismatch"  # the axes are not where the program starts
    NOT_HOMED = "not_homed"  # the cell must home first (an axis has not homed since its drive booted)
    DRIVE_FAULT = "drive_fault"  # a drive is faulted or refused to enable: recover first
    NOT_ALLOWED = "not_allowed"  # the request is not possible in the cell's present state
    BUS_ERROR = "bus_error"  # the CAN bus failed
    JOURNAL_ERROR = "journal_error"  # the motion could not be written to the journal: nothing was sent
    INTERNAL_ERROR = "internal_error"  # a bug: the request was dropped, the service stays up


ERROR_DESCRIPTIONS: dict[ErrorCode, str] = {
    ErrorCode.MALFORMED_JSON: "The payload is not UTF-8 JSON (syntax error, bad encoding, binary data).",
    ErrorCode.INVALID_REQUEST: "Valid JSON that does not follow the request's JSON Schema: not an object, a "
    "missing or unknown field, a wrong type, an empty list. details.path is the JSON path of the problem.",
    ErrorCode.WRONG_JOINT_COUNT: "A waypoint, target or start does not have exactly one value per joint of the cell "
    "(details.expected, details.got, details.path).",
    ErrorCode.NOT_FINITE: "NaN, Infinity or a number too large for a double (1e999) where a joint value is "
    "needed (details.path).",
    ErrorCode.UNKNOWN_JOINT: "joint_names names a joint the cell does not have, misses one, or repeats one.",
    ErrorCode.OUT_OF_LIMITS: "A waypoint is outside the joint position limits (the stricter of the drives' "
    "0x607D and the URDF's); details has the joint, the value and the limits.",
    ErrorCode.TOO_LARGE: f"The payload is over {MAX_REQUEST_BYTES} bytes or has more than {MAX_WAYPOINTS} waypoints.",
    ErrorCode.UNKNOWN_PLAN: "No plan with this plan_id on this cell (plans live in memory: a restart or "
    "too many newer plans forget it).",
    ErrorCode.WRONG_CELL: "The program was made for another cell, other node ids, profiles, scaling or limits.",
    ErrorCode.PLAN_FAILED: "The planner found no motion through these waypoints or poses (details.result: "
    "repeated_waypoint, path_out_of_limits, infeasible, ... or program_error; for poses also unreachable, "
    "singular or joint_limit, with details.pose, the pose the line leads to, and details.fraction, how far "
    "along it).",
    ErrorCode.VALIDATION_FAILED: "The program breaks its drives' rules (details.report is the validator's "
    "report): nothing was sent.",
    ErrorCode.BUSY: "A motion is running on this cell (details.motion_id). One motion at a time: stop it or "
    "wait for its end.",
    ErrorCode.START_MISMATCH: "The axes are not where the program starts (they moved since it was planned): "
    "plan again from the current position.",
    ErrorCode.NOT_HOMED: "The cell requires homing and an axis has not homed since its drive last booted "
    "(power-on, NMT reset, power loss): its position means nothing yet. Call home, then plan again "
    "(details.joints are the axes not homed).",
    ErrorCode.DRIVE_FAULT: "A drive is faulted, the last motion ended in a fault, or a drive refused to "
    "enable: call recover (after fixing the cause) before the next execute.",
    ErrorCode.NOT_ALLOWED: "The request is not possible in the cell's present state.",
    ErrorCode.BUS_ERROR: "The CAN bus or a drive did not answer.",
    ErrorCode.JOURNAL_ERROR: "The motion could not be written to the journal on disk (full, read-only): "
    "it was not started, because what runs must be recorded first.",
    ErrorCode.INTERNAL_ERROR: "An unexpected error in the service (a bug: please report it with the "
    "message). The request was dropped; the service keeps running.",
}


class ApiError(Exception):
    """A request refused with a stable code; ``to_json()`` is the ``reply_err`` payload."""

    def __init__(self, code: ErrorCode, message: str, details: Mapping[str, Any] | None = None) -> None:
        super().__init__(message)
        self.code = ErrorCode(code)
        self.message = message
        self.details: dict[str, Any] = dict(details or {})

    def to_json(self) -> dict[str, Any]:
        return {"error": {"code": self.code.value, "message": self.message, "details": self.details}}

    def to_bytes(self) -> bytes:
        return dumps(self.to_json())


# --- key expressions -------------------------------------------------------------------------------
def check_cell_name(cell: str) -> str:
    """A cell name must be one key-expression chunk (no '/', '*', '$', '?', '#')."""
    if not _KEY_CHUNK.match(cell):
        raise ValueError(f"cell name {cell!r} cannot be a zenoh key chunk: use letters, digits, '_', '-', '.'")
    return cell


def key(cell: str, name: str) -> str:
    """``pvtflow/<cell>/<name>``; ``cell`` may be ``*`` for a client addressing every cell."""
    return f"{PREFIX}/{cell}/{name}"


# --- JSON ------------------------------------------------------------------------------------------
def _parse_constant(name: str) -> float:
    """NaN / Infinity / -Infinity literals (not JSON, but Python's json reads them): kept, then refused."""
    return float(name.replace("Infinity", "inf"))


def dumps(data: Any) -> bytes:
    """Compact JSON; NaN never leaves the service (allow_nan=False makes that a bug, not bad JSON)."""
    return json.dumps(data, separators=(",", ":"), allow_nan=False).encode()


def parse_payload(payload: bytes | None) -> Any:
    """Bytes -> JSON value. Empty payload = ``{}`` (status, stop and recover need no fields)."""
    if payload is None or len(payload) == 0:
        return {}
    if len(payload) > MAX_REQUEST_BYTES:
        raise ApiError(
            ErrorCode.TOO_LARGE,
            f"the request is {len(payload)} bytes, the limit is {MAX_REQUEST_BYTES}",
            {"bytes": len(payload), "limit": MAX_REQUEST_BYTES},
        )
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ApiError(
            ErrorCode.MALFORMED_JSON,
            f"the payload is not UTF-8 text: {exc.reason} at byte {exc.start}",
            {"position": exc.start},
        ) from None
    try:
        data = json.loads(text, parse_constant=_parse_constant)
    except json.JSONDecodeError as exc:
        raise ApiError(
            ErrorCode.MALFORMED_JSON,
            f"the payload is not JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})",
            {"line": exc.lineno, "column": exc.colno},
        ) from None
    except RecursionError:
        raise ApiError(ErrorCode.MALFORMED_JSON, "the payload is nested too deeply to be a request") from None
    except ValueError as exc:  # e.g. an integer literal of more than 4300 digits
        raise ApiError(ErrorCode.MALFORMED_JSON, f"the payload is not usable JSON: {_short(str(exc))}") from None
    _check_finite(data)
    return data


def _all_finite(data: Any) -> bool:
    """Whether every number in ``data`` is finite: the common case, checked without building paths."""
    stack: list[Any] = [data]
    while stack:
        value = stack.pop()
        if isinstance(value, float):
            if not math.isfinite(value):
                return False
        elif isinstance(value, list):
            stack.extend(value)
        elif isinstance(value, dict):
            stack.extend(value.values())
    return True


def _check_finite(data: Any) -> None:
    """NOT_FINITE for the first NaN / Infinity / 1e999 anywhere in the request (iterative: no recursion)."""
    if _all_finite(data):
        return
    stack: list[tuple[Any, str]] = [(data, "$")]
    while stack:
        value, path = stack.pop()
        if isinstance(value, float):
            if not math.isfinite(value):
                raise ApiError(
                    ErrorCode.NOT_FINITE,
                    f"{path} is {value!r}: numbers must be finite",
                    {"path": path, "value": str(value)},
                )
        elif isinstance(value, dict):
            stack.extend((v, f"{path}.{k}") for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, f"{path}[{i}]") for i, v in enumerate(value))


# --- schemas ---------------------------------------------------------------------------------------
SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def _vector(dof: int | None, description: str) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "array", "items": {"type": "number"}, "description": description}
    if dof is not None:
        schema["minItems"] = schema["maxItems"] = dof
    return schema


def _obj(properties: dict[str, Any], required: Sequence[str] = (), **extra: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "object", "properties": properties, "additionalProperties": False}
    if required:
        out["required"] = list(required)
    out.update(extra)
    return out


_PLAN_ID = {"type": "string", "pattern": ID_PATTERN, "description": "a plan id from a plan reply"}
_MOTION_ID = {"type": "string", "pattern": ID_PATTERN}
_TEXT = {"type": "string", "maxLength": MAX_TEXT}
_PROGRAM = {"type": "object", "description": "a PVT program (pvtflow.pvt-program JSON, docs/program-format)"}
_INT_OR_NULL = {"type": ["integer", "null"]}
_NUM_OR_NULL = {"type": ["number", "null"]}
_STR_OR_NULL = {"type": ["string", "null"]}


def request_schema(name: str, dof: int | None = None) -> dict[str, Any]:
    """The JSON Schema of the request to queryable ``name`` on a cell of ``dof`` joints."""
    if name == "plan":
        body = _obj(
            {
                "waypoints": {
                    "type": "array",
                    "minItems": 1,
                    "maxItems": MAX_WAYPOINTS,
                    "items": _vector(dof, "joint positions (rad / m), in joint_names order"),
                    "description": "positions to pass through; with start=current the motion starts at the axes' "
                    "present position and goes through all of them",
                },
                "target": _vector(dof, "a single goal: the same as waypoints=[target] with start=current"),
                "joint_names": {
                    "type": "array",
                    "items": {"type": "string"},
                    "minItems": 1,
                    "description": "the order of the values (default: the cell's joint order)",
                },
                "poses": {
                    "type": "array",
                    "minItems": 1,
                    "maxItems": MAX_WAYPOINTS,
                    "items": {
                        "type": "array",
                        "items": {"type": "number"},
                        "minItems": POSE_LENGTH,
                        "maxItems": POSE_LENGTH,
                        "description": "[x, y, z, qx, qy, qz, qw]: the cell's tcp_frame in the robot's base frame "
                        f"(m; a unit quaternion, normalized within {QUATERNION_TOLERANCE:g})",
                    },
                    "description": "tool poses to go through (instead of waypoints or target), from the start",
                },
                "motion": {
                    "enum": [m.value for m in Motion],
                    "default": Motion.LINEAR.value,
                    "description": "poses only: linear, the tool on straight lines between the poses (orientation "
                    "by slerp); joint, a joint path through the inverse-kinematics solutions of the poses",
                },
                "start": {
                    "anyOf": [
                        {"enum": ["current", "first"]},
                        {"type": "array", "items": {"type": "number"}},
                    ],
                    "default": "current",
                    "description": "current: from where the axes are now; first (waypoints): the first waypoint is "
                    "the start; a list of joint values (poses): the motion starts there (execute then checks the "
                    "axes are there)",
                },
                "tolerance_qc": {
                    "type": "number",
                    "minimum": 0.5,
                    "maximum": 10000,
                    "description": "knot placement tolerance in counts (default: the cell's)",
                },
                "velocity_scale": {
                    "type": "number",
                    "exclusiveMinimum": 0,
                    "maximum": 1,
                    "default": 1,
                    "description": "speed override: plan with the joint velocity limits times this (the drives' "
                    "0x607F in the program stays the drives' own)",
                },
                "acceleration_scale": {
                    "type": "number",
                    "exclusiveMinimum": 0,
                    "maximum": 1,
                    "default": 1,
                    "description": "the same for the joint acceleration limits (0x60C5)",
                },
                "max_jerk": {
                    **_vector(
                        dof,
                        "jerk limit per joint (rad/s^3 or m/s^3, in joint_names order) instead of the cell's "
                        "axes' max_jerk: the timing is then solved jerk-limited (docs/planning.md)",
                    ),
                    "items": {"type": "number", "exclusiveMinimum": 0},
                },
                "label": _TEXT,
                "include_program": {
                    "type": "boolean",
                    "default": False,
                    "description": "put the whole PVT program in the reply",
                },
            },
            oneOf=[{"required": ["waypoints"]}, {"required": ["target"]}, {"required": ["poses"]}],
        )
    elif name == "validate":
        body = _obj(
            {"plan_id": _PLAN_ID, "program": _PROGRAM}, oneOf=[{"required": ["plan_id"]}, {"required": ["program"]}]
        )
    elif name == "execute":
        body = _obj(
            {
                "plan_id": _PLAN_ID,
                "program": _PROGRAM,
                "label": _TEXT,
                "wait": {
                    "type": "boolean",
                    "default": False,
                    "description": "reply at the end of the motion (with its outcome) instead of at its start",
                },
            },
            oneOf=[{"required": ["plan_id"]}, {"required": ["program"]}],
        )
    elif name == "stop":
        body = _obj({"reason": _TEXT})
    elif name == "status":
        body = _obj(
            {
                "recent": {
                    "type": "integer",
                    "minimum": 0,
                    "maximum": MAX_RECENT,
                    "default": 10,
                    "description": "how many recent motions (from the journal) to list",
                }
            }
        )
    elif name == "recover":
        body = _obj({})
    elif name == "home":
        body = _obj(
            {
                "joints": {
                    "type": "array",
                    "items": {"type": "string"},
                    "minItems": 1,
                    "uniqueItems": True,
                    "description": "the axes to home (default: every axis with homing), in the cell's homing order",
                },
                "wait": {
                    "type": "boolean",
                    "default": False,
                    "description": "reply at the end of the homing (with its outcome) instead of at its start",
                },
            }
        )
    else:
        raise KeyError(name)
    return {"$schema": SCHEMA_DIALECT, "$id": f"pvtflow:{name}.request", "title": f"{name} request", **body}


_AXIS_STATUS = _obj(
    {
        "joint": {"type": "string"},
        "node_id": {"type": "integer"},
        "profile": {"type": "string"},
        "state": {"type": "string", "description": "CiA 402 power state decoded from the statusword"},
        "statusword": {"type": "integer"},
        "statusword_hex": {"type": "string"},
        "position_qc": _INT_OR_NULL,
        "position": _NUM_OR_NULL,
        "buffer_status": {"type": "integer", "description": "EPOS2 0x20C4:01 (0 for other profiles)"},
        "buffer_flags": {"type": "array", "items": {"type": "string"}},
        "buffer_level": _INT_OR_NULL,
        "last_emcy": {"type": ["object", "null"]},
        "nmt_state": _INT_OR_NULL,
        "fault": {"type": "boolean"},
        "homing": {"type": "boolean", "description": "the axis has homing (an incremental encoder)"},
        "homed": {"type": "boolean", "description": "nothing to home, or homed since its drive last booted"},
    },
    required=["joint", "node_id", "state", "statusword", "position_qc", "position", "buffer_status", "fault"],
)
_RUN_RESULT = {
    "type": "object",
    "required": ["result", "message"],
    "properties": {"result": {"type": "string"}, "message": {"type": "string"}},
}
_MOTION = {
    "type": "object",
    "required": ["motion_id", "state"],
    "properties": {
        "motion_id": _MOTION_ID,
        "plan_id": _STR_OR_NULL,
        "label": _STR_OR_NULL,
        "state": {"enum": ["running", "ended", "interrupted"]},
        "accepted_at": {"type": "string"},
        "ended_at": _STR_OR_NULL,
        "duration_ms": {"type": "integer"},
        "outcome": {"type": ["object", "null"]},
    },
}
SERVICE_STATES = ("idle", "moving", "stopping", "fault", "homing")
_HOMING = {
    "type": "object",
    "required": ["homing_id", "state", "stages"],
    "properties": {
        "homing_id": _MOTION_ID,
        "state": {"enum": ["running", "ended"]},
        "stages": {"type": "array", "items": {"type": "array", "items": {"type": "string"}}},
        "outcome": {
            "type": ["object", "null"],
            "description": "result (homed, stopped, homing_error, timeout, drive_fault, emcy, heartbeat_lost, "
            "lost_sync, configuration_error), message, joint, axes (per axis: method, homed, time_s, position_qc)",
        },
    },
}


def reply_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of a successful reply of queryable ``name`` (or of a publication)."""
    if name == "plan":
        body = {
            "type": "object",
            "required": ["plan_id", "cell", "joint_names", "duration_s", "start", "end", "validation", "timing_ms"],
            "properties": {
                "plan_id": _PLAN_ID,
                "cell": {"type": "string"},
                "joint_names": {"type": "array", "items": {"type": "string"}},
                "duration_s": {"type": "number"},
                "waypoints": {"type": "integer"},
                "start": {"type": "array", "items": {"type": "number"}},
                "end": {"type": "array", "items": {"type": "number"}},
                "records": {"type": "object", "additionalProperties": {"type": "integer"}},
                "validation": {"type": "object"},
                "timing_ms": {"type": "object"},
                "program": _PROGRAM,
                "label": _STR_OR_NULL,
            },
        }
    elif name == "validate":
        body = {
            "type": "object",
            "required": ["ok", "report", "cell_problems"],
            "properties": {
                "ok": {"type": "boolean"},
                "report": {"type": "object"},
                "cell_problems": {"type": "array", "items": {"type": "string"}},
            },
        }
    elif name == "execute":
        body = {
            "type": "object",
            "required": ["motion_id", "state", "duration_ms"],
            "properties": {
                "motion_id": _MOTION_ID,
                "plan_id": _STR_OR_NULL,
                "state": {"enum": ["running", "ended"]},
                "duration_ms": {"type": "integer"},
                "start_sync": _INT_OR_NULL,
                "outcome": {"type": ["object", "null"]},
            },
        }
    elif name == "stop":
        body = {
            "type": "object",
            "required": ["was_moving", "motion_id", "axes"],
            "properties": {
                "was_moving": {"type": "boolean"},
                "motion_id": {"type": ["string", "null"]},
                "homing_id": {"type": ["string", "null"], "description": "the homing it stopped, if one ran"},
                "outcome": {"type": ["object", "null"]},
                "axes": {"type": "array", "items": _AXIS_STATUS},
            },
        }
    elif name == "status":
        body = {
            "type": "object",
            "required": ["cell", "state", "motion", "axes", "joint_names", "recent", "plans"],
            "properties": {
                "cell": {"type": "string"},
                "state": {"enum": list(SERVICE_STATES)},
                "motion": {"type": ["object", "null"]},
                "sync_count": {"type": "integer"},
                "elapsed_ms": _NUM_OR_NULL,
                "joint_names": {"type": "array", "items": {"type": "string"}},
                "axes": {"type": "array", "items": _AXIS_STATUS},
                "recent": {"type": "array", "items": _MOTION},
                "plans": {"type": "integer"},
                "last_result": {"type": ["object", "null"]},
                "requires_homing": {"type": "boolean"},
                "homed": {"type": "boolean", "description": "every axis homed since its drive last booted"},
                "homing": {"type": ["object", "null"], "description": "the last homing (as the home reply)"},
            },
        }
    elif name == "recover":
        body = {
            "type": "object",
            "required": ["ok", "message", "axes"],
            "properties": {
                "ok": {"type": "boolean"},
                "message": {"type": "string"},
                "axes": {"type": "array", "items": _AXIS_STATUS},
            },
        }
    elif name == "home":
        body = _HOMING
    elif name == "state":
        body = {
            "type": "object",
            "required": ["cell", "state", "motion_id", "axes", "seq", "time"],
            "properties": {
                "cell": {"type": "string"},
                "state": {"enum": list(SERVICE_STATES)},
                "motion_id": {"type": ["string", "null"]},
                "seq": {"type": "integer"},
                "time": {"type": "number"},
                "axes": {"type": "array", "items": {"type": "object", "required": ["joint", "state"]}},
            },
        }
    elif name == "telemetry":
        body = {
            "type": "object",
            "required": [
                "cell",
                "motion_id",
                "sync",
                "elapsed_ms",
                "positions_qc",
                "positions",
                "buffer_levels",
                "states",
                "time",
            ],
            "properties": {
                "cell": {"type": "string"},
                "motion_id": {"type": ["string", "null"]},
                "sync": {"type": "integer"},
                "elapsed_ms": _NUM_OR_NULL,
                "progress": _NUM_OR_NULL,
                "time": {"type": "number"},
                "positions_qc": {"type": "array", "items": _INT_OR_NULL},
                "positions": {"type": "array", "items": _NUM_OR_NULL},
                "buffer_levels": {"type": "array", "items": _INT_OR_NULL},
                "states": {"type": "array", "items": {"type": "string"}},
            },
        }
    elif name == "events":
        body = {
            "type": "object",
            "required": ["cell", "kind", "message", "time"],
            "properties": {
                "cell": {"type": "string"},
                "kind": {"type": "string"},
                "message": {"type": "string"},
                "joint": _STR_OR_NULL,
                "node_id": _INT_OR_NULL,
                "motion_id": {"type": ["string", "null"]},
                "time": {"type": "number"},
                "outcome": {"type": ["object", "null"]},
            },
        }
    elif name == "error":
        body = {
            "type": "object",
            "required": ["error"],
            "additionalProperties": False,
            "properties": {
                "error": {
                    "type": "object",
                    "required": ["code", "message", "details"],
                    "additionalProperties": False,
                    "properties": {
                        "code": {"enum": [c.value for c in ErrorCode]},
                        "message": {"type": "string"},
                        "details": {"type": "object"},
                    },
                }
            },
        }
    else:
        raise KeyError(name)
    return {"$schema": SCHEMA_DIALECT, "$id": f"pvtflow:{name}.reply", "title": f"{name} reply", **body}


@cache
def _validator(name: str, dof: int | None) -> Draft202012Validator:
    return Draft202012Validator(request_schema(name, dof))


def _json_path(path: Sequence[Any]) -> str:
    return "$" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path)


_NUMBER_TYPES = frozenset({int, float})  # JSON numbers as json.loads makes them (bool is not one)
_PLAN_PROPERTIES = request_schema("plan")["properties"]
_PLAN_FIELDS = frozenset(_PLAN_PROPERTIES)
_PLAN_STARTS = frozenset(_PLAN_PROPERTIES["start"]["anyOf"][0]["enum"])
_PLAN_TOLERANCE = (_PLAN_PROPERTIES["tolerance_qc"]["minimum"], _PLAN_PROPERTIES["tolerance_qc"]["maximum"])
_PLAN_SCALES = ("velocity_scale", "acceleration_scale")


def _numbers(row: Any, dof: int | None) -> bool:
    return type(row) is list and (dof is None or len(row) == dof) and all(type(v) in _NUMBER_TYPES for v in row)


def _plain_plan(data: Any, dof: int | None) -> bool:
    """True only for a plan request the plan schema certainly accepts (the common, well-formed one).

    The same rules in plain Python, ~20 times faster than jsonschema (0.45 ms for 8 waypoints on
    this VM); anything it does not recognise goes to jsonschema, which finds and words the error.
    A subset of the schema, never a second definition of it: False is always a safe answer.
    """
    if type(data) is not dict or not _PLAN_FIELDS.issuperset(data) or ("waypoints" in data) == ("target" in data):
        return False
    for name, value in data.items():
        if name == "waypoints":
            ok = type(value) is list and 1 <= len(value) <= MAX_WAYPOINTS and all(_numbers(r, dof) for r in value)
        elif name == "target":
            ok = _numbers(value, dof)
        elif name == "joint_names":
            ok = type(value) is list and len(value) > 0 and all(type(n) is str for n in value)
        elif name == "start":
            ok = type(value) is str and value in _PLAN_STARTS
        elif name == "tolerance_qc":
            ok = type(value) in _NUMBER_TYPES and _PLAN_TOLERANCE[0] <= value <= _PLAN_TOLERANCE[1]
        elif name in _PLAN_SCALES:
            ok = type(value) in _NUMBER_TYPES and 0 < value <= 1
        elif name == "max_jerk":
            ok = _numbers(value, dof) and all(v > 0 for v in value)
        elif name == "label":
            ok = type(value) is str and len(value) <= MAX_TEXT
        else:  # include_program
            ok = type(value) is bool
        if not ok:
            return False
    return True


def check_schema(name: str, data: Any, dof: int | None) -> dict[str, Any]:
    """Raise the ApiError for the first schema problem of a ``name`` request (None: it follows it)."""
    if name == "plan" and _plain_plan(data, dof):
        return data  # type: ignore[no-any-return]
    errors = list(_validator(name, dof).iter_errors(data))
    if not errors:
        return data  # type: ignore[no-any-return]
    # the most telling error first: a joint count or a size beats a generic shape problem
    for err in sorted(errors, key=lambda e: (len(e.absolute_path), str(e.message))):
        path = list(err.absolute_path)
        if err.validator in ("minItems", "maxItems") and path and path[0] == "poses":
            if path == ["poses"] and err.validator == "maxItems":
                raise ApiError(
                    ErrorCode.TOO_LARGE,
                    f"{len(err.instance)} poses, at most {MAX_WAYPOINTS}",
                    {"poses": len(err.instance), "limit": MAX_WAYPOINTS},
                )
            if len(path) == 2:
                raise ApiError(
                    ErrorCode.INVALID_REQUEST,
                    f"{_json_path(path)} has {len(err.instance)} values; a pose is [x, y, z, qx, qy, qz, qw]",
                    {"path": _json_path(path), "expected": POSE_LENGTH, "got": len(err.instance)},
                )
        if err.validator in ("minItems", "maxItems") and path and path[0] in ("waypoints", "target", "max_jerk"):
            if path == ["waypoints"]:
                if err.validator == "maxItems":
                    raise ApiError(
                        ErrorCode.TOO_LARGE,
                        f"{len(err.instance)} waypoints, at most {MAX_WAYPOINTS}",
                        {"waypoints": len(err.instance), "limit": MAX_WAYPOINTS},
                    )
                continue
            raise ApiError(
                ErrorCode.WRONG_JOINT_COUNT,
                f"{_json_path(path)} has {len(err.instance)} values, the cell has {dof} joints",
                {"path": _json_path(path), "expected": dof, "got": len(err.instance)},
            )
    raise _schema_error(name, data, errors)


def _schema_error(name: str, data: Any, errors: list[ValidationError]) -> ApiError:
    if not isinstance(data, dict):
        return ApiError(
            ErrorCode.INVALID_REQUEST,
            f"a {name} request must be a JSON object, got "
            f"{type(data).__name__ if not isinstance(data, list) else 'an array'}",
            {"path": "$"},
        )
    err = min(errors, key=lambda e: (e.validator != "additionalProperties", -len(e.absolute_path)))
    path = _json_path(list(err.absolute_path))
    if err.validator == "additionalProperties":
        allowed = sorted(request_schema(name)["properties"])
        unknown = sorted(set(err.instance) - set(allowed)) if isinstance(err.instance, dict) else []
        fields = ", ".join(map(repr, unknown))
        if allowed:
            message = f"unknown field {fields} (allowed: {', '.join(allowed)})"
        else:
            message = f"a {name} request takes no fields, got {fields}"
    elif err.validator == "oneOf" and not err.absolute_path:
        choices = [next(iter(s["required"])) for s in err.validator_value]
        message = f"a {name} request needs exactly one of {' or '.join(choices)}"
    else:
        message = _short(err.message)
    return ApiError(
        ErrorCode.INVALID_REQUEST,
        f"{path}: {message}" if path != "$" else message,
        {"path": path, "rule": str(err.validator)},
    )


def _short(message: str, limit: int = 160) -> str:
    return message if len(message) <= limit else message[: limit - 3] + "..."


# --- requests --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanRequest:
    waypoints: NDArray[np.float64]  # (N, dof) in the cell's joint order; (0, dof) for poses
    start: str = "current"  # "current", "first" (waypoints) or "joints" (poses from start_joints)
    tolerance_qc: float | None = None
    label: str | None = None
    include_program: bool = False
    velocity_scale: float = 1.0  # speed override in (0, 1] (planner.limits.check_scale)
    acceleration_scale: float = 1.0
    poses: NDArray[np.float64] | None = None  # (N, 7), unit quaternions
    motion: str = Motion.LINEAR.value
    start_joints: NDArray[np.float64] | None = None  # (dof,) in the cell's joint order
    max_jerk: NDArray[np.float64] | None = None  # (dof,) in the cell's joint order; None: the cell's


@dataclass(frozen=True)
class ExecuteRequest:
    plan_id: str | None = None
    program: dict[str, Any] | None = None
    label: str | None = None
    wait: bool = False


@dataclass(frozen=True)
class ValidateRequest:
    plan_id: str | None = None
    program: dict[str, Any] | None = None


@dataclass(frozen=True)
class StopRequest:
    reason: str = "stop requested"


@dataclass(frozen=True)
class StatusRequest:
    recent: int = 10


@dataclass(frozen=True)
class HomeRequest:
    joints: tuple[str, ...] | None = None  # None: every axis with homing
    wait: bool = False


@dataclass(frozen=True)
class RecoverRequest:
    extra: dict[str, Any] = field(default_factory=dict)


def parse_plan(data: Any, joint_names: Sequence[str], limits: JointLimits | None = None) -> PlanRequest:
    """A checked plan request; waypoints reordered into the cell's joint order and inside ``limits``."""
    dof = len(joint_names)
    check_schema("plan", data, dof)
    order = _joint_order(data.get("joint_names"), joint_names)
    if "poses" in data:
        return _parse_pose_plan(data, order, limits)
    if "motion" in data:
        raise ApiError(ErrorCode.INVALID_REQUEST, "motion is for poses, not waypoints or target", {"path": "$.motion"})
    if isinstance(data.get("start"), list):
        raise ApiError(
            ErrorCode.INVALID_REQUEST,
            "a list of joint values as start is for poses; waypoints start at current or first",
            {"path": "$.start"},
        )
    rows = data["waypoints"] if "waypoints" in data else [data["target"]]
    field_name = "waypoints" if "waypoints" in data else "target"
    try:
        waypoints = np.array([[float(row[k]) for k in order] for row in rows], dtype=float)
    except OverflowError:
        raise ApiError(
            ErrorCode.NOT_FINITE, f"$.{field_name}: an integer too large for a joint value", {"path": f"$.{field_name}"}
        ) from None
    if limits is not None:
        check_limits(waypoints, limits, field_name)
    start = data.get("start", "current")
    if field_name == "target":
        start = "current"
    if start == "first" and len(waypoints) < 2:
        raise ApiError(
            ErrorCode.INVALID_REQUEST, "with start=first a motion needs at least 2 waypoints", {"path": "$.waypoints"}
        )
    return PlanRequest(
        waypoints,
        start,
        data.get("tolerance_qc"),
        data.get("label"),
        bool(data.get("include_program", False)),
        max_jerk=_max_jerk(data, order),
        **_scales(data),
    )


def _scales(data: dict[str, Any]) -> dict[str, float]:
    """velocity_scale, acceleration_scale: the schema has refused what is not in (0, 1]; the
    planner's rule (planner.limits.check_scale), once more."""
    scales = {}
    for name in _PLAN_SCALES:
        try:
            scales[name] = check_scale(name, data.get(name, 1.0))
        except ValueError as exc:
            raise ApiError(ErrorCode.INVALID_REQUEST, f"$.{name}: {exc}", {"path": f"$.{name}"}) from None
    return scales


def _max_jerk(data: dict[str, Any], order: list[int]) -> NDArray[np.float64] | None:
    """max_jerk in the cell's joint order: the schema has refused a wrong count and what is not
    positive; the planner's rule (planner.limits.check_max_jerk), once more."""
    if "max_jerk" not in data:
        return None
    try:
        values = [data["max_jerk"][k] for k in order]
        return check_max_jerk("max_jerk", values, len(order))
    except (ValueError, IndexError, TypeError) as exc:
        raise ApiError(ErrorCode.INVALID_REQUEST, f"$.max_jerk: {exc}", {"path": "$.max_jerk"}) from None


def _parse_pose_plan(data: dict[str, Any], order: list[int], limits: JointLimits | None) -> PlanRequest:
    """A plan request with poses: the poses checked (planner.cartesian's rules: 7 numbers, a unit
    quaternion), the start current or joint values inside the limits."""
    dof = len(order)
    try:
        poses = check_poses(data["poses"])
    except PlanError as exc:
        i = exc.details.get("pose")
        path = f"$.poses[{i}]" if i is not None else "$.poses"
        raise ApiError(ErrorCode.INVALID_REQUEST, f"{path}: {exc.message}", {"path": path}) from None
    except OverflowError:
        raise ApiError(ErrorCode.NOT_FINITE, "$.poses: a number too large", {"path": "$.poses"}) from None
    start = data.get("start", "current")
    start_joints = None
    if start == "first":
        raise ApiError(
            ErrorCode.INVALID_REQUEST,
            "with poses, start is current or a list of joint values (first is for waypoints)",
            {"path": "$.start"},
        )
    if isinstance(start, list):
        if len(start) != dof:
            raise ApiError(
                ErrorCode.WRONG_JOINT_COUNT,
                f"$.start has {len(start)} values, the cell has {dof} joints",
                {"path": "$.start", "expected": dof, "got": len(start)},
            )
        try:
            start_joints = np.array([float(start[k]) for k in order], dtype=float)
        except OverflowError:
            raise ApiError(
                ErrorCode.NOT_FINITE, "$.start: an integer too large for a joint value", {"path": "$.start"}
            ) from None
        if limits is not None:
            check_limits(start_joints[None, :], limits, "start")
        start = "joints"
    return PlanRequest(
        np.empty((0, dof)),
        start,
        data.get("tolerance_qc"),
        data.get("label"),
        bool(data.get("include_program", False)),
        poses=poses,
        motion=data.get("motion", Motion.LINEAR.value),
        start_joints=start_joints,
        max_jerk=_max_jerk(data, order),
        **_scales(data),
    )


def _joint_order(names: Any, joint_names: Sequence[str]) -> list[int]:
    """Where each of the cell's joints is in a request's values (``joint_names``: their order)."""
    dof = len(joint_names)
    if names is None:
        order = list(range(dof))
    else:
        if len(set(names)) != len(names):
            raise ApiError(ErrorCode.UNKNOWN_JOINT, "joint_names lists a joint twice", {"joint_names": names})
        unknown = [n for n in names if n not in joint_names]
        if unknown:
            raise ApiError(
                ErrorCode.UNKNOWN_JOINT,
                f"unknown joint {unknown[0]!r}; the cell has {', '.join(joint_names)}",
                {"joint": unknown[0], "joints": list(joint_names)},
            )
        missing = [n for n in joint_names if n not in names]
        if missing:
            raise ApiError(
                ErrorCode.UNKNOWN_JOINT,
                f"joint_names misses joint {missing[0]!r} of the cell",
                {"joint": missing[0], "joints": list(joint_names)},
            )
        order = [names.index(n) for n in joint_names]
    return order


def check_limits(waypoints: NDArray[np.float64], limits: JointLimits, field_name: str = "waypoints") -> None:
    """OUT_OF_LIMITS naming the first waypoint and joint outside [lower, upper]."""
    low = waypoints < limits.lower
    high = waypoints > limits.upper
    bad = np.argwhere(low | high)
    if len(bad):
        i, j = (int(x) for x in bad[0])
        value = float(waypoints[i, j])
        lo, hi = float(limits.lower[j]), float(limits.upper[j])
        path = f"$.{field_name}[{i}]" if field_name == "waypoints" else f"$.{field_name}"
        raise ApiError(
            ErrorCode.OUT_OF_LIMITS,
            f"{path}: joint {limits.names[j]} = {value:.6g} is outside its position limits [{lo:.6g}, {hi:.6g}]",
            {"path": path, "joint": limits.names[j], "value": value, "lower": lo, "upper": hi},
        )


def parse_execute(data: Any) -> ExecuteRequest:
    check_schema("execute", data, None)
    return ExecuteRequest(data.get("plan_id"), data.get("program"), data.get("label"), bool(data.get("wait", False)))


def parse_validate(data: Any) -> ValidateRequest:
    check_schema("validate", data, None)
    return ValidateRequest(data.get("plan_id"), data.get("program"))


def parse_stop(data: Any) -> StopRequest:
    check_schema("stop", data, None)
    return StopRequest(data.get("reason") or "stop requested")


def parse_status(data: Any) -> StatusRequest:
    check_schema("status", data, None)
    return StatusRequest(int(data.get("recent", 10)))


def parse_home(data: Any) -> HomeRequest:
    check_schema("home", data, None)
    joints = data.get("joints")
    return HomeRequest(tuple(joints) if joints is not None else None, bool(data.get("wait", False)))


def parse_recover(data: Any) -> RecoverRequest:
    check_schema("recover", data, None)
    return RecoverRequest()


# --- documentation ---------------------------------------------------------------------------------
SCHEMA_DOC_BEGIN = "<!-- schemas: generated by `python -m service.api`; do not edit by hand -->"
SCHEMA_DOC_END = "<!-- end of generated schemas -->"


def schema_document(dof: int = 6) -> str:
    """The schemas section of docs/API.md (requests for a cell of ``dof`` joints, replies, publications)."""
    parts = [SCHEMA_DOC_BEGIN, ""]
    for op in QUERYABLES:
        parts += [f"### `{op}` request", "", "```json", json.dumps(request_schema(op, dof), indent=2), "```", ""]
        parts += [f"### `{op}` reply", "", "```json", json.dumps(reply_schema(op), indent=2), "```", ""]
    for topic in (*PUBLICATIONS, "error"):
        title = "error reply (`reply_err`, every queryable)" if topic == "error" else f"`{topic}` publication"
        parts += [f"### {title}", "", "```json", json.dumps(reply_schema(topic), indent=2), "```", ""]
    parts.append(SCHEMA_DOC_END)
    return "\n".join(parts)


if __name__ == "__main__":
    print(schema_document())
