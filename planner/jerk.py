"""Jerk-limited time-optimal timing along a joint path: a nonlinear program solved with casadi.

TOPP-RA's profiles are bang-bang in acceleration, and toppra has no jerk constraint (its
problem is linear in u = s'', x = s'^2; jerk is not). Here the timing along the same path is
a nonlinear program, warm-started from the TOPP-RA solution:

- a grid s_0 < ... < s_N along the path that contains every waypoint, so that each interval
  lies in one cubic piece of the path spline (q_sss constant on it);
- on interval k the path parameter is a cubic in time: constant s''' = j_k for a time h_k,
  from the state (s', s'') = (sd_k, a_k) at s_k; the state at s_(k+1) follows from it (the
  gap-closing rows) and the distance it covers is exactly s_(k+1) - s_k (one equality per
  interval). Acceleration is continuous, jerk piecewise constant: what a drive's cubic
  segments reproduce best;
- inside the interval the path is a cubic in sigma = s - s_k, so q_s, q_ss, q_sss there are
  exact polynomials in sigma, and every joint velocity, acceleration and jerk sample is an
  exact polynomial in the interval's variables: the rows hold at their samples exactly, not
  through a linearisation;
- rows: joint velocity at the gridpoints (a box on sd_k, merged with the TCP speed bound) and
  in the middle of every interval; joint acceleration at the start and the middle; joint
  jerk at the start, the middle and the end (jerk jumps at gridpoints); joint torque (the
  same RNEA rows as TOPP-RA's collocation) at the gridpoints; TCP speed at the gridpoints and,
  with the frame's speed factor of the interval's midpoint in s, in the middle;
- objective: the duration, sum of h_k.

The program is a discrete optimal control problem (state (sd, a), control (h, j)), which is the
structure fatrop's Riccati-based interior point exploits: its iteration solves the stages in
sequence, where ipopt's general sparse factorization (MUMPS) does not know them. Where fatrop does
not converge, ipopt is tried from the same start; where neither does, the plan is refused with the
solvers' statuses. The variables are scaled by their typical magnitudes (``_scales``: fatrop does
not scale a program) and the start is slowed down to well inside the jerk rows (``_start``): both
cut the solve time's tail.

After the solve the trajectory is checked densely (``JerkTrajectory.limit_ratios``,
``speed_ratio``), and slowed down uniformly where a sample between the rows exceeds a limit
(velocity / k, acceleration / k^2, jerk / k^3), as TOPP-RA's trajectory is.

Anytime with a deadline (``_solve``): the solve runs in a thread waited for until then; ipopt
stops there (``_Deadline``) with its last iterate whose equalities hold; without an answer in time
the motion is the S-curve floor of ``planner.scurve``. Either is checked and slowed down as above,
``optimal`` False.

A solve is started only where it can finish (``_solvers_for``), because one that cannot is worse
than none: casadi holds the interpreter's lock while it computes (measured: other threads stood up
to 87 ms), fatrop has no time limit nor iteration callback in casadi 3.8.2, and the floor's own
dense check and knots (about 25 ms of CPU, its motion being 2-4x longer) come after the deadline.
So fatrop runs only with at least its expected time left: the longest of this program shape's last
``_SOLVE_HISTORY`` fatrop solves (``_FATROP_TIME_S`` until ``_MIN_HISTORY`` are known), a measured
figure that follows the machine (a percentile let it start on a path slower than the fast ones it
had seen, and an overrun costs the whole budget); ipopt (stopped at the deadline) only with at
least ``_IPOPT_TIME_S`` left, below which its iterates were never usable (bench/RESULTS.md); with
less than both, no solver, the floor at once. At a 50 ms plan budget that is the floor: the wall
time stays within the budget instead of waiting for a solve that comes too late (bench/plan_budget.py).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import toppra.constraint as constraint
from numpy.typing import ArrayLike, NDArray

from planner.limits import JointLimits
from planner.path import JointPath, PlanError, PlanResult
from planner.scurve import rest_to_rest
from planner.slowdown import SLOWDOWN_MARGIN, slowdown
from planner.timing import (
    IntervalJointAccelerationConstraint,
    IntervalJointVelocityConstraint,
    RneaJointTorqueConstraint,
    TcpAngularSpeedConstraint,
    TcpSpeedConstraint,
    Trajectory,
)
from planner.trajectory import PathTiming

DEFAULT_JERK_INTERVALS = 48
_CHECK_SUBSAMPLES = 32
_BISECTIONS = 40  # a peak's time to 1e-12 of the samples' spacing
# intervals between two rests at least: one constant jerk per interval needs 3 to stop again (+, -, +)
MIN_REST_TO_REST = 4
# a jump of the path's second derivative at a waypoint above this is a C1 joint, not round-off
_CURVATURE_JUMP = 1e-8


# bounds on a speed |G(s) q_s| s' <= limit (the joint velocity, the TCP's linear and angular speed)
_SPEED_CONSTRAINTS = (IntervalJointVelocityConstraint, TcpSpeedConstraint, TcpAngularSpeedConstraint)


def _interval_coefficients(path: JointPath, grid: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """Taylor coefficients of the path on every grid interval: q, q_s, q_ss at its start and the
    constant q_sss of the spline piece it lies in, each (n, dof)."""
    start = grid[:-1]
    x, c = path.pieces
    piece = np.clip(np.searchsorted(x, 0.5 * (grid[:-1] + grid[1:]), side="right") - 1, 0, len(x) - 2)
    return path(start), path(start, 1), path(start, 2), 6.0 * c[0][piece]


@dataclass(frozen=True)
class JerkTrajectory(PathTiming):
    """q(t) = path(s(t)) with s''' constant between gridpoints: numbers in, numbers out.

    Provides what knot placement takes of a trajectory (planner.knots.TimedTrajectory) and what
    planner.timing.Trajectory offers for reading it back (position, velocity, acceleration).
    """

    path: JointPath
    gridpoints: NDArray[np.float64]  # s at the grid (n + 1)
    sd: NDArray[np.float64]  # s' at the grid
    sdd: NDArray[np.float64]  # s'' at the grid
    sddd: NDArray[np.float64]  # s''' on each interval (n)
    breakpoints: NDArray[np.float64]  # t at the grid [s]
    joint_names: tuple[str, ...]
    time_scale: float = 1.0  # >1 when the dense check slowed the solution down
    solver: str = ""  # the casadi solver that found it ("scurve": the deadline's floor, ``planner.scurve``)
    iterations: int = 0
    optimal: bool = True  # False: the deadline came first, this is the best timing found by then
    lower_bound: float = 0.0  # s: no timing of this path under these limits is shorter (TOPP-RA's duration)
    coefficients: tuple[NDArray[np.float64], ...] = field(default=(), repr=False, compare=False)
    check_subsamples: ClassVar[int] = _CHECK_SUBSAMPLES

    def __post_init__(self) -> None:
        if not self.coefficients:
            object.__setattr__(self, "coefficients", _interval_coefficients(self.path, self.gridpoints))

    @property
    def waypoint_times(self) -> NDArray[np.float64]:
        """When the trajectory passes each waypoint [s] (waypoints are gridpoints)."""
        idx = np.clip(np.searchsorted(self.gridpoints, self.path.waypoint_s - 1e-12), 0, len(self.gridpoints) - 1)
        return self.breakpoints[idx]

    def slowed(self, k: float) -> JerkTrajectory:
        """The same motion k times slower (s' / k, s'' / k^2, s''' / k^3)."""
        return JerkTrajectory(
            self.path,
            self.gridpoints,
            self.sd / k,
            self.sdd / (k * k),
            self.sddd / (k * k * k),
            self.breakpoints * k,
            self.joint_names,
            self.time_scale * k,
            self.solver,
            self.iterations,
            self.optimal,
            self.lower_bound,
            self.coefficients,
        )

    def _path_state(self, t: ArrayLike) -> tuple[NDArray[np.float64], ...]:
        """Interval index, sigma = s - s_k, s', s'', s''' at the times t (clipped to the motion)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)).ravel(), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.breakpoints, t, side="right") - 1, 0, len(self.sddd) - 1)
        tau = t - self.breakpoints[k]
        sd, a, j = self.sd[k], self.sdd[k], self.sddd[k]
        sigma = tau * (sd + tau * (0.5 * a + tau * j / 6.0))
        return k, sigma, sd + tau * (a + 0.5 * j * tau), a + j * tau, j

    def _joint(self, t: ArrayLike, order: int) -> NDArray[np.float64]:
        """(len(t), dof): the order-th time derivative of q at t (0..3), from the interval's exact
        Taylor polynomial of the path."""
        k, sg, sd, sdd, sddd = self._path_state(t)
        q0, q1, q2, q3 = (c[k] for c in self.coefficients)
        sg = sg[:, None]
        q_s = q1 + sg * (q2 + 0.5 * sg * q3)
        if order == 0:
            return q0 + sg * (q1 + sg * (0.5 * q2 + sg * q3 / 6.0))
        if order == 1:
            return q_s * sd[:, None]
        q_ss = q2 + sg * q3
        if order == 2:
            return q_ss * (sd * sd)[:, None] + q_s * sdd[:, None]
        return q3 * (sd**3)[:, None] + 3.0 * q_ss * (sd * sdd)[:, None] + q_s * sddd[:, None]

    def position(self, t: ArrayLike) -> NDArray[np.float64]:
        return self._scalar(t, self._joint(t, 0))

    def velocity(self, t: ArrayLike) -> NDArray[np.float64]:
        return self._scalar(t, self._joint(t, 1))

    def acceleration(self, t: ArrayLike) -> NDArray[np.float64]:
        return self._scalar(t, self._joint(t, 2))

    def jerk(self, t: ArrayLike) -> NDArray[np.float64]:
        return self._scalar(t, self._joint(t, 3))

    @staticmethod
    def _scalar(t: ArrayLike, values: NDArray[np.float64]) -> NDArray[np.float64]:
        return values[0] if np.ndim(t) == 0 else values

    def states(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions and velocities, each (dof, len(t)) (knot placement samples every drive ms)."""
        return np.ascontiguousarray(self._joint(t, 0).T), np.ascontiguousarray(self._joint(t, 1).T)

    def acceleration_jumps(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The inner gridpoints' times and |q''(t+) - q''(t-)| there: s'' is continuous, so these are
        only the solver's round-off (knot placement puts no switch knots here)."""
        h = np.diff(self.breakpoints)
        a_end = self.sdd[:-1] + self.sddd * h
        q_s = self.coefficients[1][1:]
        return self.breakpoints[1:-1], np.abs(q_s * (self.sdd[1:-1] - a_end[:-1])[:, None])

    def limit_ratios(self, limits: JointLimits, max_jerk: ArrayLike) -> tuple[float, float, float]:
        """Worst |q'|/vmax, |q''|/amax and |q'''|/max_jerk over the check times, and for the velocity
        and the acceleration also at their peaks between two check times (``_peak_ratio``)."""
        t = self.check_times()
        jmax = np.asarray(max_jerk, dtype=float)
        t2d = t.reshape(len(self.sddd), -1)
        rv = float(np.max(np.abs(self._joint(t, 1)) / limits.velocity))
        ra = float(np.max(np.abs(self._joint(t, 2)) / limits.acceleration))
        return (
            max(rv, self._peak_ratio(t2d, 1, limits.velocity)),
            max(ra, self._peak_ratio(t2d, 2, limits.acceleration)),
            float(np.max(np.abs(self._joint(t, 3)) / jmax)),
        )

    def _peak_ratio(self, t2d: NDArray[np.float64], order: int, bound: NDArray[np.float64]) -> float:
        """Worst |order-th derivative| / bound at its extrema between consecutive check times of an
        interval (rows of ``t2d``): where the next derivative changes sign, found by bisection. The
        samples alone can miss a peak between them by 1e-4 of the limit."""
        d = self._joint(t2d.ravel(), order + 1).reshape(*t2d.shape, -1)
        i, p, j = np.nonzero(d[:, :-1] * d[:, 1:] < 0.0)
        if len(i) == 0:
            return 0.0
        lo, hi, f_lo = t2d[i, p], t2d[i, p + 1], d[i, p, j]
        rows = np.arange(len(i))
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            f_mid = self._joint(mid, order + 1)[rows, j]
            left = np.sign(f_mid) == np.sign(f_lo)
            lo, f_lo, hi = np.where(left, mid, lo), np.where(left, f_mid, f_lo), np.where(left, hi, mid)
        return float(np.max(np.abs(self._joint(0.5 * (lo + hi), order)[rows, j]) / bound[j]))

    def speed_ratio(self, constraints: Sequence[constraint.Constraint]) -> float:
        """Worst speed / limit of the cell's TCP speed constraints over the check times (1 / 0: none)."""
        tcp = [c for c in constraints if isinstance(c, TcpSpeedConstraint | TcpAngularSpeedConstraint)]
        if not tcp:
            return 0.0
        k, sigma, sd, _, _ = self._path_state(self.check_times())
        s = np.clip(self.gridpoints[k] + sigma, 0.0, self.gridpoints[-1])
        return max(float(np.max(np.abs(c.speed_factors(self.path, s)) * sd[:, None] / c.limit)) for c in tcp)

    def min_path_velocity(self) -> float:
        """The smallest s' over the motion, exactly (s' is a quadratic in time on each interval)."""
        h = np.diff(self.breakpoints)
        sd, a, j = self.sd[:-1], self.sdd[:-1], self.sddd
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = np.where(j > 0.0, -a / j, np.nan)
        inside = np.isfinite(tau) & (tau > 0.0) & (tau < h)
        vertex = np.where(inside, sd - 0.5 * a * a / np.where(inside, j, 1.0), np.inf)
        return float(min(np.min(self.sd), np.min(vertex)))


# --- the nonlinear program -----------------------------------------------------------------------
@dataclass(frozen=True)
class _Rows:
    """What the program's rows are made of on one grid: numbers only, (n, dof) unless said."""

    D: NDArray[np.float64]  # (n,) interval lengths in s
    q1: NDArray[np.float64]  # q_s at the interval starts
    q2: NDArray[np.float64]  # q_ss at the interval starts
    q3: NDArray[np.float64]  # q_sss on the intervals
    e1: NDArray[np.float64]  # q_s at the interval ends (on the interval's own piece)
    e2: NDArray[np.float64]  # q_ss at the interval ends (on the interval's own piece)
    sd_max: NDArray[np.float64]  # (n + 1,) bound on s' at the gridpoints (joint and TCP speed; 0: a stop)
    sd_max_mid: NDArray[np.float64]  # (n,) bound on s' in the middle of the intervals (TCP speed; inf)
    torque: tuple[NDArray[np.float64], ...] | None  # a, b, lo, hi: lo <= a s'' + b s'^2 <= hi at the starts


# variables per stage: the state (s', s'') at the gridpoint, then the interval's controls: its time,
# its jerk s''', and sigma and s' at fixed fractions of its time (lifted: the rows there are then
# low-degree polynomials of few variables, which halves the work of the Hessian and the Jacobian)
_FRACTIONS = (0.5,)  # where in time the joint velocity and acceleration rows are held (bench/RESULTS.md)
_MIDDLE_INDEX = 0  # the fraction that is the middle (jerk and TCP speed rows there)
_STATE = ("sd", "a")
_CONTROL = ("h", "j", *(f"sigma_{i}" for i in range(len(_FRACTIONS))), *(f"sd_{i}" for i in range(len(_FRACTIONS))))
_EQUALITIES = 3 + 2 * len(_FRACTIONS)  # per stage: the next state (2), the distance, sigma and s' at the fractions
_JERK_ROWS = 3  # per joint: start, middle, end


def _stage_function(dof: int, torque: bool) -> ca.Function:
    """The rows of one interval: (its variables and numbers) -> the state at its end, then the
    distance and lifted residuals and its inequality rows (normalised to [-1, 1] but torque's)."""
    m = len(_FRACTIONS)
    sd, a, h, j = (ca.SX.sym(n) for n in (*_STATE, *_CONTROL[:2]))
    sgs = [ca.SX.sym(f"sigma_{i}") for i in range(m)]
    sds = [ca.SX.sym(f"sd_{i}") for i in range(m)]
    D = ca.SX.sym("D")
    q1, q2, q3, e1, e2, ta, tb = (ca.SX.sym(n, dof) for n in ("q1", "q2", "q3", "e1", "e2", "ta", "tb"))
    inv_v, inv_a, inv_j = (ca.SX.sym(n, dof) for n in ("inv_v", "inv_a", "inv_j"))

    def at(tau: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        """sigma, s', s'' at time tau into the interval."""
        return tau * (sd + tau * (0.5 * a + tau * j / 6.0)), sd + tau * (a + 0.5 * j * tau), a + j * tau

    def jerk(q_s: ca.SX, q_ss: ca.SX, s_d: ca.SX, s_dd: ca.SX) -> ca.SX:
        return (q3 * s_d**3 + 3.0 * q_ss * (s_d * s_dd) + q_s * j) * inv_j

    sg1, sd1, a1 = at(h)
    rows = [(q2 * sd**2 + q1 * a) * inv_a]
    if torque:
        rows.append(ta * a + tb * sd**2)
    residual = [(sg1 - D) / D]
    jerk_mid = ca.SX.zeros(dof)
    for i, f in enumerate(_FRACTIONS):
        sg_h, sd_h, a_f = at(f * h)
        residual += [sgs[i] - sg_h, sds[i] - sd_h]
        q_s, q_ss = q1 + sgs[i] * (q2 + 0.5 * sgs[i] * q3), q2 + sgs[i] * q3  # the path there, exactly
        rows += [q_s * sds[i] * inv_v, (q_ss * sds[i] ** 2 + q_s * a_f) * inv_a]
        if i == _MIDDLE_INDEX:
            jerk_mid = jerk(q_s, q_ss, sds[i], a_f)
    rows += [jerk(q1, q2, sd, a), jerk_mid, jerk(e1, e2, sd1, a1)]  # the end: sigma = D once the distance holds
    inputs = [sd, a, h, j, *sgs, *sds, D, q1, q2, q3, e1, e2, inv_v, inv_a, inv_j, ta, tb]
    return ca.Function("stage", inputs, [ca.vertcat(sd1, a1), ca.vertcat(*residual), ca.vertcat(*rows)])


@dataclass
class _Program:
    """The casadi program for n intervals and dof joints, built once and kept (``_program``).

    Variables, stage by stage: x_k = (sd_k, a_k), u_k = (h_k, j_k, sigma_mid_k, sd_mid_k), ..., x_n.
    Rows, stage by stage: x_(k+1) - F(x_k, u_k) (gap closing, the form fatrop's structure
    detection wants), the distance and middle residuals, then the stage's inequality rows.
    """

    n: int
    dof: int
    torque: bool
    nlp: dict[str, ca.SX]
    equality: list[bool]
    solvers: dict[str, ca.Function] = field(default_factory=dict)
    # one solve at a time: a solve past its plan's deadline runs on in its thread (fatrop cannot be stopped)
    lock: threading.Lock = field(default_factory=threading.Lock)
    stop: _Deadline | None = None
    fatrop_s: deque[float] = field(default_factory=lambda: deque(maxlen=_SOLVE_HISTORY))  # recent solve times

    def expected_fatrop_s(self) -> float:
        """fatrop's expected wall time on this program: the longest of its recent solves."""
        times = list(self.fatrop_s)
        return max(times) if len(times) >= _MIN_HISTORY else _FATROP_TIME_S

    def solver(self, name: str) -> ca.Function:
        if name not in self.solvers:
            options = _solver_options(name, self.equality)
            if name == "ipopt":  # ipopt asks after every iteration whether to go on; fatrop never does
                self.stop = _Deadline(self.nlp["x"].shape[0], np.asarray(self.equality))
                options["iteration_callback"] = self.stop
            self.solvers[name] = ca.nlpsol(f"jerk_{name}", name, self.nlp, options)
        return self.solvers[name]


class _Deadline(ca.Callback):
    """ipopt's iteration callback: stop once ``deadline`` (time.perf_counter) has passed, and keep
    the last iterate whose equalities hold (``best``: the motion is continuous along the path; its
    inequalities the dense check and slow-down make exact)."""

    def __init__(self, nx: int, equality: NDArray[np.bool_]) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.equality = nx, len(equality), equality
        self.deadline = float("inf")
        self.best: NDArray[np.float64] | None = None
        self.construct("jerk_deadline", {})

    def reset(self, deadline: float) -> None:
        self.deadline, self.best = deadline, None

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[int]:
        g = np.asarray(arg[2]).ravel()
        if np.max(np.abs(g[self.equality]), initial=0.0) <= _ITERATE_TOL:
            self.best = np.asarray(arg[0]).ravel().copy()
        return [1 if time.perf_counter() >= self.deadline else 0]


_MAX_ITER = 300
_START_JERK_SLACK = 0.3  # the start's joint jerk at most this fraction of the limit (see ``_start``)
_TOL = 1e-6  # optimality (relative duration)
_CONSTRAINT_TOL = 1e-9  # the residuals: positions along the path continuous to 1e-9 of an interval
_ITERATE_TOL = 1e-8  # an unfinished ipopt iterate is a motion where its residuals are this small
# fatrop's expected solve time until _MIN_HISTORY solves of a program shape were timed (``_solvers_for``):
# twice its p50 on 8-waypoint arm6 paths, so that a fresh process (``pvtflow plan``) solves at 200 ms
_FATROP_TIME_S = 0.06
_SOLVE_HISTORY = 50
_MIN_HISTORY = 10
_IPOPT_TIME_S = 0.04  # with less time left ipopt's iterates were never usable: no solve, the floor


def _solver_options(name: str, equality: list[bool]) -> dict[str, Any]:
    base: dict[str, Any] = {"print_time": False, "error_on_fail": False}
    common = {"print_level": 0, "tol": _TOL, "constr_viol_tol": _CONSTRAINT_TOL, "max_iter": _MAX_ITER}
    if name == "fatrop":
        return base | {"structure_detection": "auto", "equality": equality, "fatrop": common}
    return base | {"ipopt": common | {"sb": "yes"}}


@functools.lru_cache(maxsize=8)
def _program(n: int, dof: int, torque: bool) -> _Program:
    stage = _stage_function(dof, torque)
    D = ca.SX.sym("D", n)
    per_stage = [ca.SX.sym(name, n, dof) for name in ("q1", "q2", "q3", "e1", "e2", "ta", "tb")]
    inv = ca.SX.sym("inv", 3 * dof)
    # the variables are the program's own divided by a typical magnitude of each (``_scales``)
    scale = ca.SX.sym("scale", len(_STATE) + len(_CONTROL))
    x_scale, u_scale = scale[: len(_STATE)], scale[len(_STATE) :]
    m = len(_FRACTIONS)
    sigma_scale, sd_scale = u_scale[2], u_scale[2 + m]
    residual_scale = ca.vertcat(1.0, *([sigma_scale, sd_scale] * m))
    x = [ca.SX.sym(f"x{k}", len(_STATE)) for k in range(n + 1)]
    u = [ca.SX.sym(f"u{k}", len(_CONTROL)) for k in range(n)]
    w: list[ca.SX] = []
    g: list[ca.SX] = []
    equality: list[bool] = []
    for k in range(n):
        q1, q2, q3, e1, e2, ta, tb = (mat[k, :].T for mat in per_stage)
        xs, us = x[k] * x_scale, u[k] * u_scale
        controls = (us[i] for i in range(len(_CONTROL)))
        limits = (inv[:dof], inv[dof : 2 * dof], inv[2 * dof :])
        x1, residual, rows = stage(xs[0], xs[1], *controls, D[k], q1, q2, q3, e1, e2, *limits, ta, tb)
        w += [x[k], u[k]]
        g += [x[k + 1] - x1 / x_scale, residual / residual_scale, rows]
        equality += [True] * _EQUALITIES + [False] * rows.shape[0]
    w.append(x[n])
    p = ca.vertcat(D, *(ca.vec(mat) for mat in per_stage), inv, scale)
    objective = ca.sum1(ca.vertcat(*(uk[0] for uk in u)))
    return _Program(n, dof, torque, {"x": ca.vertcat(*w), "p": p, "f": objective, "g": ca.vertcat(*g)}, equality)


# --- from a path and its TOPP-RA solution to the program's numbers and back -------------------------
@dataclass(frozen=True)
class WarmProfile:
    """The TOPP-RA solution's s'^2 along the path, brought to rest where the jerk-limited motion
    must be at rest (the ends and every C1 waypoint, ``curvature_jumps``): the program's grid
    and its start come from it."""

    s: NDArray[np.float64]  # samples along the path
    x: NDArray[np.float64]  # s'^2 there
    t: NDArray[np.float64]  # time there, for s'' constant between samples

    @classmethod
    def of(cls, warm: Trajectory, stops: NDArray[np.float64]) -> WarmProfile:
        length = warm.gridpoints[-1]
        s = np.union1d(np.union1d(warm.gridpoints, np.linspace(0.0, length, 1001)), stops)
        x = np.interp(s, warm.gridpoints, warm.sd**2)
        if len(stops):
            # braking into and out of each stop at a typical path acceleration of the TOPP-RA solution
            accel = np.percentile(np.abs(warm.sdd), 75)
            distance = np.min(np.abs(s[:, None] - stops[None, :]), axis=1)
            x = np.minimum(x, 2.0 * accel * distance)
        v = np.sqrt(np.maximum(x, 0.0))
        with np.errstate(divide="ignore"):
            dt = 2.0 * np.diff(s) / (v[:-1] + v[1:])
        return cls(s, x, np.concatenate(([0.0], np.cumsum(np.where(np.isfinite(dt), dt, 0.0)))))

    def grid(self, waypoint_s: NDArray[np.float64], rests: NDArray[np.float64], n: int) -> NDArray[np.float64]:
        """n intervals: every waypoint, and between two waypoints points evenly spaced in this
        profile's time (the intervals shared out by the time spent between them), at least
        ``MIN_REST_TO_REST`` between two rests (``rests``: a subset of the waypoints).

        Even in time, not in s: the grid is dense where the motion is slow, where its
        accelerations and their switches are, and where most of the duration is; each jerk
        switch needs a gridpoint.
        """
        segments = len(waypoint_s) - 1
        section = np.searchsorted(rests, waypoint_s[:-1], side="right") - 1  # the rest-to-rest part of each segment
        floor = np.ones(segments, dtype=int)
        for k in range(len(rests) - 1):
            inside = np.flatnonzero(section == k)
            longest = inside[np.argmax(np.diff(waypoint_s)[inside])]
            floor[longest] += max(0, MIN_REST_TO_REST - len(inside))
        if n < floor.sum():
            raise ValueError(f"{n} intervals cannot hold {segments} waypoint segments and {len(rests) - 2} stops")
        tw = np.interp(waypoint_s, self.s, self.t)
        share = np.diff(tw) / tw[-1] * n
        count = np.maximum(floor, np.floor(share)).astype(int)
        while count.sum() > n:
            count[np.argmax(np.where(count > floor, count - share, -np.inf))] -= 1
        while count.sum() < n:
            count[np.argmax(share - count)] += 1
        parts = [np.interp(np.linspace(tw[i], tw[i + 1], c + 1)[1:-1], self.t, self.s) for i, c in enumerate(count)]
        return np.sort(np.concatenate((waypoint_s, *parts)))


def curvature_jumps(path: JointPath) -> NDArray[np.float64]:
    """|q_ss(s+) - q_ss(s-)| at every inner waypoint, (N - 2, dof): where the path is C1 only.

    There q'' = q_ss s'^2 + q_s s'' jumps by (q_ss+ - q_ss-) s'^2 whatever s'' does (one scalar
    cannot cancel a jump in dof directions): a finite jerk passes such a waypoint at rest.
    """
    x, c = path.pieces
    h = np.diff(x)[:-1, None]
    end = 6.0 * c[0, :-1] * h + 2.0 * c[1, :-1]  # q_ss at the end of each piece but the last
    return np.abs(2.0 * c[1, 1:] - end)


def _rows(
    path: JointPath, grid: NDArray[np.float64], limits: JointLimits, constraints: Sequence[constraint.Constraint]
) -> _Rows:
    """The numbers of the program's rows on ``grid``, from the cell's toppra constraints."""
    n = len(grid) - 1
    _, q1, q2, q3 = _interval_coefficients(path, grid)
    D = np.diff(grid)
    mid = 0.5 * (grid[:-1] + grid[1:])
    sd_max = np.full(n + 1, np.inf)
    sd_max_mid = np.full(n, np.inf)
    torque = None
    for c in constraints:
        if isinstance(c, _SPEED_CONSTRAINTS):
            with np.errstate(divide="ignore"):
                sd_max = np.minimum(sd_max, np.min(c.limit / np.abs(c.speed_factors(path, grid)), axis=1))
                if not isinstance(c, IntervalJointVelocityConstraint):
                    sd_max_mid = np.minimum(sd_max_mid, np.min(c.limit / np.abs(c.speed_factors(path, mid)), axis=1))
        elif isinstance(c, RneaJointTorqueConstraint):
            a, b, cc, _F, _g, _ub, _xb = c.compute_constraint_params(path, grid[:-1])
            torque = (a / c.effort, b / c.effort, -1.0 - cc / c.effort, 1.0 - cc / c.effort)
        elif not isinstance(c, IntervalJointAccelerationConstraint):
            raise ValueError(f"the jerk-limited timing cannot hold a {type(c).__name__}")
    e1 = q1 + D[:, None] * (q2 + 0.5 * D[:, None] * q3)
    e2 = q2 + D[:, None] * q3
    return _Rows(D, q1, q2, q3, e1, e2, sd_max, sd_max_mid, torque)


def _bounds(rows: _Rows, program: _Program) -> dict[str, NDArray[np.float64]]:
    """lbx, ubx, lbg, ubg of the program for ``rows``: rest at both ends and at every stop, speed
    boxes, row bounds."""
    n, dof = program.n, program.dof
    width = len(_STATE) + len(_CONTROL)
    lbx, ubx = np.full((n + 1, width), -np.inf), np.full((n + 1, width), np.inf)
    lbx[:, 0], ubx[:, 0] = 0.0, rows.sd_max
    # no interval is crossed faster than at a quarter of the highest speed allowed anywhere: keeps the
    # solver away from h -> 0, where the distance row loses its gradient (a trap of local infeasibility)
    finite = rows.sd_max[np.isfinite(rows.sd_max) & (rows.sd_max > 0.0)]
    lbx[:-1, 2] = 0.25 * rows.D / (np.max(finite) if len(finite) else 1e6)
    first_sd = len(_STATE) + 2 + len(_FRACTIONS)  # the column of the first lifted s'
    lbx[:-1, first_sd : first_sd + len(_FRACTIONS)] = 0.0
    ubx[:-1, first_sd + _MIDDLE_INDEX] = rows.sd_max_mid
    # at rest with zero acceleration at both ends and at every stop on the way (a stop with s'' != 0
    # would run backwards along the path on one side of it)
    rest = rows.sd_max == 0.0
    rest[[0, n]] = True
    lbx[rest, :2] = ubx[rest, :2] = 0.0
    one = np.ones((n, dof))
    lo, hi = [np.zeros((n, _EQUALITIES)), -one], [np.zeros((n, _EQUALITIES)), one]
    if rows.torque is not None:
        lo.append(rows.torque[2])
        hi.append(rows.torque[3])
    rest_rows = 2 * len(_FRACTIONS) + _JERK_ROWS
    lo += [-one] * rest_rows
    hi += [one] * rest_rows
    cut = len(_CONTROL)  # the last stage has a state only
    return {
        "lbx": lbx.ravel()[:-cut],
        "ubx": ubx.ravel()[:-cut],
        "lbg": np.hstack(lo).ravel(),
        "ubg": np.hstack(hi).ravel(),
    }


def _parameters(rows: _Rows, limits: JointLimits, max_jerk: NDArray[np.float64]) -> NDArray[np.float64]:
    zero = np.zeros_like(rows.q1)
    ta, tb = (rows.torque[0], rows.torque[1]) if rows.torque is not None else (zero, zero)
    per_stage = (rows.q1, rows.q2, rows.q3, rows.e1, rows.e2, ta, tb)
    inv = np.concatenate((1.0 / limits.velocity, 1.0 / limits.acceleration, 1.0 / max_jerk))
    return np.concatenate((rows.D, *(m.ravel("F") for m in per_stage), inv))


def _scales(start: NDArray[np.float64]) -> NDArray[np.float64]:
    """A typical magnitude of each of a stage's variables (the 90th percentile of its |start| over
    the stages, 1 where that is 0): fatrop, unlike ipopt, does not scale a program itself, and the
    jerk s''' is orders of magnitude larger than the times h."""
    width = len(_STATE) + len(_CONTROL)
    stages = np.append(start, np.zeros(len(_CONTROL))).reshape(-1, width)[:-1]
    typical = np.percentile(np.abs(stages), 90, axis=0)
    return np.where(typical > 0.0, typical, 1.0)


def _start(
    profile: WarmProfile, grid: NDArray[np.float64], rows: _Rows, max_jerk: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The program's variables along ``profile`` on ``grid``, within the speed bounds: s' and a
    smoothed s'' (TOPP-RA's jumps between its intervals) at the gridpoints, the times between
    them, the jerk that joins the s'', and the middles that follow from those.

    Slowed down uniformly until its joint jerk at the interval starts is at most
    ``_START_JERK_SLACK`` of the limit: a start inside the jerk rows, with room to speed up. From a
    start far outside them (a limit far below the TOPP-RA profile's jerk) the solvers spend their
    time in restoration; from one near or on them, fatrop's iterations have a long tail
    (bench/RESULTS.md)."""
    x = np.minimum(np.interp(grid, profile.s, profile.x), rows.sd_max**2)
    sd = np.sqrt(np.maximum(x, 0.0))
    a = 0.5 * np.gradient(x, grid)
    a[rows.sd_max == 0.0] = 0.0
    a[[0, -1]] = 0.0
    h = np.diff(grid) / np.maximum(0.5 * (sd[:-1] + sd[1:]), 1e-3 * np.max(sd))
    j = np.diff(a) / h
    v, u = sd[:-1, None], a[:-1, None]
    jerk = rows.q3 * v**3 + 3.0 * rows.q2 * v * u + rows.q1 * j[:, None]
    k = np.cbrt(max(1.0, float(np.max(np.abs(jerk) / max_jerk) / _START_JERK_SLACK)))
    sd, a, h, j = sd / k, a / (k * k), h * k, j / (k * k * k)
    v, u = sd[:-1], a[:-1]
    tau = [f * h for f in _FRACTIONS]
    sigma = [t * (v + t * (0.5 * u + t * j / 6.0)) for t in tau]
    speed = [np.maximum(v + t * (u + 0.5 * j * t), 0.0) for t in tau]
    stages = np.column_stack((v, u, h, j, *sigma, *speed))
    return np.concatenate((stages.ravel(), [0.0, 0.0]))


@dataclass(frozen=True)
class _Solution:
    sd: NDArray[np.float64]  # (n + 1,)
    sdd: NDArray[np.float64]  # (n + 1,)
    h: NDArray[np.float64]  # (n,)
    j: NDArray[np.float64]  # (n,)
    solver: str
    iterations: int
    optimal: bool = True


def _solvers_for(program: _Program, time_left: float) -> tuple[str, ...]:
    """The solvers worth starting with ``time_left`` (s) before the deadline (module docstring)."""
    names = ("fatrop",) if time_left >= program.expected_fatrop_s() else ()
    return (*names, "ipopt") if time_left >= _IPOPT_TIME_S else names


def _solve_now(
    program: _Program,
    args: dict[str, Any],
    scale: NDArray[np.float64],
    deadline: float,
    names: tuple[str, ...] = ("fatrop", "ipopt"),
) -> tuple[_Solution | None, str, bool]:
    """``names`` in turn (fatrop, then ipopt from the same start where fatrop does not converge;
    ``args`` scaled by ``scale``, the solution is not). The third value: whether the deadline
    stopped it."""
    statuses = []
    width = len(_STATE) + len(_CONTROL)

    def solution(x: Any, name: str, iterations: int, optimal: bool = True) -> _Solution:
        w = np.append(np.asarray(x).ravel(), np.zeros(len(_CONTROL))).reshape(program.n + 1, width) * scale
        return _Solution(w[:, 0], w[:, 1], w[:-1, 2], w[:-1, 3], name, iterations, optimal)

    for name in names:
        if time.perf_counter() >= deadline:
            return None, "; ".join(statuses), True
        solver = program.solver(name)
        if program.stop is not None:
            program.stop.reset(deadline)
        began = time.perf_counter()
        out = solver(**args)
        if name == "fatrop":
            program.fatrop_s.append(time.perf_counter() - began)
        stats = solver.stats()
        if stats["success"]:
            return solution(out["x"], name, int(stats.get("iter_count", 0))), "", False
        status = stats.get("return_status", "")
        if status == "User_Requested_Stop":  # the deadline, through ``_Deadline``: its best iterate, if any
            best = program.stop.best if program.stop is not None else None
            iterations = int(stats.get("iter_count", 0))
            return (None if best is None else solution(best, name, iterations, False)), "; ".join(statuses), True
        statuses.append(f"{name}: {status}" if isinstance(status, str) else f"{name}: failed (return status {status})")
    return None, "; ".join(statuses), False


def _solve(
    program: _Program, args: dict[str, Any], scale: NDArray[np.float64], deadline: float | None
) -> tuple[_Solution | None, str, bool]:
    """``_solve_now`` within ``deadline`` (time.perf_counter; None: as long as it takes).

    With a deadline the solve runs in a thread (casadi releases the GIL while it solves) and is
    waited for until the deadline: ipopt stops there itself (``_Deadline``), fatrop cannot be
    stopped and finishes in its thread, its answer unused; the next solve of the same program
    waits for it (``_Program.lock``), within its own deadline."""
    if deadline is None:
        with program.lock:
            return _solve_now(program, args, scale, float("inf"))
    names = _solvers_for(program, deadline - time.perf_counter())
    if not names:  # no solver can answer in time: the floor at once, no thread holding the interpreter
        return None, "", True
    result: list[tuple[_Solution | None, str, bool]] = []

    def work() -> None:
        if program.lock.acquire(timeout=max(0.0, deadline - time.perf_counter())):
            try:  # the time left again: a solve past its own deadline may have held the lock
                now_names = _solvers_for(program, deadline - time.perf_counter())
                result.append(_solve_now(program, args, scale, deadline, now_names))
            finally:
                program.lock.release()

    # not a daemon: an interpreter that exits waits for the solve instead of tearing casadi down under it
    thread = threading.Thread(target=work, name="jerk-solve", daemon=False)
    thread.start()
    thread.join(max(0.0, deadline - time.perf_counter()))
    return result[0] if result else (None, "", True)


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
    k = max(factors)
    return traj.slowed(k * (1.0 + SLOWDOWN_MARGIN)) if k > 1.0 else traj


def jerk_limited(
    path: JointPath,
    limits: JointLimits,
    constraints: Sequence[constraint.Constraint],
    max_jerk: ArrayLike,
    warm: Trajectory,
    intervals: int = DEFAULT_JERK_INTERVALS,
    deadline: float | None = None,
) -> JerkTrajectory:
    """The time-optimal rest-to-rest trajectory along ``path`` with |q'''_j| <= max_jerk_j besides
    ``constraints`` (the cell's toppra constraints, held as TOPP-RA holds them), started from
    ``warm``, the TOPP-RA solution of the same path and constraints.

    PlanError(INFEASIBLE) where no solver converges (the message carries their statuses).

    Anytime with a ``deadline`` (time.perf_counter): where the solvers have not finished by then,
    the answer is the S-curve floor (``planner.scurve``), ``optimal`` False; time alone never makes
    it INFEASIBLE. ``lower_bound``: TOPP-RA's duration, which no jerk-limited timing beats.
    """
    jmax = np.asarray(max_jerk, dtype=float)
    # at rest at both ends and at every waypoint where the path is C1 only (``curvature_jumps``)
    stops = path.waypoint_s[1:-1][np.any(curvature_jumps(path) > _CURVATURE_JUMP, axis=1)]
    rests = np.concatenate(([0.0], stops, [path.length]))
    n = max(int(intervals), (len(path.waypoint_s) - 1) + MIN_REST_TO_REST * (len(rests) - 1))
    profile = WarmProfile.of(warm, rests)
    grid = profile.grid(path.waypoint_s, rests, n)
    rows = _rows(path, grid, limits, constraints)
    rows.sd_max[np.searchsorted(grid, stops)] = 0.0
    program = _program(n, limits.dof, rows.torque is not None)
    start = _start(profile, grid, rows, jmax)
    scale = _scales(start)
    per_variable = np.tile(scale, n + 1)[: len(start)]
    args = {k: v / per_variable for k, v in _bounds(rows, program).items() if k in ("lbx", "ubx")}
    args |= {k: v for k, v in _bounds(rows, program).items() if k in ("lbg", "ubg")}
    args["p"] = np.concatenate((_parameters(rows, limits, jmax), scale))
    args["x0"] = start / per_variable
    sol, status, late = _solve(program, args, scale, deadline)
    if sol is None and not late:
        raise PlanError(
            PlanResult.INFEASIBLE,
            f"the jerk-limited timing found no trajectory within the limits ({status})",
            solver_status=status,
        )
    if sol is None:  # the deadline first: the floor that needs no solver (planner/scurve.py)
        g, sd, sdd, sddd, t = rest_to_rest(path, rests, limits, jmax)
        traj = JerkTrajectory(path, g, sd, sdd, sddd, t, limits.names, solver="scurve", optimal=False)
    else:
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
    traj = dataclasses.replace(traj, lower_bound=warm.duration)
    return _checked(traj, limits, jmax, constraints)
