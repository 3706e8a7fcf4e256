"""Jerk-limited time-optimal timing along a joint path: a nonlinear program solved with casadi.

TOPP-RA's profiles are bang-bang in acceleration, and toppra has no jerk constraint (its
problem is linear in u = s'', x = s'^2; jerk is not). Here the timing along the same path is
a nonlinear program, warm-started from the TOPP-RA solution:

- on a grid along the path that contains every waypoint, the path parameter is a cubic in time
  on each interval (constant s''') and every joint velocity, acceleration, jerk, torque and TCP
  speed row holds exactly at its samples; the objective is the duration (``nlp``);
- fatrop solves it, ipopt where fatrop does not converge, within the plan's deadline, and the
  S-curve floor of ``planner.scurve`` where no solver answers in time (``solve``).

After the solve the trajectory is checked densely (``JerkTrajectory.limit_ratios``,
``speed_ratio``), and slowed down uniformly where a sample between the rows exceeds a limit
(velocity / k, acceleration / k^2, jerk / k^3), as TOPP-RA's trajectory is. So is joint torque,
which the rows hold at the gridpoints only and the S-curve floor not at all: with TOPP-RA's own
check (``RneaJointTorqueConstraint.slowdown``) on the motion cut into short pieces
(``_torque_slowdown``). A solver's optimum slowed by more than 0.1 % for torque is reported as no
optimum (``JerkTrajectory.torque_slowed``): the shorter motion the rows allowed was not within the
limits, and the one within them is not known to be the shortest.

Where each part lives: ``trajectory`` (the result, ``JerkTrajectory``, and its dense check),
``warm`` (the TOPP-RA profile, the grid, the start), ``nlp`` (the program and its numbers),
``solve`` (the solvers, the deadline), and the whole, :func:`jerk_limited`, here.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import toppra.constraint as constraint
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.jerk.nlp import program_bounds, program_parameters, program_rows, variable_scales
from pvtflow.planner.jerk.screen import ROW_JOINTS, ROW_TOL, largest_row, row_joints, screened
from pvtflow.planner.jerk.solve import (
    PROGRAMS,
    Program,
    cached_program,
    expected_build_s,
    expected_solve_s,
    solve_in_time,
)
from pvtflow.planner.jerk.trajectory import JerkTrajectory
from pvtflow.planner.jerk.warm import MIN_REST_TO_REST, WarmProfile, rests_of, warm_start
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError, PlanResult
from pvtflow.planner.scurve import rest_to_rest
from pvtflow.planner.slowdown import SLOWDOWN_MARGIN, slowdown
from pvtflow.planner.timing import RneaJointTorqueConstraint, Trajectory

__all__ = [
    "DEFAULT_JERK_INTERVALS",
    "GRID_UNIT",
    "WARM_INTERVALS",
    "JerkTrajectory",
    "forget_solve_times",
    "grid_sizes",
    "jerk_limited",
    "untimed_grids",
    "warm_up",
]

# the program's grid: as fine as the time allows, up to DEFAULT_JERK_INTERVALS; its sizes are GRID_UNIT
# times a power of two (each size is a program to build, seconds at start). On 20 arm6 8-waypoint
# paths against copp-py's TOPP3 at 1000 stations (bench/jerk_vs_copp.py, bench/RESULTS.md "Issue 39
# item 2"): 48 intervals 1.084x at the median, 96 1.017x, 192 1.001x; fatrop's time grows with them
GRID_UNIT = 48
DEFAULT_JERK_INTERVALS = 192
# the sizes a warm-up builds: those a budget of some 100 ms can be solved on; 192 (1.35 s of CPU to build
# with its solvers, at every start, where casadi 3.8.2 leaves the interpreter's lock while it builds:
# bench/gil_stall.py) is built by the first plan without a deadline (a deadline never waits for a build)
WARM_INTERVALS = 96

# the torque check (``_torque_slowdown``, bench/jerk_torque.py): on 20 random arm6 paths at 30 % of
# every effort the torque between its samples was at most 3.5e-5 of a limit above theirs with pieces
# of 5 ms, 1.5e-4 with 10 ms, 1 % with the intervals whole; with 25 ms between samples the largest
# torque was missed by at most 0.18 %, which the screen's 2 % margin covers
_TORQUE_PIECE_S = 0.005
_TORQUE_SCREEN_S = 0.05
_TORQUE_SCREEN_MARGIN = 0.02


def _checked(
    traj: JerkTrajectory, limits: JointLimits, jmax: NDArray[np.float64], constraints: Sequence[constraint.Constraint]
) -> JerkTrajectory:
    """``traj`` checked densely and slowed down uniformly until every limit holds (PlanError where
    it is no motion along the path)."""
    if traj.min_path_velocity() < -1e-6 * max(np.max(traj.sd), 1e-9):
        raise PlanError(PlanResult.INFEASIBLE, "the jerk-limited timing reverses along the path", solver=traj.solver)
    rv, ra, rj = traj.limit_ratios(limits, jmax)
    factors = (slowdown(rv, ra), np.cbrt(rj), traj.speed_ratio(constraints))
    if not np.all(np.isfinite(factors)):  # a solver's "success" that is no motion: never handed on
        raise PlanError(PlanResult.INFEASIBLE, "the jerk-limited timing returned no finite motion", solver=traj.solver)
    torque = _torque_slowdown(traj, constraints)
    k = max(*factors, torque)
    if torque > 1.0:
        traj = dataclasses.replace(traj, torque_scale=torque)
    return traj.slowed(k * (1.0 + SLOWDOWN_MARGIN)) if k > 1.0 else traj


def _torque_slowdown(traj: JerkTrajectory, constraints: Sequence[constraint.Constraint]) -> float:
    """The uniform slow-down that holds the torque limits everywhere in time (1: none needed), from
    ``RneaJointTorqueConstraint.slowdown`` on ``traj`` cut into short pieces (its check looks at the
    ends and the middle of every interval: an S-curve's cruise lasts seconds, and near a stop the
    torque of a solver's answer peaks within 10-20 ms).

    First a screen (pieces of ``_TORQUE_SCREEN_S``, each effort less ``_TORQUE_SCREEN_MARGIN``):
    a plan well inside its torque limits costs a few hundred RNEAs; only one near a limit is
    checked at ``_TORQUE_PIECE_S`` and slowed by the exact factor."""
    torque = [c for c in constraints if isinstance(c, RneaJointTorqueConstraint)]
    if not torque:
        return 1.0
    h = np.diff(traj.breakpoints)
    screen = traj.subdivided(np.ceil(h / _TORQUE_SCREEN_S))
    margin = 1.0 - _TORQUE_SCREEN_MARGIN
    if all(RneaJointTorqueConstraint(c.model, margin * c.effort).slowdown(screen) <= 1.0 for c in torque):
        return 1.0
    fine = traj.subdivided(np.ceil(h / _TORQUE_PIECE_S))
    k = max(c.slowdown(fine) for c in torque)
    if math.isinf(k):
        raise PlanError(PlanResult.INFEASIBLE, "gravity alone exceeds a joint's torque limit on this path")
    return k


def grid_sizes(needed: int, intervals: int = DEFAULT_JERK_INTERVALS) -> list[int]:
    """The program sizes a path needing ``needed`` intervals may be solved on, smallest first: the
    least multiple of ``GRID_UNIT`` that holds it, doubled while within ``intervals``."""
    sizes = [GRID_UNIT * max(1, math.ceil(needed / GRID_UNIT))]
    while 2 * sizes[-1] <= intervals:
        sizes.append(2 * sizes[-1])
    return sizes


def warm_up() -> None:
    """Build, for every joint count a plan has built a program for, every size up to
    ``WARM_INTERVALS`` a path of up to 44 waypoints (or 12 with a stop at each) and one of up to
    twice that may be solved on (``grid_sizes``), so that no plan within a deadline meets a
    shape that is not built (it would answer on a coarser grid, or the floor), the programs a deadline
    solves compiled (``solve.Program.use_compiled``); the warm-up's own solve times are forgotten
    (``forget_solve_times``)."""
    for _, dof, torque in PROGRAMS.shapes():
        for n in {*grid_sizes(GRID_UNIT, WARM_INTERVALS), *grid_sizes(2 * GRID_UNIT, WARM_INTERVALS)}:
            cached_program(n, dof, torque)
            # the screened program a deadline solves, its functions compiled (a second of gcc per shape, once per
            # machine: ``compiled``) before its time per iteration is taken (``service.cell_planner``)
            cached_program(n, _row_dof(dof, torque, 0.0), torque).use_compiled()
    forget_solve_times()


def untimed_grids() -> list[int]:
    """The grid sizes a warm-up builds (``warm_up``) whose program a deadline solves has no time per
    iteration yet (``solve.Program.iteration_s``): kept per process, so a cell's later warm-ups skip them."""
    sizes = set()
    for n, dof, torque in PROGRAMS.shapes():
        program = PROGRAMS.ready(n, _row_dof(dof, torque, 0.0), torque)
        if n <= WARM_INTERVALS and program is not None and not program.iteration_s:
            sizes.add(n)
    return sorted(sizes)


def forget_solve_times() -> None:
    """Forget every program's solve times but its times per iteration: a warm-up's moves are no
    request's (its short move took 151 ms on 96 intervals, requests 50; ``solve.Program.iteration_s``)."""
    for shape in PROGRAMS.shapes():
        program = PROGRAMS.ready(*shape)
        if program is not None:
            program.fatrop_s.clear()


def _row_dof(dof: int, torque: bool, deadline: float | None) -> int:
    """The joints whose rows each stage of the program holds: every one without a deadline (the
    reference), else ``screen.ROW_JOINTS`` (one more with torque rows: a fourth kind that may bind)."""
    return dof if deadline is None else min(dof, ROW_JOINTS + int(torque))


def _program_for(sizes: list[int], dof: int, torque: bool, deadline: float | None) -> tuple[Program | None, int]:
    """Without a deadline the finest of ``sizes`` (built now where it is not). Within one the finest
    whose solve fits the time left (a size not built is built where the time left covers the build
    and twice its expected solve), else the coarsest, built now only where the time left covers the
    build (its solvers then decide, ``solve.solve_in_time``), else None (the floor; build it later).

    A finer size's solve time is its own measured one (``Program.measured_fatrop_s``), else the
    coarsest's measured one times the square of the ratio of their intervals, else twice its expected one: a first
    request after the start at the cell's 200 ms solves the coarsest (a late solve costs the whole
    budget: the floor comes after it), one with seconds to spare the finest."""
    if deadline is None:
        return cached_program(sizes[-1], dof, torque), sizes[-1]
    coarsest = PROGRAMS.ready(sizes[0], dof, torque)
    coarsest_s = None if coarsest is None else coarsest.measured_fatrop_s()
    for n in reversed(sizes[1:]):
        program = PROGRAMS.ready(n, dof, torque)
        if program is None and deadline - time.perf_counter() >= expected_build_s(n) + 2.0 * expected_solve_s(n):
            program = cached_program(n, dof, torque)
        if program is None:
            continue
        measured = program.measured_fatrop_s()
        if measured is None:
            # fatrop's time grows about as the square of the intervals (more iterations, each longer): 96
            # intervals took 3.8-4.1x 48's at the median (bench/jerk_rows.py, bench/RESULTS.md)
            # (not its time per iteration from the warm-up: a late finer solve is the floor where a coarser one
            # answers, and under load 96 intervals took 4x 48's; bench/RESULTS.md)
            measured = 2.0 * expected_solve_s(n) if coarsest_s is None else coarsest_s * (n / sizes[0]) ** 2
        if deadline - time.perf_counter() >= measured:
            return program, n
    program = coarsest
    if program is None and deadline - time.perf_counter() >= expected_build_s(sizes[0]):
        program = cached_program(sizes[0], dof, torque)
    return program, sizes[0]


def _floor(
    path: JointPath, rests: NDArray[np.float64], limits: JointLimits, jmax: NDArray[np.float64], warm: Trajectory
) -> JerkTrajectory:
    """The S-curve floor that needs no solver (planner/scurve.py): the answer where none is in time."""
    g, sd, sdd, sddd, t = rest_to_rest(path, rests, limits, jmax)
    traj = JerkTrajectory(path, g, sd, sdd, sddd, t, limits.names, solver="scurve", optimal=False)
    return dataclasses.replace(traj, lower_bound=warm.duration)


def jerk_limited(
    path: JointPath,
    limits: JointLimits,
    constraints: Sequence[constraint.Constraint],
    max_jerk: ArrayLike,
    warm: Trajectory,
    intervals: int | None = None,
    deadline: float | None = None,
    on_floor: Callable[[JerkTrajectory], None] | None = None,
) -> JerkTrajectory:
    """The time-optimal rest-to-rest trajectory along ``path`` with |q'''_j| <= max_jerk_j besides
    ``constraints`` (the cell's toppra constraints, held as TOPP-RA holds them), started from
    ``warm``, the TOPP-RA solution of the same path and constraints.

    PlanError(INFEASIBLE) where no solver converges (the message carries their statuses).

    Anytime with a ``deadline`` (time.perf_counter): where the solvers have not finished by then,
    the answer is the S-curve floor (``planner.scurve``), ``optimal`` False, computed while the
    solver runs; time alone never makes it INFEASIBLE. ``lower_bound``: TOPP-RA's duration, which
    no jerk-limited timing beats.
    ``torque_scale``: the slow-down torque between the rows asked for after the solve.
    ``intervals``: the grid's size at most (None: ``DEFAULT_JERK_INTERVALS``; ``grid_sizes``).
    ``on_floor``: called with the checked floor where it is computed while a solver runs (in this
    thread, before the solver's answer is taken), for what the caller makes of it meanwhile (its knots:
    ``service.cell_planner``); the floor answered is that same object.
    """
    jmax = np.asarray(max_jerk, dtype=float)
    rests = rests_of(path)
    stops = rests[1:-1]
    needed = (len(path.waypoint_s) - 1) + MIN_REST_TO_REST * (len(rests) - 1)
    torque = any(isinstance(c, RneaJointTorqueConstraint) for c in constraints)
    # within a deadline each stage holds the rows of the joints that may bind there (``screen``)
    row_dof = _row_dof(limits.dof, torque, deadline)
    # a program is built within a deadline only where the time left covers it (0.6 s for 48 intervals);
    # else the floor, and the smallest is built for later
    sizes = grid_sizes(needed, DEFAULT_JERK_INTERVALS if intervals is None else int(intervals))
    program, n = _program_for(sizes, row_dof, torque, deadline)
    if program is None:
        PROGRAMS.build_later(n, row_dof, torque)
        return _checked(_floor(path, rests, limits, jmax, warm), limits, jmax, constraints)
    profile = WarmProfile.of(warm, rests)
    grid = profile.grid(path.waypoint_s, rests, n)
    rows = program_rows(path, grid, limits, constraints)
    rows.sd_max[np.searchsorted(grid, stops)] = 0.0
    start = warm_start(profile, grid, rows, jmax)
    joints = None if row_dof == limits.dof else row_joints(rows, start, limits, jmax, row_dof)
    held = rows if joints is None else screened(rows, joints)
    scale = variable_scales(start)
    per_variable = np.tile(scale, n + 1)[: len(start)]
    bounds = program_bounds(held)
    args = {k: v / per_variable for k, v in bounds.items() if k in ("lbx", "ubx")}
    args |= {k: v for k, v in bounds.items() if k in ("lbg", "ubg")}
    args["p"] = np.concatenate((program_parameters(held, limits, jmax, joints), scale))
    args["x0"] = start / per_variable
    # within a deadline the floor is computed while the solver runs (solve.solve_in_time), ready when it is late
    floor: list[JerkTrajectory | Exception] = []

    def floor_meanwhile() -> None:
        try:
            floor.append(_checked(_floor(path, rests, limits, jmax, warm), limits, jmax, constraints))
        except Exception as exc:  # raised only where the floor is the answer, as it was computed after the solve
            floor.append(exc)
            return
        if on_floor is not None:
            on_floor(floor[0])

    meanwhile = None if deadline is None else floor_meanwhile
    sol, status, late = solve_in_time(program, args, scale, deadline, meanwhile)
    if sol is None and not late:
        raise PlanError(
            PlanResult.INFEASIBLE,
            f"the jerk-limited timing found no trajectory within the limits ({status})",
            solver_status=status,
        )
    if sol is None:  # the deadline first: the floor that needs no solver (planner/scurve.py)
        if not floor:  # no solver started: the floor computed now (nothing to do beside a solve)
            on_floor = None
            floor_meanwhile()
        if isinstance(floor[0], Exception):
            raise floor[0]
        return floor[0]
    traj = JerkTrajectory(
        path,
        grid,
        np.maximum(sol.sd, 0.0),
        sol.sdd,
        sol.j,
        np.concatenate(([0.0], np.cumsum(np.maximum(sol.h, 0.0)))),
        limits.names,
        solver=sol.solver,
        iterations=sol.iterations,
        optimal=sol.optimal,
    )
    if joints is not None and largest_row(rows, sol.sd, sol.sdd, sol.h, sol.j, limits, jmax) > 1.0 + ROW_TOL:
        traj = dataclasses.replace(traj, optimal=False)  # a joint left out bound: no optimum of the whole program
    traj = dataclasses.replace(traj, lower_bound=warm.duration)
    return _checked(traj, limits, jmax, constraints)
