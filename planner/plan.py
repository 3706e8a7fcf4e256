"""Planning as one call: a PlanInput in, a PlanOutput out, a PlanResult that says what happened.

This is the planner's front door (ruckig style): path, limits and timing compose behind it, and
no input, however bad, escapes as an exception.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from planner.cartesian import CartesianResult, Motion, PoseSolver, ToolPath
from planner.ik import IkSolver
from planner.limits import JointLimits, check_scale
from planner.model import RobotModel
from planner.path import JointPath, PlanError, PlanResult
from planner.timing import DEFAULT_GRIDPOINTS, Trajectory, parameterize, timing_constraints

# What a plan can end with: the joint-space outcomes, and the refusals of tool poses.
PlanOutcome = PlanResult | CartesianResult


def _scale(name: str, value: object) -> float:
    """``check_scale``'s answer as a PlanError (INVALID_INPUT, ``details["field"]``: which one)."""
    try:
        return check_scale(name, value)
    except ValueError as exc:
        raise PlanError(PlanResult.INVALID_INPUT, str(exc), field=name) from None


@dataclass(frozen=True)
class PlanInput:
    """Everything a plan depends on. Waypoints are (N, dof) in the limits' joint order; or, with
    ``poses`` (N, 7 tool poses: planner/cartesian.py), ``waypoints`` is the one joint position the
    motion starts from and ``motion`` says how the tool goes through the poses."""

    waypoints: ArrayLike
    limits: JointLimits
    model: RobotModel | None = None
    tcp_frame: str | None = None
    max_tcp_speed: float | None = None
    torque_limits: bool = False
    gridpoints: int | None = None  # TOPP-RA grid intervals; None: DEFAULT_GRIDPOINTS
    velocity_scale: float = 1.0  # speed override in (0, 1]: the joint velocity limits planned with
    acceleration_scale: float = 1.0  # the same for the joint acceleration limits
    max_tcp_angular_speed: float | None = None  # rad/s
    poses: ArrayLike | None = None
    motion: str = Motion.LINEAR.value


@dataclass(frozen=True)
class PlanOutput:
    result: PlanOutcome
    message: str = ""
    trajectory: Trajectory | None = None
    planning_time: float = 0.0  # s, wall clock
    details: dict[str, object] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.result is PlanResult.OK


class Planner:
    """Plans for one robot and one set of limits; builds its toppra constraints once.

    ``plan(waypoints)`` is what a service calls per request; the module-level ``plan(PlanInput)``
    is the same for a one-off call. A request's speed override (``velocity_scale``,
    ``acceleration_scale``) plans with the joint velocity and acceleration limits scaled down: its
    constraints are built for that call (cheap: the constraints compute nothing until they see a
    path). The TCP speed and torque limits stay as the cell sets them.
    """

    def __init__(
        self,
        limits: JointLimits,
        model: RobotModel | None = None,
        tcp_frame: str | None = None,
        max_tcp_speed: float | None = None,
        torque_limits: bool = False,
        gridpoints: int | None = None,
        max_tcp_angular_speed: float | None = None,
    ) -> None:
        self.limits = limits
        self.gridpoints = DEFAULT_GRIDPOINTS if gridpoints is None else int(gridpoints)
        if self.gridpoints < 2:
            raise ValueError(f"gridpoints must be >= 2, got {self.gridpoints}")
        for name, value in (("max_tcp_speed", max_tcp_speed), ("max_tcp_angular_speed", max_tcp_angular_speed)):
            if value is not None and not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")
        self.constraints = timing_constraints(
            limits, model, torque_limits, tcp_frame, max_tcp_speed, max_tcp_angular_speed
        )
        self._cell_constraints = (model, torque_limits, tcp_frame, max_tcp_speed, max_tcp_angular_speed)
        # tool poses need the robot and its tool frame
        self.poses: PoseSolver | None = None
        if model is not None and tcp_frame is not None:
            self.poses = PoseSolver(IkSolver(model, tcp_frame, limits.lower, limits.upper), limits)

    def _scaled(self, velocity_scale: float, acceleration_scale: float) -> tuple[JointLimits, list[object]]:
        """The joint limits and TOPP-RA constraints of one plan under the speed override."""
        scales = [_scale("velocity_scale", velocity_scale), _scale("acceleration_scale", acceleration_scale)]
        if scales == [1.0, 1.0]:
            return self.limits, self.constraints
        limits = self.limits.scaled(*scales)
        return limits, timing_constraints(limits, *self._cell_constraints)

    def plan(self, waypoints: ArrayLike, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> PlanOutput:
        """Time-optimal rest-to-rest trajectory through the waypoints, or the reason there is none.

        ``velocity_scale``, ``acceleration_scale`` in (0, 1]: the joint velocity and acceleration
        limits are multiplied by them for this plan (INVALID_INPUT naming the field otherwise)."""
        start = time.perf_counter()
        try:
            limits, constraints = self._scaled(velocity_scale, acceleration_scale)
            path = JointPath(waypoints, limits)
            trajectory = parameterize(path, limits, constraints, self.gridpoints)
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - start, dict(exc.details))
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - start)

    def plan_poses(
        self,
        start: ArrayLike,
        poses: ArrayLike,
        motion: str | Motion = Motion.LINEAR,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
    ) -> PlanOutput:
        """Time-optimal rest-to-rest trajectory of the tool from joint positions ``start`` through
        ``poses`` (straight lines or joint moves: planner/cartesian.py), or the reason there is none.
        ``details["ik"]``: the inverse kinematics' share of the planning time [s], and the number of
        joint samples it made."""
        t0 = time.perf_counter()
        if self.poses is None:
            return PlanOutput(PlanResult.INVALID_INPUT, "tool poses need the robot model and its tcp_frame")
        try:
            kind = Motion(motion)
        except ValueError:
            choices = ", ".join(m.value for m in Motion)
            return PlanOutput(PlanResult.INVALID_INPUT, f"motion must be one of {choices}, got {motion!r}")
        try:
            limits, constraints = self._scaled(velocity_scale, acceleration_scale)
            tool: ToolPath = self.poses.solve(start, poses, kind)
            t_ik = time.perf_counter() - t0
            trajectory = parameterize(tool.path, limits, constraints, self.gridpoints)
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - t0, dict(exc.details))
        details: dict[str, object] = {"ik_s": t_ik, "samples": len(tool.path.points)}
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - t0, details)


def plan(inp: PlanInput) -> PlanOutput:
    """Plan once: a Planner for ``inp``'s limits and constraints, applied to its waypoints (or poses)."""
    start = time.perf_counter()
    try:
        planner = Planner(
            inp.limits,
            inp.model,
            inp.tcp_frame,
            inp.max_tcp_speed,
            inp.torque_limits,
            inp.gridpoints,
            inp.max_tcp_angular_speed,
        )
    except ValueError as exc:
        return PlanOutput(PlanResult.INVALID_INPUT, str(exc), None, time.perf_counter() - start)
    if inp.poses is not None:
        out = planner.plan_poses(inp.waypoints, inp.poses, inp.motion, inp.velocity_scale, inp.acceleration_scale)
    else:
        out = planner.plan(inp.waypoints, inp.velocity_scale, inp.acceleration_scale)
    return PlanOutput(out.result, out.message, out.trajectory, time.perf_counter() - start, out.details)
