"""Time-optimal parameterization of a joint path with TOPP-RA, and the trajectory it gives.

toppra solves for the path velocity s'(s) on a grid under the joint velocity and acceleration
limits (and, where the robot has them, joint torques through Pinocchio's RNEA and a TCP speed
limit through the frame Jacobian). Between gridpoints the path acceleration s'' is constant, so
the trajectory here is exact for that profile ("constant acceleration" parametrizer).

Torque and TCP speed need Pinocchio at every sample: those calls are batched (one RNEA call for
a whole grid), and torque limits, which rarely bind, are checked on the result of a solve without
them before being solved with (see ``parameterize``).

TOPP-RA enforces the constraints at the gridpoints. Between them the joint velocity and
acceleration can exceed the limits by a hair; the trajectory is checked densely afterwards and,
where needed, slowed down uniformly by the smallest factor that brings it inside (reported as
``time_scale``). That keeps the result honest on a coarse, fast grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import toppra.algorithm as algo
import toppra.constraint as constraint
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog
from toppra.algorithm.algorithm import ParameterizationAlgorithm
from toppra.constants import MAX_TRIES, SMALL, TINY
from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

from planner.limits import JointLimits
from planner.model import RobotModel
from planner.path import JointPath, PlanError, PlanResult, interval, spline_at, spline_piece

DEFAULT_GRIDPOINTS = 140
# sub-samples per grid interval for the post-check
_CHECK_SUBSAMPLES = 8


_X_MAX = 1e8  # bound on s'^2 where nothing binds (the solver wants finite numbers)


class _IntervalSpeedConstraint(constraint.LinearConstraint):
    """A speed bound |G(s) q'(s)| s' <= limit held at the start, middle and end of every grid interval.

    toppra's joint velocity constraint bounds s' at the gridpoints only, and between them |qd| can
    overshoot by a few percent on a coarse grid. Here the bound is imposed inside the interval:
    with u = s'' constant on [s_i, s_i+1], s'^2 at s_i + sigma is x_i + 2 u sigma, so each sample
    gives the linear row  G^2 (x_i + 2 u sigma) <= limit^2  on the stage variables (u, x_i). All the
    quantities at one sample share that direction: only the tightest, x_i + 2 u sigma <=
    min(limit^2 / G^2), can bind, so one row per sample says exactly the same with m times fewer
    rows for the solver to copy and check.
    """

    # where inside each interval the bound is held; both ends are the gridpoints' boxes on x (the
    # end's box binds through the next stage's controllable set)
    FRACTIONS = np.array([0.25, 0.5, 0.75])

    def __init__(self, limit: NDArray[np.float64]) -> None:
        super().__init__()
        self.limit = np.asarray(limit, dtype=float)
        self.identical = True

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """(len(s), m): speed of each bounded quantity per unit path speed at s."""
        raise NotImplementedError

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        n, f = len(gridpoints), len(self.FRACTIONS)
        delta = np.append(np.diff(gridpoints), 0.0)
        sigma = delta[:, None] * self.FRACTIONS[None, :]  # (n, f)
        # the end of interval i is gridpoint i + 1: the gridpoints and the inner samples in one evaluation
        inner = self.FRACTIONS < 1.0
        s_inner = (gridpoints[:-1, None] + sigma[:-1, inner]).ravel()
        factors2 = self.speed_factors(path, np.concatenate((gridpoints, s_inner))) ** 2
        with np.errstate(divide="ignore", over="ignore"):
            # the largest s'^2 each sample allows (inf where nothing moves: capped, the solver wants numbers)
            x_max = np.minimum(np.min(self.limit**2 / factors2, axis=1), _X_MAX)
        at_grid = x_max[:n]
        bound = np.empty((n, f))
        bound[:-1, inner] = x_max[n:].reshape(n - 1, int(inner.sum()))
        bound[:-1, ~inner] = at_grid[1:, None]
        bound[-1] = at_grid[-1]
        # rows 2 sigma u + x - bound <= 0
        xbound = np.column_stack((np.zeros(n), at_grid))
        return 2.0 * sigma, np.ones((n, f)), -bound, np.eye(f), np.zeros(f), None, xbound


class IntervalJointVelocityConstraint(_IntervalSpeedConstraint):
    """|qd_j| <= vmax_j inside every grid interval, not only at the gridpoints."""

    def __init__(self, vmax: NDArray[np.float64]) -> None:
        super().__init__(vmax)
        self.dof = len(self.limit)
        self._format_string = "    Joint velocity limit (interval-sampled)\n"

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        return path(s, 1)


class IntervalJointAccelerationConstraint(constraint.LinearConstraint):
    """|qdd_j| <= amax_j at the start, middle and end of every grid interval.

    toppra's interpolation discretization holds the bound at both ends of an interval; the middle
    row closes most of the remaining gap. With u constant on the interval and
    s'^2 = x + 2 u sigma, qdd = q''(s) s'^2 + q'(s) u = (q' + 2 sigma q'') u + q'' x: linear in (u, x).
    Every sample is taken on the interval's own path piece (the path's q'' may jump at a waypoint).
    """

    FRACTIONS = np.array([0.0, 0.5, 1.0])

    def __init__(self, amax: NDArray[np.float64]) -> None:
        super().__init__()
        self.amax = np.asarray(amax, dtype=float)
        self.dof = len(self.amax)
        self.identical = True
        self._format_string = "    Joint acceleration limit (interval-sampled)\n"

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        n, f = len(gridpoints), len(self.FRACTIONS)
        sigma = np.append(np.diff(gridpoints), 0.0)[:, None] * self.FRACTIONS[None, :]
        # every sample on its interval's own piece: q_ss may jump at a waypoint (a gridpoint), and
        # the interval that ends there is held with the q_ss of the piece that ends there
        anchor = np.repeat(gridpoints, f)
        s = anchor + sigma.ravel()
        qs = path.on_piece_of(anchor, s, 1).reshape(n, f, -1)
        qss = path.on_piece_of(anchor, s, 2).reshape(n, f, -1)
        a = (qs + 2.0 * sigma[:, :, None] * qss).reshape(n, -1)
        b = qss.reshape(n, -1)
        m = a.shape[1]
        F = np.vstack((np.eye(m), -np.eye(m)))
        g = np.tile(self.amax, 2 * f)
        return a, b, np.zeros_like(a), F, g, None, None


class TcpSpeedConstraint(_IntervalSpeedConstraint):
    """|v_tcp| <= max_speed at ``frame``'s origin, at the gridpoints and mid-interval (the frame
    speed per unit path speed comes from one batched Pinocchio call for all samples)."""

    FRACTIONS = np.array([0.5])

    def __init__(self, model: RobotModel, frame: str, max_speed: float) -> None:
        super().__init__(np.array([float(max_speed)]))
        self.model = model
        self.frame = frame
        self.dof = model.dof
        self._format_string = f"    TCP speed limit: {max_speed} m/s at {frame}\n"

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.model.frame_speeds(path(s), path(s, 1), self.frame)[:, None]


class TcpAngularSpeedConstraint(_IntervalSpeedConstraint):
    """|omega_tcp| <= max_speed (rad/s) of ``frame``, sampled as TcpSpeedConstraint is (one batched
    Pinocchio call: ``RobotModel.frame_angular_speeds``)."""

    FRACTIONS = np.array([0.5])

    def __init__(self, model: RobotModel, frame: str, max_speed: float) -> None:
        super().__init__(np.array([float(max_speed)]))
        self.model = model
        self.frame = frame
        self.dof = model.dof
        self._format_string = f"    TCP angular speed limit: {max_speed} rad/s at {frame}\n"

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.model.frame_angular_speeds(path(s), path(s, 1), self.frame)[:, None]


class RneaJointTorqueConstraint(constraint.LinearConstraint):
    """|tau_j| <= effort_j at every gridpoint (toppra's collocation scheme), tau from Pinocchio's RNEA.

    Along the path tau = a(s) s'' + b(s) s'^2 + c(s) with c = g(q) = rnea(q, 0, 0),
    a = M(q) q' = rnea(q, 0, q') - c and b = M(q) q'' + C(q, q') q' = rnea(q, q', q'') - c: the
    three RNEAs per gridpoint of toppra's JointTorqueConstraint, same numbers, but all in one
    batched Pinocchio call (3 N Python calls were a quarter of a plan).
    """

    def __init__(self, model: RobotModel, effort: NDArray[np.float64]) -> None:
        super().__init__()
        self.model = model
        self.effort = np.asarray(effort, dtype=float)
        self.dof = len(self.effort)
        self.identical = True
        self._format_string = "    Joint torque limit (RNEA, collocation)\n"

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        n = len(gridpoints)
        q, qs, qss = path(gridpoints), path(gridpoints, 1), path(gridpoints, 2)
        zero = np.zeros_like(q)
        tau = self.model.inverse_dynamics_rows(
            np.concatenate((q, q, q)), np.concatenate((zero, zero, qs)), np.concatenate((zero, qs, qss))
        )
        c = tau[:n]
        a = tau[n : 2 * n] - c
        b = tau[2 * n :] - c
        F = np.vstack((np.eye(self.dof), -np.eye(self.dof)))
        return a, b, c, F, np.tile(self.effort, 2), None, None

    def holds_on(self, traj: Trajectory) -> bool:
        """True when ``traj`` meets the limits where this constraint would hold them: at every
        gridpoint, with the s'' of the interval that starts there (the last: the one that ends there)."""
        grid, sd = traj.gridpoints, traj.sd
        sdd = np.append(traj.sdd, traj.sdd[-1])
        qs, qss = traj.path(grid, 1), traj.path(grid, 2)
        qd = qs * sd[:, None]
        qdd = qss * (sd * sd)[:, None] + qs * sdd[:, None]
        tau = self.model.inverse_dynamics_rows(traj.path(grid), qd, qdd)
        return bool(np.all(np.abs(tau) <= self.effort))


@njit(cache=True)
def _path_state(
    t: float,
    i: int,
    breakpoints: NDArray[np.float64],
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
) -> tuple[float, float, float, int]:
    """s, s', s'' at time t (clipped to the motion), and its grid interval (``i``: a hint for it):
    s'' is constant between two gridpoints."""
    t = min(max(t, 0.0), breakpoints[-1])
    i = interval(breakpoints, t, i, len(sdd) - 1)
    tau = t - breakpoints[i]
    s = min(gridpoints[i] + sd[i] * tau + 0.5 * sdd[i] * tau * tau, gridpoints[i + 1])
    return s, sd[i] + sdd[i] * tau, sdd[i], i


@njit(cache=True)
def _path_states(
    t: NDArray[np.float64],
    breakpoints: NDArray[np.float64],
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """s, s', s'' at every t, and the start (s) of the grid interval each lies in."""
    s, s_d, s_dd, start = np.empty(len(t)), np.empty(len(t)), np.empty(len(t)), np.empty(len(t))
    i = 0
    for k in range(len(t)):
        s[k], s_d[k], s_dd[k], i = _path_state(t[k], i, breakpoints, gridpoints, sd, sdd)
        start[k] = gridpoints[i]
    return s, s_d, s_dd, start


@njit(cache=True)
def _joint_states(
    t: NDArray[np.float64],
    breakpoints: NDArray[np.float64],
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """q and q' = q_s(s) s', each (dof, len(t)), in one pass."""
    dof = c.shape[2]
    q, qd = np.empty((dof, len(t))), np.empty((dof, len(t)))
    g, i = 0, 0
    for k in range(len(t)):
        s, s_d, _, g = _path_state(t[k], g, breakpoints, gridpoints, sd, sdd)
        i, h = spline_piece(x, gridpoints[g], s, i)
        for j in range(dof):
            q[j, k], q_s, _ = spline_at(c, i, h, j)
            qd[j, k] = q_s * s_d
    return q, qd


@njit(cache=True)
def _worst_ratios(
    t: NDArray[np.float64],
    breakpoints: NDArray[np.float64],
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    vmax: NDArray[np.float64],
    amax: NDArray[np.float64],
) -> tuple[float, float]:
    """max |q'| / vmax and max |q''| / amax over the times t, q' = q_s s', q'' = q_ss s'^2 + q_s s''."""
    rv, ra = 0.0, 0.0
    g, i = 0, 0
    for k in range(len(t)):
        s, s_d, s_dd, g = _path_state(t[k], g, breakpoints, gridpoints, sd, sdd)
        i, h = spline_piece(x, gridpoints[g], s, i)
        for j in range(c.shape[2]):
            _, q_s, q_ss = spline_at(c, i, h, j)
            rv = max(rv, abs(q_s * s_d) / vmax[j])
            ra = max(ra, abs(q_ss * s_d * s_d + q_s * s_dd) / amax[j])
    return rv, ra


@njit(cache=True)
def _interval_peaks(
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    vmax: NDArray[np.float64],
    amax: NDArray[np.float64],
) -> tuple[float, float]:
    """max |q'| / vmax and max |q''| / amax inside the grid intervals, exactly.

    With s'' = u constant on an interval and s'^2 = x_i + 2 u sigma, q'' = q_ss (x_i + 2 u sigma)
    + q_s u is a quadratic in sigma on the interval's piece (q_ss linear, q_s quadratic): its peak
    is at an end or at its vertex, and |q'| = |q_s| s' peaks at an end or where q'' = 0, a root of
    that quadratic. The ends are gridpoints, which the check times hold; here the inside."""
    rv, ra = 0.0, 0.0
    i = 0
    f = np.empty(3)
    for g in range(len(sdd)):
        delta = gridpoints[g + 1] - gridpoints[g]
        x_g, u = sd[g] * sd[g], sdd[g]
        for j in range(c.shape[2]):
            for m in range(3):
                i, h = spline_piece(x, gridpoints[g], gridpoints[g] + 0.5 * m * delta, i)
                _, q_s, q_ss = spline_at(c, i, h, j)
                f[m] = q_ss * (x_g + u * m * delta) + q_s * u
            # the quadratic through the three, f0 + b r + a r^2 with r = sigma / delta
            a = 2.0 * (f[0] - 2.0 * f[1] + f[2])
            b = 4.0 * f[1] - 3.0 * f[0] - f[2]
            r = -b / (2.0 * a) if a != 0.0 else -1.0
            if 0.0 < r < 1.0:
                ra = max(ra, abs(f[0] + (b + a * r) * r) / amax[j])
            # where q'' = 0 inside: the velocity's extrema
            if a != 0.0:
                disc = b * b - 4.0 * a * f[0]
                roots = (math.nan, math.nan)
                if disc >= 0.0:
                    sq = math.sqrt(disc)
                    roots = ((-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a))
            else:
                roots = (-f[0] / b if b != 0.0 else math.nan, math.nan)
            for r0 in roots:
                if 0.0 < r0 < 1.0:
                    sigma = r0 * delta
                    i, h = spline_piece(x, gridpoints[g], gridpoints[g] + sigma, i)
                    _, q_s, _ = spline_at(c, i, h, j)
                    rv = max(rv, abs(q_s) * math.sqrt(max(x_g + 2.0 * u * sigma, 0.0)) / vmax[j])
    return rv, ra


@dataclass(frozen=True)
class Trajectory:
    """q(t) = path(s(t)) with s'' constant between gridpoints: numbers in, numbers out.

    ``breakpoints`` are the times of the gridpoints: the joint acceleration is continuous between
    two of them and may jump at them (where the time-optimal profile switches).
    """

    path: JointPath
    gridpoints: NDArray[np.float64]  # s at the grid
    sd: NDArray[np.float64]  # s' at the grid
    sdd: NDArray[np.float64]  # s'' on each interval
    breakpoints: NDArray[np.float64]  # t at the grid [s]
    joint_names: tuple[str, ...]
    time_scale: float = 1.0  # >1 when the post-check slowed the raw TOPP-RA profile down

    @classmethod
    def from_path_velocities(
        cls, path: JointPath, gridpoints: NDArray[np.float64], sd: NDArray[np.float64], joint_names: tuple[str, ...]
    ) -> Trajectory:
        ds = np.diff(gridpoints)
        sd = np.maximum(sd, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            dt = 2.0 * ds / (sd[:-1] + sd[1:])
        if not np.all(np.isfinite(dt)):
            raise PlanError(PlanResult.INFEASIBLE, "the time-optimal profile stalls on the path (zero path velocity)")
        sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
        t = np.concatenate(([0.0], np.cumsum(dt)))
        return cls(path, gridpoints, sd, sdd, t, joint_names)

    def slowed(self, k: float) -> Trajectory:
        """The same motion k times slower (velocities / k, accelerations / k^2)."""
        return Trajectory(
            self.path,
            self.gridpoints,
            self.sd / k,
            self.sdd / (k * k),
            self.breakpoints * k,
            self.joint_names,
            self.time_scale * k,
        )

    @property
    def duration(self) -> float:
        return float(self.breakpoints[-1])

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def waypoint_times(self) -> NDArray[np.float64]:
        """When the trajectory passes each waypoint [s]."""
        return self.time_at(self.path.waypoint_s)

    def time_at(self, s: ArrayLike) -> NDArray[np.float64]:
        """Inverse of s(t) on the grid (exact for constant s'' per interval)."""
        s = np.clip(np.asarray(s, dtype=float), self.gridpoints[0], self.gridpoints[-1])
        i = np.clip(np.searchsorted(self.gridpoints, s, side="right") - 1, 0, len(self.sdd) - 1)
        ds = s - self.gridpoints[i]
        a, v = self.sdd[i], self.sd[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            disc = np.sqrt(np.maximum(v * v + 2.0 * a * ds, 0.0))
            tau = np.where(np.abs(a) > 1e-12, (disc - v) / a, ds / v)
        return self.breakpoints[i] + np.where(ds > 0, tau, 0.0)

    def _state(
        self, t: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], bool]:
        """s, s', s'' at t, the start of each one's grid interval (the anchor of its path piece), and
        whether t was a scalar."""
        t_arr = np.asarray(t, dtype=float)
        scalar = t_arr.ndim == 0
        s, sd, sdd, start = _path_states(
            np.atleast_1d(t_arr).ravel(), self.breakpoints, self.gridpoints, self.sd, self.sdd
        )
        return s, sd, sdd, start, scalar

    def _profile_and_path(self) -> tuple[NDArray[np.float64], ...]:
        """What the compiled loops need of the motion: the s'' profile and the path's cubic pieces."""
        return self.breakpoints, self.gridpoints, self.sd, self.sdd, *self.path.pieces

    def states(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions and velocities, each (dof, len(t)), at the times t in one pass: for sampling
        at every drive ms (one row per joint, as the drives take them)."""
        return _joint_states(np.atleast_1d(np.asarray(t, dtype=float)).ravel(), *self._profile_and_path())

    def acceleration_jumps(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The times of the inner gridpoints and |q''(t+) - q''(t-)| there, (n, dof): where the
        time-optimal profile switches or the path's curvature jumps (at a waypoint where it is C1
        only), and by how much. s, s' and q_s are continuous, so q'' = q_ss s'^2 + q_s s'' jumps
        by q_s (s''_i - s''_(i-1)) + (q_ss+ - q_ss-) s'^2."""
        grid = self.gridpoints
        qs = self.path(grid[1:-1], 1)
        curvature = self.path(grid[1:-1], 2) - self.path.on_piece_of(grid[:-2], grid[1:-1], 2)
        jump = qs * np.diff(self.sdd)[:, None] + curvature * (self.sd[1:-1] ** 2)[:, None]
        return self.breakpoints[1:-1], np.abs(jump)

    def position(self, t: ArrayLike) -> NDArray[np.float64]:
        s, _, _, start, scalar = self._state(t)
        q = self.path.on_piece_of(start, s, 0)
        return q[0] if scalar else q

    def velocity(self, t: ArrayLike) -> NDArray[np.float64]:
        s, sd, _, start, scalar = self._state(t)
        qd = self.path.on_piece_of(start, s, 1) * sd[:, None]
        return qd[0] if scalar else qd

    def acceleration(self, t: ArrayLike) -> NDArray[np.float64]:
        s, sd, sdd, start, scalar = self._state(t)
        q_s, q_ss = self.path.on_piece_of(start, s, 1), self.path.on_piece_of(start, s, 2)
        qdd = q_ss * (sd * sd)[:, None] + q_s * sdd[:, None]
        return qdd[0] if scalar else qdd

    def check_times(self, subsamples: int = _CHECK_SUBSAMPLES) -> NDArray[np.float64]:
        """Gridpoint times plus ``subsamples`` evenly spaced times inside every interval (one-sided
        at the ends so that both accelerations of a switch are seen)."""
        f = np.arange(subsamples + 2) / (subsamples + 1)
        bp = self.breakpoints
        eps = 1e-9 * max(self.duration, 1.0)
        inner = bp[:-1, None] + np.diff(bp)[:, None] * f[None, :]
        inner[:, 0] += eps
        inner[:, -1] -= eps
        return inner.ravel()

    def limit_ratios(self, limits: JointLimits) -> tuple[float, float]:
        """Worst |qd|/vmax and |qdd|/amax over the check times and at their peaks inside every grid
        interval (exact: ``_interval_peaks``)."""
        vmax, amax = np.asarray(limits.velocity, dtype=float), np.asarray(limits.acceleration, dtype=float)
        rv, ra = _worst_ratios(self.check_times(), *self._profile_and_path(), vmax, amax)
        rv_in, ra_in = _interval_peaks(self.gridpoints, self.sd, self.sdd, *self.path.pieces, vmax, amax)
        return max(rv, rv_in), max(ra, ra_in)


def timing_constraints(
    limits: JointLimits,
    model: RobotModel | None = None,
    torque_limits: bool = False,
    tcp_frame: str | None = None,
    max_tcp_speed: float | None = None,
    max_tcp_angular_speed: float | None = None,
) -> list[constraint.Constraint]:
    """The toppra constraints of a cell: joint velocity and acceleration always; joint torque
    (RNEA) where asked for and the model has effort limits and masses; TCP linear and angular speed
    where asked for."""
    out: list[constraint.Constraint] = [
        IntervalJointVelocityConstraint(limits.velocity),
        IntervalJointAccelerationConstraint(limits.acceleration),
    ]
    if torque_limits and model is not None and model.has_dynamics and np.all(np.isfinite(limits.effort)):
        out.append(RneaJointTorqueConstraint(model, limits.effort))
    if max_tcp_speed is not None:
        if model is None or tcp_frame is None:
            raise ValueError("a TCP speed limit needs the robot model and the TCP frame")
        out.append(TcpSpeedConstraint(model, tcp_frame, max_tcp_speed))
    if max_tcp_angular_speed is not None:
        if model is None or tcp_frame is None:
            raise ValueError("a TCP angular speed limit needs the robot model and the TCP frame")
        out.append(TcpAngularSpeedConstraint(model, tcp_frame, max_tcp_angular_speed))
    return out


class _Computed(constraint.LinearConstraint):
    """A constraint's parameters on one grid, computed once: the solver wrapper and the rest check
    of LeanTOPPRA both read them."""

    def __init__(self, source: constraint.Constraint, params: tuple) -> None:
        super().__init__()
        self.identical = source.identical
        self.params = params

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        return self.params


# the solver wrapper's box on u and x at every stage (toppra's seidel VAR_MIN / VAR_MAX)
_VAR_MAX = 1e8


def _times(F: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """F v at every stage: F the same at every stage (2-D) or one per stage (3-D)."""
    return v @ F.T if F.ndim == 2 else np.einsum("ikj,ij->ik", F, v)


@dataclass(frozen=True)
class _StageRows:
    """Every stage's rows A u + B x + C <= 0 (all constraints stacked, as the solver wrapper does)
    and its boxes on x and u, (n, m) and (n,) arrays: what the LP skips of LeanTOPPRA read."""

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    x_lo: NDArray[np.float64]
    x_hi: NDArray[np.float64]
    u_lo: NDArray[np.float64]
    u_hi: NDArray[np.float64]

    @classmethod
    def stack(cls, params: list[tuple], n: int) -> _StageRows:
        x_lo, x_hi = np.full(n, -_VAR_MAX), np.full(n, _VAR_MAX)
        u_lo, u_hi = np.full(n, -_VAR_MAX), np.full(n, _VAR_MAX)
        A, B, C = [np.zeros((n, 0))], [np.zeros((n, 0))], [np.zeros((n, 0))]
        for a, b, c, F, h, ubound, xbound in params:
            if a is not None:
                A.append(_times(F, a))
                B.append(_times(F, b))
                C.append(_times(F, c) - h)
            if xbound is not None:
                x_lo, x_hi = np.maximum(x_lo, xbound[:, 0]), np.minimum(x_hi, xbound[:, 1])
            if ubound is not None:
                u_lo, u_hi = np.maximum(u_lo, ubound[:, 0]), np.minimum(u_hi, ubound[:, 1])
        return cls(np.hstack(A), np.hstack(B), np.hstack(C), x_lo, x_hi, u_lo, u_hi)

    def rest_feasible(self) -> NDArray[np.bool_]:
        """Stages at which (u, x) = (0, 0), standing still, satisfies every row and box."""
        return np.all(self.C <= 0.0, axis=1) & (self.x_lo <= 0.0) & (self.u_lo <= 0.0) & (self.u_hi >= 0.0)

    def x_extreme(self, i: int, two_delta: float, lo: float, hi: float, highest: bool) -> float:
        """The largest (lowest) x at stage i from which some u satisfies every row and box and
        lands x + two_delta u in [lo, hi]; NaN where none does. HiGHS, for the rare stage whose LP
        toppra's seidel solver gives up on although it is feasible: next to a point where the path
        stops (q' = 0 at a waypoint in a corner of the joint box, or where it reverses), the rows
        there span u from 1e-16 to 1e4 and the seidel solver returns NaN, stock toppra's too."""
        rows = np.column_stack((self.A[i], self.B[i]))
        a_ub = np.vstack((rows, [[two_delta, 1.0], [-two_delta, -1.0]]))
        b_ub = np.concatenate((-self.C[i], [hi, -lo]))
        bounds = [(self.u_lo[i], self.u_hi[i]), (max(self.x_lo[i], 0.0), self.x_hi[i])]
        res = linprog([0.0, -1.0 if highest else 1.0], A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
        return float(res.x[1]) if res.status == 0 else math.nan

    def u_range_at(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The exact range [lo, hi] of u that satisfies every row and box at x (one x per stage;
        lo = inf where none does)."""
        A = self.A
        r = self.B * x[:, None] + self.C
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            bound = -r / A
        hi = np.minimum(self.u_hi, np.min(np.where(A > 0.0, bound, np.inf), axis=1, initial=np.inf))
        lo = np.maximum(self.u_lo, np.max(np.where(A < 0.0, bound, -np.inf), axis=1, initial=-np.inf))
        lo[np.any((A == 0.0) & (r > 0.0), axis=1) | (x < self.x_lo) | (x > self.x_hi)] = np.inf
        return lo, hi


# rows whose u-coefficient is smaller than this are not a bound on u (toppra's seidel solver, TINY)
_SEIDEL_TINY = 1e-10


@njit(cache=True)
def _forward_pass(
    A: NDArray[np.float64],
    B: NDArray[np.float64],
    C: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    x_lo: NDArray[np.float64],
    x_hi: NDArray[np.float64],
    K: NDArray[np.float64],
    two_delta: NDArray[np.float64],
    x_start: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """toppra's greedy forward pass: at every stage the largest u whose x + 2 delta u lands in the
    next controllable set. With x fixed, the stage's LP has one variable, and it is solved as
    toppra's seidel wrapper solves it then (its 1-D LP: the tightest row above and below, rows with
    |a| <= TINY skipped, infeasible when they cross); same safeguards (back off x by TINY or 0.1 %,
    at most MAX_TRIES times, when a stage is infeasible from round-off). Returns u per stage and x
    per gridpoint (NaN from where it gave up)."""
    n = len(two_delta)
    us, xs = np.zeros(n), np.full(n + 1, np.nan)
    xs[0] = x_start
    i, tries, x = 0, 0, x_start
    while i < n:
        k_lo, k_hi = K[i + 1, 0], K[i + 1, 1]
        lo, hi = u_lo[i], u_hi[i]
        for j in range(A.shape[1]):
            a = A[i, j]
            if a > _SEIDEL_TINY:
                hi = min(hi, -(B[i, j] * x + C[i, j]) / a)
            elif a < -_SEIDEL_TINY:
                lo = max(lo, -(B[i, j] * x + C[i, j]) / a)
        hi = min(hi, (k_hi - x) / two_delta[i])
        lo = max(lo, (k_lo - x) / two_delta[i])
        if lo > hi or x < x_lo[i] or x > x_hi[i]:  # slightly infeasible from round-off: back off x a little
            if tries >= MAX_TRIES:
                return us, xs
            x = max(x - TINY, 0.999 * x)
            xs[i] = x
            tries += 1
            continue
        tries = 0
        us[i] = hi
        x_next = x + two_delta[i] * hi
        x_next = max(x_next - TINY, 0.9999 * x_next)
        x = min(k_hi, max(k_lo, x_next))
        xs[i + 1] = x
        i += 1
    return us, xs


class LeanTOPPRA(algo.TOPPRA):
    """toppra's TOPPRA, with the per-stage bookkeeping of its two passes done once up front.

    Same algorithm, same solver wrapper, same results: the backward pass (controllable sets) calls
    the seidel solver exactly as toppra does, but without re-allocating the objective vectors and
    re-checking NaNs through numpy at every stage, which is where most of the time of a coarse-grid
    solve goes. The forward pass fixes x at every stage, so its LP has one variable: it is solved
    in one compiled loop by the rule toppra's seidel wrapper applies to it (``_forward_pass``; the
    same u, bit for bit, on 70,000 stages of arm6 and gantry3 plans). LPs of the backward pass are
    skipped where their answer is known exactly (checked in closed form, with every stage's rows
    stacked once up front):

    - the lower end of a controllable set is 0 wherever standing still is allowed and leads into
      a set that contains 0 (a rest-to-rest move: almost every stage);
    - its upper end is the stage's own bound x_top (speed limits) wherever some u allowed at
      x_top leads into the next set (cruising at a speed limit: most stages);
    """

    def __init__(
        self, constraint_list: list[constraint.Constraint], path: JointPath, gridpoints: NDArray[np.float64]
    ) -> None:
        # toppra's ReachabilityAlgorithm.__init__ would first probe the importable solvers (a
        # file-system search on every plan); the solver here is always seidel, so set it up directly
        ParameterizationAlgorithm.__init__(self, constraint_list, path, gridpoints=gridpoints)
        params = [c.compute_constraint_params(self.path, self.gridpoints) for c in self.constraints]
        rows = self._rows = _StageRows.stack(params, len(self.gridpoints))
        self._rest = rows.rest_feasible()
        self._x_top = rows.x_hi
        self._u_top = rows.u_range_at(rows.x_hi)
        computed = [_Computed(c, p) for c, p in zip(self.constraints, params, strict=True)]
        self.solver_wrapper = seidelWrapper(computed, self.path, self.gridpoints, solve_lp1d=True)
        n_vars = self.solver_wrapper.get_no_vars()
        self._g_max_x = np.zeros(n_vars)
        self._g_max_x[0], self._g_max_x[1] = 1e-9, -1.0
        self._g_min_x = -self._g_max_x

    def compute_controllable_sets(self, sdmin: float, sdmax: float) -> NDArray[np.float64]:
        n = self._N
        K = np.full((n + 1, 2), np.nan)
        K[n] = (sdmin**2, sdmax**2)
        solve = self.solver_wrapper.solve_stagewise_optim
        g_max, g_min, nan = self._g_max_x, self._g_min_x, np.nan
        rest = self._rest.tolist()
        x_top, (u_lo, u_hi) = self._x_top.tolist(), (v.tolist() for v in self._u_top)
        two_delta = (2.0 * self.solver_wrapper.get_deltas()).tolist()
        self.solver_wrapper.setup_solver()
        lo, hi = float(K[n, 0]), float(K[n, 1])
        los, his = [], []
        for i in range(n - 1, -1, -1):
            # a u feasible at x_top[i] that lands in [lo, hi]: x_top[i] is the LP's maximum
            x = x_top[i]
            first = max(u_lo[i], (lo - x) / two_delta[i])
            if first + 1e-9 * (1.0 + abs(first)) <= min(u_hi[i], (hi - x) / two_delta[i]):
                x_hi = x
            else:
                x_hi = solve(i, None, g_max, nan, nan, lo, hi)[1]
                if x_hi != x_hi:
                    x_hi = self._rows.x_extreme(i, two_delta[i], lo, hi, highest=True)
            # standing still is allowed here and 0 is in [lo, hi]: the minimum is 0
            x_lo = 0.0 if lo == 0.0 and rest[i] else solve(i, None, g_min, nan, nan, lo, hi)[1]
            if x_lo != x_lo and x_hi == x_hi:
                x_lo = self._rows.x_extreme(i, two_delta[i], lo, hi, highest=False)
            lo, hi = max(x_lo, 0.0), x_hi
            if lo != lo or hi != hi:  # NaN: no controllable state at this stage (K stays NaN there)
                break
            los.append(lo)
            his.append(hi)
        else:
            self.solver_wrapper.close_solver()
        k = len(los)
        K[n - k : n, 0] = los[::-1]
        K[n - k : n, 1] = his[::-1]
        return K

    def compute_parameterization(self, sd_start: float, sd_end: float, return_data: bool = False):  # type: ignore[override]
        """toppra's forward pass (greedy: the largest controllable x at every stage), same safeguards,
        each stage's one-variable LP solved in a compiled loop (``_forward_pass``)."""
        K = self.compute_controllable_sets(sd_end, sd_end)
        if np.isnan(K).any():
            return (None, None, None, K) if return_data else (None, None, None)
        x_start = sd_start**2
        if x_start + SMALL < K[0, 0] or K[0, 1] + SMALL < x_start:
            return (None, None, None, K) if return_data else (None, None, None)
        r = self._rows
        two_delta = 2.0 * self.solver_wrapper.get_deltas()
        us, xs = _forward_pass(r.A, r.B, r.C, r.u_lo, r.u_hi, r.x_lo, r.x_hi, K, two_delta, x_start)
        sd = np.sqrt(xs)
        return (us, sd, None, K) if return_data else (us, sd, None)


# Starting from and stopping at rest is where a coarse grid loses most of its time (the profile
# s'(s) ~ sqrt(s) there is far from what one constant s'' per interval can follow): the first and
# last uniform intervals are split geometrically. So are the intervals on both sides of a kink (a
# waypoint where the path's second derivative jumps, ``JointPath.kinks``): where the curvature
# jumps up, holding the acceleration takes a burst of s'' that one constant s'' over a whole
# interval turns into a near stop (what that costs: bench/RESULTS.md, issue 13).
END_REFINEMENT = 0.5 ** np.arange(1, 7)


def make_gridpoints(path: JointPath, n: int) -> NDArray[np.float64]:
    """n uniform intervals, every waypoint, and a geometric refinement towards both ends and both
    sides of every kink."""
    length = path.length
    h = length / n
    steps = h * END_REFINEMENT
    ends = np.concatenate((steps, length - steps))
    kinks = (path.kinks[:, None] + np.concatenate((steps, -steps))[None, :]).ravel()
    kinks = kinks[(kinks > 0.0) & (kinks < length)]
    grid = np.union1d(np.union1d(np.linspace(0.0, length, n + 1), path.waypoint_s), np.union1d(ends, kinks))
    # drop slivers left by the union (they only cost time): the later point of the pair, unless it
    # is a waypoint (the path's pieces meet there: a waypoint is always a gridpoint), then the earlier
    sliver = np.diff(grid) <= 1e-3 * h * END_REFINEMENT[-1]
    waypoint = np.isin(grid, path.waypoint_s)
    drop = np.zeros(len(grid), dtype=bool)
    drop[1:] = sliver & ~waypoint[1:]
    drop[:-1] |= sliver & waypoint[1:] & ~waypoint[:-1]
    grid = grid[~drop]
    grid[-1] = length
    return grid


def _solve(
    path: JointPath, grid: NDArray[np.float64], limits: JointLimits, constraints: list[constraint.Constraint]
) -> Trajectory:
    """TOPP-RA on ``grid``, then the between-gridpoint check against ``limits`` (slowed where needed)."""
    instance = LeanTOPPRA(constraints, path, grid)
    _sdd, sd, _v = instance.compute_parameterization(0.0, 0.0)
    if sd is None or np.any(~np.isfinite(sd)):
        raise PlanError(PlanResult.INFEASIBLE, "no trajectory along this path satisfies the limits (TOPP-RA failed)")
    traj = Trajectory.from_path_velocities(path, grid, np.asarray(sd, dtype=float), limits.names)
    rv, ra = traj.limit_ratios(limits)
    k = max(rv, np.sqrt(ra))
    if k > 1.0:
        traj = traj.slowed(k * (1.0 + 1e-9))
    return traj


def parameterize(
    path: JointPath,
    limits: JointLimits,
    constraints: list[constraint.Constraint],
    gridpoints: int = DEFAULT_GRIDPOINTS,
) -> Trajectory:
    """The time-optimal rest-to-rest trajectory along ``path`` under ``constraints``.

    ``limits`` are the joint limits the constraints were built from: the result is checked
    against them between the gridpoints and slowed down uniformly where it exceeds them.

    Joint torque limits rarely bind on a well-sized robot, and their rows cost three RNEAs per
    gridpoint: the first solve leaves them out and the result is checked against them (one RNEA
    per gridpoint). Where it holds them, it is also the optimum with them (a constraint the
    optimum already meets changes nothing); where it does not, the solve is made again with them.
    """
    grid = make_gridpoints(path, gridpoints)
    deferred = [c for c in constraints if isinstance(c, RneaJointTorqueConstraint)]
    if not deferred:
        return _solve(path, grid, limits, constraints)
    traj = _solve(path, grid, limits, [c for c in constraints if not isinstance(c, RneaJointTorqueConstraint)])
    if all(c.holds_on(traj) for c in deferred):
        return traj
    return _solve(path, grid, limits, constraints)


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
    "timing_constraints",
]
