"""Planning as one call: a PlanInput in, a PlanOutput out, a PlanResult that says what happened.

This is the planner's front door (ruckig style): path, limits and timing compose behind it, and
no input, however bad, escapes as an exception.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from planner.limits import JointLimits, check_scale
from planner.model import RobotModel
from planner.path import JointPath, PlanError, PlanResult
from planner.timing import DEFAULT_GRIDPOINTS, Trajectory, parameterize, timing_constraints


def _scale(name: str, value: object) -> float:
    """``check_scale``'s answer as a PlanError (INVALID_INPUT, ``details["field"]``: which one)."""
    try:
        return check_scale(name, value)
    except ValueError as exc:
        raise PlanError(PlanResult.INVALID_INPUT, str(exc), field=name) from None


@dataclass(frozen=True)
class PlanInput:
    """Everything a plan depends on. Waypoints are (N, dof) in the limits' joint order."""

    waypoints: ArrayLike
    limits: JointLimits
    model: RobotModel | None = None
    tcp_frame: str | None = None
    max_tcp_speed: float | None = None
    torque_limits: bool = False
    gridpoints: int | None = None  # TOPP-RA grid intervals; None: DEFAULT_GRIDPOINTS
    velocity_scale: float = 1.0  # speed override in (0, 1]: the joint velocity limits planned with
    acceleration_scale: float = 1.0  # the same for the joint acceleration limits


@dataclass(frozen=True)
class PlanOutput:
    result: PlanResult
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
    ) -> None:
        self.limits = limits
        self.gridpoints = DEFAULT_GRIDPOINTS if gridpoints is None else int(gridpoints)
        if self.gridpoints < 2:
            raise ValueError(f"gridpoints must be >= 2, got {self.gridpoints}")
        if max_tcp_speed is not None and not (np.isfinite(max_tcp_speed) and max_tcp_speed > 0):
            raise ValueError(f"max_tcp_speed must be a positive number, got {max_tcp_speed}")
        self.constraints = timing_constraints(limits, model, torque_limits, tcp_frame, max_tcp_speed)
        self._cell_constraints = (model, torque_limits, tcp_frame, max_tcp_speed)

    def plan(self, waypoints: ArrayLike, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> PlanOutput:
        """Time-optimal rest-to-rest trajectory through the waypoints, or the reason there is none.

        ``velocity_scale``, ``acceleration_scale`` in (0, 1]: the joint velocity and acceleration
        limits are multiplied by them for this plan (INVALID_INPUT naming the field otherwise)."""
        start = time.perf_counter()
        try:
            scales = [_scale("velocity_scale", velocity_scale), _scale("acceleration_scale", acceleration_scale)]
            limits, constraints = self.limits, self.constraints
            if scales != [1.0, 1.0]:
                limits = self.limits.scaled(*scales)
                constraints = timing_constraints(limits, *self._cell_constraints)
            path = JointPath(waypoints, limits)
            trajectory = parameterize(path, limits, constraints, self.gridpoints)
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - start, dict(exc.details))
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - start)


def plan(inp: PlanInput) -> PlanOutput:
    """Plan once: a Planner for ``inp``'s limits and constraints, applied to its waypoints."""
    start = time.perf_counter()
    try:
        planner = Planner(inp.limits, inp.model, inp.tcp_frame, inp.max_tcp_speed, inp.torque_limits, inp.gridpoints)
    except ValueError as exc:
        return PlanOutput(PlanResult.INVALID_INPUT, str(exc), None, time.perf_counter() - start)
    out = planner.plan(inp.waypoints, inp.velocity_scale, inp.acceleration_scale)
    return PlanOutput(out.result, out.message, out.trajectory, time.perf_counter() - start, out.details)
