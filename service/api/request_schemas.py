"""The JSON Schema of every request: the one description of what a request may hold.

The service checks every request against it (service.api.schema_check), docs/API.md prints it; the
parts a reply shares with a request (a plan id, a program, the object every payload is) are here too.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pvtflow.planner.cartesian import POSE_LENGTH, QUATERNION_TOLERANCE, MoveKind
from pvtflow.service.api.wire import ID_PATTERN, MAX_RECENT, MAX_TEXT, MAX_WAYPOINTS, PlanStart

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def _vector(dof: int | None, description: str) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "array", "items": {"type": "number"}, "description": description}
    if dof is not None:
        schema["minItems"] = schema["maxItems"] = dof
    return schema


def object_schema(properties: dict[str, Any], required: Sequence[str] = (), **extra: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "object", "properties": properties, "additionalProperties": False}
    if required:
        out["required"] = list(required)
    out.update(extra)
    return out


PLAN_ID = {"type": "string", "pattern": ID_PATTERN, "description": "a plan id from a plan reply"}


_TEXT = {"type": "string", "maxLength": MAX_TEXT}


PROGRAM = {"type": "object", "description": "a PVT program (pvtflow.pvt-program JSON, docs/program-format)"}


_POSE = {
    "type": "array",
    "items": {"type": "number"},
    "minItems": POSE_LENGTH,
    "maxItems": POSE_LENGTH,
    "description": "[x, y, z, qx, qy, qz, qw]: the cell's tcp_frame in the robot's base frame (m; a unit quaternion)",
}
_POINT = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_SEQUENCE_ITEM = object_schema(
    {
        "motion": {
            "enum": ["ptp", "lin", "circ"],
            "description": "ptp: a straight line in joint space to target (or to pose's inverse kinematics); lin: the "
            "tool on a straight line to pose (orientation by slerp); circ: the tool on the arc through via (or about "
            "center) to pose",
        },
        "target": {"type": "array", "items": {"type": "number"}, "description": "ptp: the goal's joint values"},
        "pose": _POSE,
        "via": {**_POINT, "description": "circ: a point on the arc [x, y, z] (m)"},
        "center": {**_POINT, "description": "circ: the arc's center [x, y, z] (m)"},
        "blend_radius": {
            "type": "number",
            "minimum": 0,
            "default": 0,
            "description": "m: inside this sphere about the goal the tool leaves this item's path for the next "
            "one's without stopping; 0: it stops exactly at the goal; the last item's is ignored. Neighbouring "
            "spheres must not overlap (refused, never shrunk)",
        },
        "label": _TEXT,
    },
    required=["motion"],
)


def request_schema(name: str, dof: int | None = None) -> dict[str, Any]:
    """The JSON Schema of the request to queryable ``name`` on a cell of ``dof`` joints."""
    if name == "plan":
        body = object_schema(
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
                "sequence": {
                    "type": "array",
                    "minItems": 1,
                    "maxItems": MAX_WAYPOINTS,
                    "items": _SEQUENCE_ITEM,
                    "description": "a motion sequence (instead of waypoints, target or poses), from the start: "
                    "ptp, lin and circ items, each blended into the next inside its blend_radius sphere; one "
                    "plan, one program (docs/planning.md, Motion sequences)",
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
            oneOf=[
                {"required": ["waypoints"]},
                {"required": ["target"]},
                {"required": ["poses"]},
                {"required": ["sequence"]},
            ],
        )
    elif name == "validate":
        body = object_schema(
            {"plan_id": PLAN_ID, "program": PROGRAM}, oneOf=[{"required": ["plan_id"]}, {"required": ["program"]}]
        )
    elif name == "execute":
        body = object_schema(
            {
                "plan_id": PLAN_ID,
                "program": PROGRAM,
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
                "queue": {
                    "type": "boolean",
                    "default": False,
                    "description": "while a motion runs: run this one after it (and after the motions queued "
                    "before it) with no stop in between, from the SYNC after its last record; it must start "
                    "where that motion ends and be given before the drives' end record goes out (the drives' "
                    "master heartbeat watch before the end), else it is refused and nothing changes; with "
                    "nothing running it starts as without it. stop ends the running and every queued motion",
                },
            },
            oneOf=[{"required": ["plan_id"]}, {"required": ["program"]}],
        )
    elif name == "stop":
        body = object_schema(
            {
                "reason": _TEXT,
                "mode": {
                    "enum": ["path", "quick"],
                    "default": "path",
                    "description": "path: the rest of the path re-timed to rest within every limit, every axis at "
                    "rest on the same SYNC, the tool on the planned path (braking begins where the records the "
                    "drives hold end, within the cell's max_lookahead_ms); quick: every axis brakes on its own "
                    "deceleration at once, off the path (what faults and a lost SYNC use; also what a path stop "
                    "falls back to when its braking cannot be made in time)",
                },
            }
        )
    elif name == "pause":
        body = object_schema({"reason": _TEXT})
    elif name == "resume":
        body = object_schema(
            {
                "wait": {
                    "type": "boolean",
                    "default": False,
                    "description": "reply at the end of the motion (with its outcome) instead of at its start",
                }
            }
        )
    elif name == "override":
        body = object_schema(
            {
                "scale": {
                    "type": "number",
                    "minimum": 0.05,
                    "maximum": 1.0,
                    "description": "the fraction of the planned path speed the rest of the running motion runs at "
                    "(1.0: the planned timing again); effective within the cell's max_lookahead_ms",
                }
            },
            required=["scale"],
        )
    elif name == "status":
        body = object_schema(
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
        body = object_schema({})
    elif name == "home":
        body = object_schema(
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
