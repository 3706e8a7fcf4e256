"""The requests as the service takes them: each payload checked (schema, then values) and parsed
into a frozen dataclass in the cell's joint order."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.cartesian import MoveKind, check_poses
from pvtflow.planner.limits import JointLimits, check_max_jerk, check_scale
from pvtflow.planner.path import PlanError
from pvtflow.planner.plan import PlanInput
from pvtflow.service.api.schema_check import PLAN_SCALES, check_schema
from pvtflow.service.api.wire import ApiError, ErrorCode, PlanStart


@dataclass(frozen=True)
class PlanRequest:
    waypoints: NDArray[np.float64]  # (N, dof) in the cell's joint order; (0, dof) for poses
    start: PlanStart = PlanStart.CURRENT  # JOINTS: poses from start_joints
    tolerance_qc: float | None = None
    label: str | None = None
    include_program: bool = False
    velocity_scale: float = 1.0  # speed override in (0, 1] (planner.limits.check_scale)
    acceleration_scale: float = 1.0
    poses: NDArray[np.float64] | None = None  # (N, 7), unit quaternions
    motion: MoveKind = MoveKind.LINEAR
    start_joints: NDArray[np.float64] | None = None  # (dof,) in the cell's joint order
    max_jerk: NDArray[np.float64] | None = None  # (dof,) in the cell's joint order; None: the cell's
    budget_ms: float | None = None  # the plan's deadline; None: the cell's planning.budget_ms
    # a motion sequence's items as the request has them (planner/sequence.py checks them), from
    # start_joints or the start; targets in the cell's joint order
    sequence: list[dict[str, Any]] | None = None

    def plan_input(self, start: NDArray[np.float64], **scales: Any) -> PlanInput:
        """The planner's input of a poses or sequence request from joint positions ``start``."""
        if self.sequence is not None:
            return PlanInput(start, sequence=self.sequence, **scales)
        return PlanInput(start, self.poses, self.motion, **scales)


@dataclass(frozen=True)
class ExecuteRequest:
    plan_id: str | None = None
    program: dict[str, Any] | None = None
    label: str | None = None
    wait: bool = False
    approach: bool = False  # move to the program's start first (service/approach.py), never implicitly
    queue: bool = False  # while a motion runs: start where it ends, with no stop in between (axes.master.run_queue)


@dataclass(frozen=True)
class ValidateRequest:
    plan_id: str | None = None
    program: dict[str, Any] | None = None


class StopMode(StrEnum):
    """``stop``'s mode: on the planned path (every axis at rest on the same SYNC), or the fastest, off it."""

    PATH = "path"
    QUICK = "quick"


@dataclass(frozen=True)
class StopRequest:
    reason: str = "stop requested"
    mode: StopMode = StopMode.PATH


@dataclass(frozen=True)
class PauseRequest:
    reason: str = "pause requested"


@dataclass(frozen=True)
class ResumeRequest:
    wait: bool = False


@dataclass(frozen=True)
class OverrideRequest:
    scale: float


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
    if "poses" in data or "sequence" in data:
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
    start = PlanStart(data.get("start", PlanStart.CURRENT))
    if field_name == "target" and start is not PlanStart.HOME:
        start = PlanStart.CURRENT
    if start is PlanStart.FIRST and len(waypoints) < 2:
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
        budget_ms=data.get("budget_ms"),
        **_scales(data),
    )


def _scales(data: dict[str, Any]) -> dict[str, float]:
    """velocity_scale, acceleration_scale: the schema has refused what is not in (0, 1]; the
    planner's rule (planner.limits.check_scale), once more."""
    scales = {}
    for name in PLAN_SCALES:
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
    if "motion" in data and "sequence" in data:
        raise ApiError(
            ErrorCode.INVALID_REQUEST, "motion is for poses; a sequence's items name their own", {"path": "$.motion"}
        )
    sequence = None
    if "sequence" in data:
        sequence = [dict(item) for item in data["sequence"]]
        for i, item in enumerate(sequence):
            if "target" in item:
                target = item["target"]
                if len(target) != dof:
                    raise ApiError(
                        ErrorCode.WRONG_JOINT_COUNT,
                        f"$.sequence[{i}].target has {len(target)} values, the cell has {dof} joints",
                        {"path": f"$.sequence[{i}].target", "expected": dof, "got": len(target)},
                    )
                item["target"] = [float(target[k]) for k in order]
        poses = None
    try:
        if sequence is None:
            poses = check_poses(data["poses"])
    except PlanError as exc:
        i = exc.details.get("pose")
        path = f"$.poses[{i}]" if i is not None else "$.poses"
        raise ApiError(ErrorCode.INVALID_REQUEST, f"{path}: {exc.message}", {"path": path}) from None
    except OverflowError:
        raise ApiError(ErrorCode.NOT_FINITE, "$.poses: a number too large", {"path": "$.poses"}) from None
    start = data.get("start", PlanStart.CURRENT)
    start_joints = None
    if start == PlanStart.FIRST:
        raise ApiError(
            ErrorCode.INVALID_REQUEST,
            "with poses or a sequence, start is current or a list of joint values (first is for waypoints)",
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
        start = PlanStart.JOINTS
    return PlanRequest(
        np.empty((0, dof)),
        PlanStart(start),
        data.get("tolerance_qc"),
        data.get("label"),
        bool(data.get("include_program", False)),
        poses=poses,
        motion=MoveKind(data.get("motion", MoveKind.LINEAR)),
        sequence=sequence,
        start_joints=start_joints,
        max_jerk=_max_jerk(data, order),
        budget_ms=data.get("budget_ms"),
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
    return ExecuteRequest(
        data.get("plan_id"),
        data.get("program"),
        data.get("label"),
        bool(data.get("wait", False)),
        bool(data.get("approach", False)),
        bool(data.get("queue", False)),
    )


def parse_validate(data: Any) -> ValidateRequest:
    check_schema("validate", data, None)
    return ValidateRequest(data.get("plan_id"), data.get("program"))


def parse_stop(data: Any) -> StopRequest:
    check_schema("stop", data, None)
    return StopRequest(data.get("reason") or "stop requested", StopMode(data.get("mode", StopMode.PATH.value)))


def parse_pause(data: Any) -> PauseRequest:
    check_schema("pause", data, None)
    return PauseRequest(data.get("reason") or "pause requested")


def parse_resume(data: Any) -> ResumeRequest:
    check_schema("resume", data, None)
    return ResumeRequest(bool(data.get("wait", False)))


def parse_override(data: Any) -> OverrideRequest:
    check_schema("override", data, None)
    return OverrideRequest(float(data["scale"]))


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
