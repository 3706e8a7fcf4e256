"""A request checked against its JSON Schema, the first problem worded as the one ``ApiError`` it answers.

The common plan request takes a plain-Python path (a subset of the schema, never a second
definition of it); anything else goes to jsonschema, whose most telling error becomes the reply.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError

from pvtflow.planner.cartesian import POSE_LENGTH
from pvtflow.planner.limits import check_scale
from pvtflow.service.api.request_schemas import request_schema
from pvtflow.service.api.wire import MAX_TEXT, MAX_WAYPOINTS, ApiError, ErrorCode, _short


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


PLAN_SCALES = ("velocity_scale", "acceleration_scale")


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
        elif name in PLAN_SCALES:
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
    elif list(err.absolute_path) in ([s] for s in PLAN_SCALES):
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
