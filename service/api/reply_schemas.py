"""The JSON Schema of every reply and publication: what the service answers and publishes.

The tests check every reply against it; docs/API.md prints it.
"""

from __future__ import annotations

from typing import Any

from pvtflow.service.api.request_schemas import PLAN_ID, PROGRAM, SCHEMA_DIALECT, object_schema
from pvtflow.service.api.wire import ID_PATTERN, CellState, ErrorCode, RunState

_MOTION_ID = {"type": "string", "pattern": ID_PATTERN}


_INT_OR_NULL = {"type": ["integer", "null"]}


_NUM_OR_NULL = {"type": ["number", "null"]}


_STR_OR_NULL = {"type": ["string", "null"]}


_AXIS_STATUS = object_schema(
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
        "queued_after": {"type": ["string", "null"], "description": "queued: the motion it ran on from"},
    },
}


_BRAKING = {
    "type": ["object", "null"],
    "description": "the on-path braking: begun_ms / ended_ms in program time (ms from the start SYNC), begun_sync / "
    "ended_sync the SYNCs; null for a quick stop",
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
                "plan_id": PLAN_ID,
                "cell": {"type": "string"},
                "joint_names": {"type": "array", "items": {"type": "string"}},
                "duration_s": {"type": "number"},
                "waypoints": {"type": "integer"},
                "start": {"type": "array", "items": {"type": "number"}},
                "end": {"type": "array", "items": {"type": "number"}},
                "records": {"type": "object", "additionalProperties": {"type": "integer"}},
                "validation": {"type": "object"},
                "timing_ms": {"type": "object"},
                "program": PROGRAM,
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
                "state": {"enum": [RunState.RUNNING.value, RunState.ENDED.value, RunState.QUEUED.value]},
                "duration_ms": {"type": "integer"},
                "start_sync": _INT_OR_NULL,
                "outcome": {"type": ["object", "null"]},
                "queued_after": {
                    "type": ["string", "null"],
                    "description": "a queued motion: the motion it runs on from (execute with queue)",
                },
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
                "queued": {
                    "type": "array",
                    "items": _MOTION_ID,
                    "description": "the queued motions it ended before they began",
                },
                "axes": {"type": "array", "items": _AXIS_STATUS},
                "mode": {"enum": ["path", "quick"], "description": "how the motion was stopped"},
                "braking": _BRAKING,
                "fallback": {
                    "type": ["string", "null"],
                    "description": "why a path stop was made the quick way (its braking could not be made in time)",
                },
                "ended_pause": {"type": "string", "description": "the paused motion this stop ended"},
            },
        }
    elif name == "pause":
        body = {
            "type": "object",
            "required": ["paused", "motion_id", "braking", "remaining", "axes"],
            "properties": {
                "paused": {"type": "boolean", "description": "false: a fault or the end came first (see outcome)"},
                "motion_id": {"type": "string"},
                "braking": _BRAKING,
                "fallback": {"type": ["string", "null"], "description": "why it was stopped the quick way instead"},
                "remaining": {
                    "type": ["number", "null"],
                    "description": "the share of the motion's path (in program time) still to go",
                },
                "outcome": {"type": ["object", "null"]},
                "axes": {"type": "array", "items": _AXIS_STATUS},
            },
        }
    elif name == "resume":
        body = {
            "type": "object",
            "required": ["motion_id", "resumed", "state", "duration_ms"],
            "properties": {
                "motion_id": _MOTION_ID,
                "resumed": {"type": "string", "description": "the paused motion it continues"},
                "plan_id": _STR_OR_NULL,
                "label": _STR_OR_NULL,
                "state": {"enum": [RunState.RUNNING.value, RunState.ENDED.value]},
                "duration_ms": {"type": "integer"},
                "start_sync": _INT_OR_NULL,
                "outcome": {"type": ["object", "null"]},
            },
        }
    elif name == "override":
        body = {
            "type": "object",
            "required": ["motion_id", "scale", "from_ms", "duration_ms"],
            "properties": {
                "motion_id": _MOTION_ID,
                "scale": {"type": "number", "description": "the scale the rest of the motion now runs at"},
                "limited": {
                    "type": ["string", "null"],
                    "description": "why the scale asked for could not be made and the lower one runs instead "
                    "(e.g. its records would leave 0x60C5 or the jerk limit); null: made as asked",
                },
                "from_ms": {"type": "number", "description": "program time (ms) from which the new speed applies"},
                "from_sync": {"type": "integer", "description": "the SYNC from which it applies"},
                "duration_ms": {"type": "integer", "description": "the motion's program time to its end, now"},
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
                "item": {
                    "type": ["object", "null"],
                    "description": "the item of a motion sequence running now (index, label); null otherwise",
                },
                "queue": {
                    "type": "array",
                    "items": {"type": "object"},
                    "description": "the motions queued after the running one, in order (as the execute reply)",
                },
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
                "override": {
                    "type": ["number", "null"],
                    "description": "the speed override the running motion runs at (1.0: as planned); null: none runs",
                },
                "paused": {
                    "type": ["object", "null"],
                    "description": "state paused: the paused motion (motion_id) and the share of its path left "
                    "(remaining)",
                },
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
