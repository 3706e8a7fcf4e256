"""Time-optimal parameterization of a joint path with TOPP-RA, and the trajectory it gives.

toppra solves for the path velocity s'(s) on a grid under the joint velocity and acceleration
limits (and, where the robot has them, joint torques through Pinocchio's RNEA and a TCP speed
limit through the frame Jacobian). Between gridpoints the path acceleration s'' is constant, so
the trajectory here is exact for that profile ("constant acceleration" parametrizer).

Torque and TCP speed need Pinocchio at every sample: those calls are batched (one RNEA call for
a whole grid), and torque limits, which rarely bind, are checked on the result of a solve without
them before being solved with (see ``parameterize``).

TOPP-RA enforces the constraints at the gridpoints. Between them the joint velocity and
acceleration can exceed the limits by a hair; the trajectory is checked afterwards (exactly: at
both ends of every interval and at the peaks inside it) and, where needed, slowed down uniformly by
the smallest factor that brings it inside (reported as ``time_scale``). That keeps the result
honest on a coarse, fast grid. Joint torque the same way (``TorqueCheck``): the collocation holds
it at each gridpoint with the s'' of the interval after it, so the end of the interval before (a
binding arm6 path: 2.6 % over) is checked too, bounded from the next gridpoint's torque by the mass
matrix's bound where that keeps it well inside (no RNEA), each interval's middle where an end is
near a limit, and the motion slowed by the exact factor (about 0.25 ms of Pinocchio per arm6
plan: a limit is a limit).

With ``speed_band``, the profile is then flattened (``planner.speed_band``: s'' constant over spans
of several gridpoints, the path speed at most that fraction below TOPP-RA's): fewer acceleration
switches, fewer records. It is checked the same way; where the cell has torque limits and the
flattened profile does not hold them at the gridpoints, TOPP-RA's own is kept.

The pieces, as toppra splits them: ``planner.constraints`` (the constraints),
``planner.topp`` (the algorithm), ``planner.trajectory`` (the trajectory and its check);
``parameterize`` here puts them together.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import toppra.constraint as constraint
from numba import njit
from numpy.typing import NDArray

from pvtflow.planner.constraints import (
    IntervalJointAccelerationConstraint,
    IntervalJointVelocityConstraint,
    RneaJointTorqueConstraint,
    TcpAngularSpeedConstraint,
    TcpSpeedConstraint,
    TorqueCheck,
    middles_warm_up,
    timing_constraints,
)
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError, PlanResult, not_a_knot
from pvtflow.planner.slowdown import SLOWDOWN_MARGIN, slowdown
from pvtflow.planner.speed_band import flattened
from pvtflow.planner.topp.lean import LeanTOPPRA
from pvtflow.planner.trajectory import Trajectory

# the default plan within 1.005x (mean) and 1.01x (max) of the 3000-gridpoint optimum: 140 gave a mean
# of 1.0052, 160 gives 1.0042 and max 1.0064 for 0.03 ms more per plan (bench/RESULTS.md, "Issue 39 item 1")
DEFAULT_GRIDPOINTS = 160


# Starting from and stopping at rest is where a coarse grid loses most of its time (the profile
# s'(s) ~ sqrt(s) there is far from what one constant s'' per interval can follow): the first and
# last uniform intervals are split geometrically. So are the intervals on both sides of a kink (a
# waypoint where the path's second derivative jumps, ``JointPath.kinks``): where the curvature
# jumps up, holding the acceleration takes a burst of s'' that one constant s'' over a whole
# interval turns into a near stop.
END_REFINEMENT = 0.5 ** np.arange(1, 7)


def make_gridpoints(path: JointPath, n: int) -> NDArray[np.float64]:
    """n uniform intervals, every waypoint, and a geometric refinement towards both ends and both
    sides of every kink."""
    length = path.length
    return _gridpoints(length, n, np.linspace(0.0, length, n + 1), path.waypoint_s, path.kinks, END_REFINEMENT)


@njit(cache=True)
def _gridpoints(
    length: float,
    n: int,
    uniform: NDArray[np.float64],
    waypoint_s: NDArray[np.float64],
    kinks: NDArray[np.float64],
    refinement: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``make_gridpoints``: the union of the uniform points, the waypoints and the refinements (at
    h * refinement from both ends and on both sides of every kink, inside the path), sorted, less
    the slivers it leaves."""
    h = length / n
    m = len(refinement)
    points = np.empty(len(uniform) + len(waypoint_s) + 2 * m * (1 + len(kinks)))
    k = 0
    for v in uniform:
        points[k] = v
        k += 1
    for v in waypoint_s:
        points[k] = v
        k += 1
    for r in refinement:
        points[k] = h * r
        k += 1
    for r in refinement:
        points[k] = length - h * r
        k += 1
    for kink in kinks:
        for sign in (1.0, -1.0):
            for r in refinement:
                v = kink + sign * (h * r)
                if 0.0 < v < length:
                    points[k] = v
                    k += 1
    grid = np.unique(points[:k])
    # drop slivers left by the union (they only cost time): the later point of the pair, unless it
    # is a waypoint (the path's pieces meet there: a waypoint is always a gridpoint), then the earlier
    sliver_width = 1e-3 * h * refinement[-1]
    # the waypoints are gridpoints (sorted, distinct): where each one sits in the grid
    waypoint = np.zeros(len(grid), dtype=np.bool_)
    waypoint[np.searchsorted(grid, waypoint_s)] = True
    keep = np.ones(len(grid), dtype=np.bool_)
    for i in range(len(grid) - 1):
        if grid[i + 1] - grid[i] <= sliver_width:
            if not waypoint[i + 1]:
                keep[i + 1] = False
            elif not waypoint[i]:
                keep[i] = False
    grid = grid[keep]
    grid[-1] = length
    return grid


def _checked(traj: Trajectory, limits: JointLimits) -> Trajectory:
    """``traj`` slowed down where it exceeds ``limits`` between the gridpoints."""
    rv, ra = traj.limit_ratios(limits)
    k = slowdown(rv, ra)
    if k > 1.0:
        traj = traj.slowed(k * (1.0 + SLOWDOWN_MARGIN))
    return traj


def _solve(
    path: JointPath,
    grid: NDArray[np.float64],
    limits: JointLimits,
    constraints: list[constraint.Constraint],
    speed_band: float = 0.0,
    torque: Sequence[RneaJointTorqueConstraint] = (),
) -> tuple[Trajectory, float]:
    """TOPP-RA on ``grid``, then the between-gridpoint check against ``limits`` (slowed where
    needed), flattened within ``speed_band`` where that holds ``torque`` too; and the duration of
    TOPP-RA's own (checked) profile, what the flattening is measured against."""
    instance = LeanTOPPRA(constraints, path, grid)
    _sdd, sd, _v = instance.compute_parameterization(0.0, 0.0)
    if sd is None or np.any(~np.isfinite(sd)):
        raise PlanError(PlanResult.INFEASIBLE, "no trajectory along this path satisfies the limits (TOPP-RA failed)")
    traj = _checked(Trajectory.from_path_velocities(path, grid, np.asarray(sd, dtype=float), limits.names), limits)
    if speed_band <= 0.0:
        return traj, traj.duration
    flat = _checked(flattened(traj, limits, speed_band), limits)
    return (flat if all(c.holds_on(flat) for c in torque) else traj), traj.duration


def parameterize(
    path: JointPath,
    limits: JointLimits,
    constraints: list[constraint.Constraint],
    gridpoints: int = DEFAULT_GRIDPOINTS,
    speed_band: float = 0.0,
) -> Trajectory:
    """The time-optimal rest-to-rest trajectory along ``path`` under ``constraints``
    (``parameterize_banded``'s trajectory)."""
    return parameterize_banded(path, limits, constraints, gridpoints, speed_band)[0]


def parameterize_banded(
    path: JointPath,
    limits: JointLimits,
    constraints: list[constraint.Constraint],
    gridpoints: int = DEFAULT_GRIDPOINTS,
    speed_band: float = 0.0,
) -> tuple[Trajectory, float]:
    """The time-optimal rest-to-rest trajectory along ``path`` under ``constraints``, and what the
    speed band cost: its duration over TOPP-RA's own (both before any torque slow-down; 1.0 without
    a band).

    ``limits`` are the joint limits the constraints were built from: the result is checked
    against them between the gridpoints and slowed down uniformly where it exceeds them.
    ``speed_band``: flattened within it (``planner.speed_band``; 0: TOPP-RA's profile as it is).

    Joint torque limits rarely bind on a well-sized robot, and their rows cost three RNEAs per
    gridpoint: the first solve leaves them out and the result is checked against them (one RNEA
    per gridpoint, the same that size the slow-down between them). Where it holds them, it is also
    the optimum with them (a constraint the optimum already meets changes nothing); where it does
    not, the solve is made again with them (and its flattened profile is kept only where it holds
    them too).
    """
    grid = make_gridpoints(path, gridpoints)
    deferred = [c for c in constraints if isinstance(c, RneaJointTorqueConstraint)]
    if not deferred:
        traj, optimal = _solve(path, grid, limits, constraints, speed_band)
        return traj, traj.duration / optimal
    lean = [c for c in constraints if not isinstance(c, RneaJointTorqueConstraint)]
    traj, optimal = _solve(path, grid, limits, lean, speed_band)
    checks = [c.check(traj) for c in deferred]
    if not all(check.holds for check in checks):
        traj, optimal = _solve(path, grid, limits, constraints, speed_band, deferred)
        checks = [c.check(traj) for c in deferred]
    ratio = traj.duration / optimal
    return _torque_checked(traj, checks), ratio


def _torque_checked(traj: Trajectory, checks: Sequence[TorqueCheck]) -> Trajectory:
    """``traj`` slowed down where it exceeds a torque limit between the gridpoints (``TorqueCheck.slowdown``)."""
    k = max(check.slowdown() for check in checks)
    if math.isinf(k):
        raise PlanError(PlanResult.INFEASIBLE, "gravity alone exceeds a joint's torque limit on this path")
    return traj.slowed(k * (1.0 + SLOWDOWN_MARGIN)) if k > 1.0 else traj


def warm_up() -> None:
    """Load the compiled loops a plan may call that a service's short warm-up move does not (numba's
    cache; on a new machine their compilation, seconds, would fall inside a request's budget):
    the not-a-knot spline's, which a path of 4 waypoints or more takes, and the torque check's
    middles, which only a trajectory near a torque limit takes. tests/service/test_warm_up.py."""
    s = np.arange(4.0)
    c, _ = not_a_knot(s, np.column_stack((s, s * s)))
    middles_warm_up(s, np.ascontiguousarray(c))


__all__ = [
    "DEFAULT_GRIDPOINTS",
    "IntervalJointAccelerationConstraint",
    "IntervalJointVelocityConstraint",
    "LeanTOPPRA",
    "RneaJointTorqueConstraint",
    "TcpAngularSpeedConstraint",
    "TcpSpeedConstraint",
    "Trajectory",
    "make_gridpoints",
    "parameterize",
    "parameterize_banded",
    "timing_constraints",
    "warm_up",
]
