"""Planning as one call: a PlanInput in, a PlanOutput out, a PlanResult that says what happened.

This is the planner's front door (ruckig style): path, limits and timing compose behind it, and
no input, however bad, escapes as an exception.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import toppra.constraint as constraint
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.cartesian import CartesianResult, MoveKind, PoseSolver, ToolPath
from pvtflow.planner.ik import IkSolver
from pvtflow.planner.limits import JointLimits, check_max_jerk, check_scale
from pvtflow.planner.model import RobotModel
from pvtflow.planner.path import JointPath, PlanError, PlanResult
from pvtflow.planner.sequence import SequenceSolver
from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND
from pvtflow.planner.timing import DEFAULT_GRIDPOINTS, Trajectory, parameterize, parameterize_banded, timing_constraints

if TYPE_CHECKING:  # planner.jerk loads casadi: only a plan with a jerk limit does
    from pvtflow.planner.jerk import JerkTrajectory

# What a plan can end with: the joint-space outcomes, and the refusals of tool poses.
PlanOutcome = PlanResult | CartesianResult
# what a caller does with the S-curve floor while the jerk-limited solve runs (``Planner.plan``): the
# floor and its details (``max_jerk``)
FloorHook = Callable[["JerkTrajectory", dict[str, object]], None]


def jerk_scale(velocity_scale: float, acceleration_scale: float) -> float:
    """The factor a speed override puts on the jerk limit: ``velocity_scale * acceleration_scale``.

    Why the product: a motion slowed down in time by k has its velocity times k, its acceleration
    times k^2 and its jerk times k^3; the override (velocity_scale = k, acceleration_scale = k^2)
    then gives k^3, the jerk of that slowed motion. For any other pair it is at most 1 (it never
    loosens the limit), smaller with either factor, and follows both: a slower speed alone softens
    the jerk too, as a lower acceleration alone does.
    """
    return float(velocity_scale) * float(acceleration_scale)


def _scale(name: str, value: object) -> float:
    """``check_scale``'s answer as a PlanError (INVALID_INPUT, ``details["field"]``: which one)."""
    try:
        return check_scale(name, value)
    except ValueError as exc:
        raise PlanError(PlanResult.INVALID_INPUT, str(exc), field=name) from None


def jerk_details(jerky: JerkTrajectory) -> dict[str, object]:
    """A jerk-limited plan's details that its trajectory decides (``Planner.plan``)."""
    return {
        "solver": jerky.solver,
        "iterations": jerky.iterations,
        "time_scale": jerky.time_scale,
        # not the optimum where the deadline came first or torque between the solver's rows slowed it
        "optimal": jerky.optimal and not jerky.torque_slowed,
        "solver_finished": jerky.optimal,
        "torque_scale": jerky.torque_scale,
        "lower_bound_s": jerky.lower_bound,  # TOPP-RA's duration: no jerk-limited timing is shorter
        # the solver's grid (0: the S-curve floor, no solver's)
        "jerk_intervals": 0 if jerky.solver == "scurve" else len(jerky.gridpoints) - 1,
    }


def _max_jerk(value: object, dof: int) -> NDArray[np.float64]:
    """``check_max_jerk``'s answer as a PlanError (INVALID_INPUT, ``details["field"]``: max_jerk)."""
    try:
        return check_max_jerk("max_jerk", value, dof)
    except ValueError as exc:
        raise PlanError(PlanResult.INVALID_INPUT, str(exc), field="max_jerk") from None


def _speed_band(value: object) -> float:
    """A request's speed band in [0, 1) as a float (PlanError INVALID_INPUT, ``details["field"]``: speed_band)."""
    try:
        band = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        band = math.nan
    if not 0.0 <= band < 1.0:
        raise PlanError(PlanResult.INVALID_INPUT, f"speed_band must be in [0, 1), got {value!r}", field="speed_band")
    return band


@dataclass(frozen=True)
class PlanInput:
    """What changes from one plan to the next (the robot, its limits and the cell's constraints are
    the ``Planner``'s, fixed when it is built). ``waypoints`` (N, dof) in the limits' joint order;
    or, with ``poses`` (N, 7 tool poses: planner/cartesian.py), the one joint position the motion
    starts from, ``motion`` saying how the tool goes through the poses."""

    waypoints: ArrayLike
    poses: ArrayLike | None = None
    motion: str | MoveKind = MoveKind.LINEAR
    velocity_scale: float = 1.0  # speed override in (0, 1]: the joint velocity limits planned with
    acceleration_scale: float = 1.0  # the same for the joint acceleration limits
    max_jerk: ArrayLike | None = None  # joint units / s^3, one per joint (inf: unlimited); None: the planner's
    budget_ms: float | None = None  # the jerk-limited timing's deadline from the call's start; None: none
    # this plan's speed band (planner.speed_band), None: the planner's; a plan without a jerk limit only
    speed_band: float | None = None
    # the jerk-limited timing's grid at most this many intervals (None: planner.jerk.DEFAULT_JERK_INTERVALS)
    jerk_intervals: int | None = None
    # a motion sequence (planner/sequence.py: ptp, lin and circ items with blend radii) from the one
    # joint position in ``waypoints``; instead of poses
    sequence: Sequence[Any] | None = None


@dataclass(frozen=True)
class PlanOutput:
    result: PlanOutcome
    message: str = ""
    trajectory: Trajectory | JerkTrajectory | None = None
    planning_time: float = 0.0  # s, wall clock
    details: dict[str, object] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.result is PlanResult.OK


class Planner:
    """Plans for one robot and one set of limits; builds its toppra constraints once.

    ``Planner(limits, ...)`` holds what is fixed (ruckig style: settings once), ``plan(PlanInput)``
    what changes per request, and never raises: a refusal is a ``PlanOutput`` with its result. A
    request's speed override (``velocity_scale``,
    ``acceleration_scale``) plans with the joint velocity and acceleration limits scaled down: its
    constraints are built for that call (cheap: the constraints compute nothing until they see a
    path), and with the jerk limit times ``jerk_scale`` (their product). The TCP speed and torque
    limits stay as the cell sets them.

    Without a jerk limit, TOPP-RA's profile is flattened within ``speed_band`` (the path speed at
    most that fraction below the time-optimal one; 0, the default: none), for fewer records on the
    bus (``planner.speed_band``): motion time given for records, so only where the cell asks for it
    or its bus needs it; ``details``: ``speed_band`` and ``speed_band_cost`` (the duration over
    TOPP-RA's own, less 1) of a plan that was flattened.

    With a jerk limit (``max_jerk``: the cell's, or a request's, which replaces it), the TOPP-RA
    solution is the warm start of the jerk-limited timing along the same path (planner/jerk,
    casadi) under the same constraints; ``details``: ``topp_s`` and ``jerk_s`` (their shares of
    the planning time), ``solver``, ``iterations``, ``time_scale`` of the jerk-limited solve and
    the ``max_jerk`` it held.
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
        max_jerk: ArrayLike | None = None,
        speed_band: float = DEFAULT_SPEED_BAND,
    ) -> None:
        if not 0.0 <= speed_band < 1.0:
            raise ValueError(f"speed_band must be in [0, 1), got {speed_band}")
        self.speed_band = float(speed_band)
        self.limits = limits
        self.max_jerk = None if max_jerk is None else check_max_jerk("max_jerk", max_jerk, limits.dof)
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
        self.sequences = SequenceSolver(self.poses) if self.poses is not None else None

    def _scaled(self, velocity_scale: float, acceleration_scale: float) -> tuple[JointLimits, list[object]]:
        """The joint limits and TOPP-RA constraints of one plan under the speed override."""
        scales = [_scale("velocity_scale", velocity_scale), _scale("acceleration_scale", acceleration_scale)]
        if scales == [1.0, 1.0]:
            return self.limits, self.constraints
        limits = self.limits.scaled(*scales)
        return limits, timing_constraints(limits, *self._cell_constraints)

    def _jerk_limit(
        self, max_jerk: ArrayLike | None, velocity_scale: float = 1.0, acceleration_scale: float = 1.0
    ) -> NDArray[np.float64] | None:
        """The jerk limit of one plan: the request's, else the cell's, times the speed override's
        ``jerk_scale``; None where no joint has one."""
        jerk = self.max_jerk if max_jerk is None else _max_jerk(max_jerk, self.limits.dof)
        if jerk is None or not np.any(np.isfinite(jerk)):
            return None
        return jerk * jerk_scale(velocity_scale, acceleration_scale)

    def _timed(
        self,
        path: JointPath,
        limits: JointLimits,
        constraints: list[constraint.Constraint],
        max_jerk: NDArray[np.float64] | None,
        deadline: float | None = None,
        speed_band: float | None = None,
        gridpoints: int | None = None,
        jerk_intervals: int | None = None,
        on_floor: FloorHook | None = None,
    ) -> tuple[Trajectory | JerkTrajectory, dict[str, object]]:
        """TOPP-RA along ``path``, flattened within the speed band (``speed_band``, None: the
        planner's); with a jerk limit, the jerk-limited timing warm-started from TOPP-RA's own profile."""
        t0 = time.perf_counter()
        grid = self.gridpoints if gridpoints is None else gridpoints
        if max_jerk is None:
            band = self.speed_band if speed_band is None else _speed_band(speed_band)
            traj, ratio = parameterize_banded(path, limits, constraints, grid, band)
            return traj, ({"speed_band": band, "speed_band_cost": ratio - 1.0} if band > 0.0 else {})
        trajectory = parameterize(path, limits, constraints, grid)
        from pvtflow.planner.jerk import jerk_limited  # casadi: loaded by the first plan that needs it

        t1 = time.perf_counter()
        jerk_detail = [float(j) if np.isfinite(j) else None for j in max_jerk]  # None: that joint unlimited
        floor_hook = None if on_floor is None else lambda floor: on_floor(floor, {"max_jerk": jerk_detail})
        try:
            jerky = jerk_limited(path, limits, constraints, max_jerk, trajectory, jerk_intervals, deadline, floor_hook)
        except (ValueError, RuntimeError) as exc:  # PlanError is a ValueError: passed on as it is
            if isinstance(exc, PlanError):
                raise
            raise PlanError(PlanResult.INFEASIBLE, f"the jerk-limited timing failed: {exc}") from None
        details: dict[str, object] = {
            "topp_s": t1 - t0,
            "jerk_s": time.perf_counter() - t1,
            "max_jerk": jerk_detail,
            **jerk_details(jerky),
        }
        return jerky, details

    def plan(self, inp: PlanInput, on_floor: FloorHook | None = None) -> PlanOutput:
        """Time-optimal rest-to-rest trajectory through the waypoints (or of the tool through the
        poses), or the reason there is none.

        ``velocity_scale``, ``acceleration_scale`` in (0, 1]: the joint velocity and acceleration
        limits are multiplied by them for this plan (INVALID_INPUT naming the field otherwise).
        ``max_jerk``: this plan's jerk limit, one per joint (None: the planner's, if any).
        ``budget_ms``: the jerk-limited timing is anytime, its answer due this long after the call
        (``details["optimal"]`` False where the deadline came first, ``solver_finished`` False too,
        or where the torque limits between the solver's rows slowed its answer by more than 0.1 %,
        ``torque_scale``; ``lower_bound_s`` TOPP-RA's duration, the gap's other end). Time alone
        never refuses a plan here.

        ``on_floor(trajectory, details)``: with a jerk limit and a deadline, called with the S-curve floor
        and the ``max_jerk`` detail where the floor is computed while a solver runs (``planner.jerk``), so
        that the caller's work on it is done by the time the answer is; not for a sequence."""
        scales = (inp.velocity_scale, inp.acceleration_scale, inp.max_jerk)
        options = (inp.speed_band, inp.jerk_intervals)
        deadline = None
        if inp.budget_ms is not None:
            deadline = time.perf_counter() + max(0.0, float(inp.budget_ms)) / 1000.0
        if inp.sequence is not None:
            return self._plan_sequence(inp.waypoints, inp.sequence, *scales, deadline, *options)
        if inp.poses is not None:
            return self._plan_poses(inp.waypoints, inp.poses, inp.motion, *scales, deadline, *options, on_floor)
        return self._plan_waypoints(inp.waypoints, *scales, deadline, *options, on_floor)

    def _plan_waypoints(
        self,
        waypoints: ArrayLike,
        velocity_scale: float,
        acceleration_scale: float,
        max_jerk: ArrayLike | None,
        deadline: float | None = None,
        speed_band: float | None = None,
        jerk_intervals: int | None = None,
        on_floor: FloorHook | None = None,
    ) -> PlanOutput:
        start = time.perf_counter()
        try:
            limits, constraints = self._scaled(velocity_scale, acceleration_scale)
            jerk = self._jerk_limit(max_jerk, velocity_scale, acceleration_scale)
            path = JointPath(waypoints, limits)
            trajectory, details = self._timed(
                path, limits, constraints, jerk, deadline, speed_band, None, jerk_intervals, on_floor
            )
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - start, dict(exc.details))
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - start, details)

    def _plan_poses(
        self,
        start: ArrayLike,
        poses: ArrayLike,
        motion: str | MoveKind,
        velocity_scale: float,
        acceleration_scale: float,
        max_jerk: ArrayLike | None,
        deadline: float | None = None,
        speed_band: float | None = None,
        jerk_intervals: int | None = None,
        on_floor: FloorHook | None = None,
    ) -> PlanOutput:
        """The tool from joint positions ``start`` through ``poses`` (straight lines or joint moves:
        planner/cartesian.py). ``details["ik_s"]``: the inverse kinematics' share of the planning
        time [s], ``details["samples"]``: the joint samples it made."""
        t0 = time.perf_counter()
        if self.poses is None:
            return PlanOutput(PlanResult.INVALID_INPUT, "tool poses need the robot model and its tcp_frame")
        try:
            kind = MoveKind(motion)
        except ValueError:
            choices = ", ".join(m.value for m in MoveKind)
            return PlanOutput(PlanResult.INVALID_INPUT, f"motion must be one of {choices}, got {motion!r}")
        try:
            limits, constraints = self._scaled(velocity_scale, acceleration_scale)
            jerk = self._jerk_limit(max_jerk, velocity_scale, acceleration_scale)
            tool: ToolPath = self.poses.solve(start, poses, kind)
            t_ik = time.perf_counter() - t0
            trajectory, timed = self._timed(
                tool.path, limits, constraints, jerk, deadline, speed_band, None, jerk_intervals, on_floor
            )
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - t0, dict(exc.details))
        details: dict[str, object] = {"ik_s": t_ik, "samples": len(tool.path.points), **timed}
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - t0, details)

    def _plan_sequence(
        self,
        start: ArrayLike,
        items: Sequence[Any],
        velocity_scale: float,
        acceleration_scale: float,
        max_jerk: ArrayLike | None,
        deadline: float | None = None,
        speed_band: float | None = None,
        jerk_intervals: int | None = None,
    ) -> PlanOutput:
        """A motion sequence from joint positions ``start`` (planner/sequence.py), timed once as a
        whole. ``details["items"]``: per item its index, label and start and end time [s] on the
        trajectory (an item ends at its goal, or halfway through its blend)."""
        t0 = time.perf_counter()
        if self.sequences is None:
            return PlanOutput(PlanResult.INVALID_INPUT, "a sequence needs the robot model and its tcp_frame")
        try:
            limits, constraints = self._scaled(velocity_scale, acceleration_scale)
            jerk = self._jerk_limit(max_jerk, velocity_scale, acceleration_scale)
            solved = self.sequences.solve(start, items)
            t_ik = time.perf_counter() - t0
            # every item gets the grid a plan of its own gets (one grid for the whole sequence
            # coarsens every item's timing: bench/sequence.py)
            grid = self.gridpoints * len(solved.item_end)
            # the grid refines on both sides of an exact stop as of a kink (there the path turns
            # within the samples next to the goal: a coarse grid there slows the whole motion down)
            path = solved.tool.path
            stops = [path.waypoint_s[k] for k, r in zip(solved.item_end, solved.radii, strict=True) if r == 0.0]
            path.kinks = np.union1d(path.kinks, np.array(stops[:-1], dtype=float))
            trajectory, timed = self._timed(
                solved.tool.path, limits, constraints, jerk, deadline, speed_band, grid, jerk_intervals
            )
        except PlanError as exc:
            return PlanOutput(exc.result, exc.message, None, time.perf_counter() - t0, dict(exc.details))
        times = np.asarray(trajectory.waypoint_times, dtype=float)
        spans, begin = [], 0.0
        for i, end in enumerate(solved.item_end):
            label = items[i].get("label") if isinstance(items[i], dict) else None
            spans.append({"index": i, "label": label, "start_s": begin, "end_s": float(times[end])})
            begin = float(times[end])
        spans[-1]["end_s"] = float(trajectory.duration)
        details: dict[str, object] = {
            "ik_s": t_ik,
            "samples": len(solved.tool.path.points),
            "items": spans,
            **timed,
        }
        return PlanOutput(PlanResult.OK, "", trajectory, time.perf_counter() - t0, details)
