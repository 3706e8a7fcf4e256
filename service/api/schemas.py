"""The JSON Schemas of every request, reply and publication: the one description of the payloads
(the service validates with them, docs/API.md prints them, the tests check every reply against them)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import cache
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError

from planner.cartesian import POSE_LENGTH, QUATERNION_TOLERANCE, MoveKind
from planner.limits import check_scale
from service.api.wire import (
    ID_PATTERN,
    MAX_RECENT,
    MAX_TEXT,
    MAX_WAYPOINTS,
    PUBLICATIONS,
    QUERYABLES,
    ApiError,
    CellState,
    ErrorCode,
    PlanStart,
    RunState,
    _short,
)

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
                    "enum": [m.value for m in MoveKind],
                    "default": MoveKind.LINEAR.value,
                    "description": "poses only: linear, the tool on straight lines between the poses (orientation "
                    "by slerp); joint, a joint path through the inverse-kinematics solutions of the poses",
                },
                "start": {
                    "anyOf": [
                        {"enum": [PlanStart.CURRENT.value, PlanStart.FIRST.value, PlanStart.HOME.value]},
                        {"type": "array", "items": {"type": "number"}},
                    ],
                    "default": PlanStart.CURRENT.value,
                    "description": "current: from where the axes are now; first (waypoints): the first waypoint is "
                    "the start; home: the cell's home position (where homing leaves the axes: each axis's 0x607C), "
                    "then through every waypoint or pose; a list of joint values (poses): the motion starts there "
                    "(execute then checks the axes are there)",
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
                "budget_ms": {
                    "type": "number",
                    "exclusiveMinimum": 0,
                    "maximum": 60000,
                    "description": "the plan's deadline in ms (default: the cell's planning.budget_ms): a "
                    "jerk-limited timing answers by then with its best so far (optimal: false in the reply); a plan "
                    "still not done then for another reason: timeout",
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
                "approach": {
                    "type": "boolean",
                    "default": False,
                    "description": "where the axes are not at the program's start: first move them there, a joint "
                    "move within the limits planned by the cell's planner (a motion of its own, journaled), then "
                    "start the program; without it such a program is refused (start_mismatch)",
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
        "state": {"enum": [s.value for s in RunState]},
        "accepted_at": {"type": "string"},
        "ended_at": _STR_OR_NULL,
        "duration_ms": {"type": "integer"},
        "outcome": {"type": ["object", "null"]},
        "recording": _STR_OR_NULL,
    },
}


SERVICE_STATES = tuple(s.value for s in CellState)


_HOMING = {
    "type": "object",
    "required": ["homing_id", "state", "stages"],
    "properties": {
        "homing_id": _MOTION_ID,
        "state": {"enum": [RunState.RUNNING.value, RunState.ENDED.value]},
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
                "state": {"enum": [RunState.RUNNING.value, RunState.ENDED.value]},
                "duration_ms": {"type": "integer"},
                "start_sync": _INT_OR_NULL,
                "outcome": {"type": ["object", "null"]},
                "approach": {
                    "type": ["object", "null"],
                    "description": "the approach motion (motion_id, duration_ms, outcome) when one ran first",
                },
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

    The same rules in plain Python, which a well-formed request passes without jsonschema's cost per
    keyword; anything it does not recognise goes to jsonschema, which finds and words the error.
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
        elif name == "budget_ms":
            ok = type(value) in _NUMBER_TYPES and 0 < value <= 60000
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
    elif list(err.absolute_path) in ([s] for s in _PLAN_SCALES):
        message = _scale_problem(str(err.absolute_path[0]), err.instance)
    else:
        message = _short(err.message)
    return ApiError(
        ErrorCode.INVALID_REQUEST,
        f"{path}: {message}" if path != "$" else message,
        {"path": path, "rule": str(err.validator)},
    )


def _scale_problem(name: str, value: Any) -> str:
    """A speed override's refusal in the words of its one check (planner.limits.check_scale), which
    ``pvtflow plan``'s options get too."""
    try:
        check_scale(name, value)
    except ValueError as exc:
        return str(exc)
    return f"{name} must be a number in (0, 1], got {value!r}"


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
