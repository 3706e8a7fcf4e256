"""What goes on the wire: key expressions, the error codes a request is refused with, JSON payloads
(NaN and infinities refused), the limits on requests, and the states a cell reports."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from enum import StrEnum
from typing import Any

API_VERSION = 1


PREFIX = "pvtflow"


QUERYABLES = ("plan", "validate", "execute", "stop", "status", "recover", "home", "pause", "resume", "override")


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
    TIMEOUT = "timeout"  # the plan was not done within its budget_ms (for another reason than the jerk solve)
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
    ErrorCode.TIMEOUT: "The plan was not done within its budget_ms (the request's, else the cell's "
    "planning.budget_ms) for another reason than the jerk-limited timing's solve, which answers in time with its "
    "best so far (optimal: false): inverse kinematics, TOPP-RA, knots or validation took too long. Nothing was kept "
    "(details.budget_ms).",
    ErrorCode.PLAN_FAILED: "The planner found no motion through these waypoints or poses (details.result: "
    "repeated_waypoint, path_out_of_limits, infeasible, ... or program_error; for poses also unreachable, "
    "singular or joint_limit, with details.pose, the pose the line leads to, and details.fraction, how far "
    "along it).",
    ErrorCode.VALIDATION_FAILED: "The program breaks its drives' rules (details.report is the validator's "
    "report): nothing was sent.",
    ErrorCode.BUSY: "A motion is running on this cell (details.motion_id). One motion at a time: stop it or "
    "wait for its end.",
    ErrorCode.START_MISMATCH: "The axes are not where the program starts (they moved since it was planned): "
    "plan again from the current position, or execute with approach: true.",
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

    def line(self) -> str:
        """``CODE: MESSAGE``, as every command prints a refusal (``pvtflow request`` prints a reply's so)."""
        return f"{self.code.value}: {self.message}"


def check_cell_name(cell: str) -> str:
    """A cell name must be one key-expression chunk (no '/', '*', '$', '?', '#')."""
    if not _KEY_CHUNK.match(cell):
        raise ValueError(f"cell name {cell!r} cannot be a zenoh key chunk: use letters, digits, '_', '-', '.'")
    return cell


def key(cell: str, name: str) -> str:
    """``pvtflow/<cell>/<name>``; ``cell`` may be ``*`` for a client addressing every cell."""
    return f"{PREFIX}/{cell}/{name}"


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


class CellState(StrEnum):
    """The cell as the service reports it (``state`` publication, ``status``)."""

    IDLE = "idle"
    MOVING = "moving"
    STOPPING = "stopping"
    FAULT = "fault"
    HOMING = "homing"
    PAUSED = "paused"  # a motion stopped on its path by ``pause``: ``resume`` continues it, ``stop`` ends it


class RunState(StrEnum):
    """Where a motion or a homing is (``state`` of their summaries and of the journal's entries)."""

    RUNNING = "running"
    ENDED = "ended"
    INTERRUPTED = "interrupted"  # journaled without an outcome: the service stopped while it ran
    QUEUED = "queued"  # accepted after the running motion (execute with queue), its start not reached yet

    @classmethod
    def of(cls, ended: bool, running: bool = True) -> RunState:
        return cls.ENDED if ended else (cls.RUNNING if running else cls.INTERRUPTED)


class PlanStart(StrEnum):
    """Where a plan request's motion starts (``start``)."""

    CURRENT = "current"  # where the axes stand
    FIRST = "first"  # the first waypoint (waypoints only)
    HOME = "home"  # the cell's home position
    JOINTS = "joints"  # the request's list of joint values (poses only; never on the wire as a word)


def _short(message: str, limit: int = 160) -> str:
    return message if len(message) <= limit else message[: limit - 3] + "..."
