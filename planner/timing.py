"""Time-optimal parameterization of a joint path with TOPP-RA, and the trajectory it gives.

toppra solves for the path velocity s'(s) on a grid under the joint velocity and acceleration
limits (and, where the robot has them, joint torques through Pinocchio's RNEA and a TCP speed
limit through the frame Jacobian). Between gridpoints the path acceleration s'' is constant, so
the trajectory here is exact for that profile ("constant acceleration" parametrizer).

TOPP-RA enforces the constraints at the gridpoints. Between them the joint velocity and
acceleration can exceed the limits by a hair; the trajectory is checked densely afterwards and,
where needed, slowed down uniformly by the smallest factor that brings it inside (reported as
``time_scale``). That keeps the result honest on a coarse, fast grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import toppra.algorithm as algo
import toppra.constraint as constraint
from numpy.typing import ArrayLike, NDArray
from toppra.algorithm.algorithm import ParameterizationAlgorithm
from toppra.constants import MAX_TRIES, SMALL, TINY
from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

from planner.limits import JointLimits
from planner.model import RobotModel
from planner.path import JointPath, PlanError, PlanResult

DEFAULT_GRIDPOINTS = 140
# sub-samples per grid interval for the post-check
_CHECK_SUBSAMPLES = 8


_X_MAX = 1e8  # bound on s'^2 where nothing binds (the solver wants finite numbers)


class _IntervalSpeedConstraint(constraint.LinearConstraint):
    """A speed bound |G(s) q'(s)| s' <= limit held at the start, middle and end of every grid interval.

    toppra's joint velocity constraint bounds s' at the gridpoints only, and between them |qd| can
    overshoot by a few percent on a coarse grid. Here the bound is imposed inside the interval:
    with u = s'' constant on [s_i, s_i+1], s'^2 at s_i + sigma is x_i + 2 u sigma, so each sample
    gives the linear row  G^2 (x_i + 2 u sigma) <= limit^2  on the stage variables (u, x_i).
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
        # the end of interval i is gridpoint i + 1: evaluate the gridpoints once, the inner samples once
        at_grid = self.speed_factors(path, gridpoints) ** 2  # (n, m)
        inner = self.FRACTIONS < 1.0
        s_inner = (gridpoints[:-1, None] + sigma[:-1, inner]).ravel()
        g2 = np.empty((n, f, at_grid.shape[1]))
        g2[:-1, inner] = (self.speed_factors(path, s_inner) ** 2).reshape(n - 1, int(inner.sum()), -1)
        g2[:-1, ~inner] = at_grid[1:, None, :]
        g2[-1] = at_grid[-1]
        a = (2.0 * sigma[:, :, None] * g2).reshape(n, -1)
        b = g2.reshape(n, -1)
        m = a.shape[1]
        with np.errstate(divide="ignore"):
            x_max = np.min(np.where(at_grid > 0, self.limit**2 / np.maximum(at_grid, 1e-300), np.inf), axis=1)
        xbound = np.column_stack((np.zeros(n), np.minimum(x_max, _X_MAX)))
        return a, b, np.zeros_like(a), np.eye(m), np.tile(self.limit**2, f), None, xbound


class JointVelocityConstraint(_IntervalSpeedConstraint):
    """|qd_j| <= vmax_j inside every grid interval, not only at the gridpoints."""

    def __init__(self, vmax: NDArray[np.float64]) -> None:
        super().__init__(vmax)
        self.dof = len(self.limit)
        self._format_string = "    Joint velocity limit (interval-sampled)\n"

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        return path(s, 1)


class JointAccelerationConstraint(constraint.LinearConstraint):
    """|qdd_j| <= amax_j at the start, middle and end of every grid interval.

    toppra's interpolation discretization holds the bound at both ends of an interval; the middle
    row closes most of the remaining gap. With u constant on the interval and
    s'^2 = x + 2 u sigma, qdd = q''(s) s'^2 + q'(s) u = (q' + 2 sigma q'') u + q'' x: linear in (u, x).
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
        s = np.minimum(gridpoints[:, None] + sigma, gridpoints[-1]).ravel()
        qs = path(s, 1).reshape(n, f, -1)
        qss = path(s, 2).reshape(n, f, -1)
        a = (qs + 2.0 * sigma[:, :, None] * qss).reshape(n, -1)
        b = qss.reshape(n, -1)
        m = a.shape[1]
        F = np.vstack((np.eye(m), -np.eye(m)))
        g = np.tile(self.amax, 2 * f)
        return a, b, np.zeros_like(a), F, g, None, None


class TcpSpeedConstraint(_IntervalSpeedConstraint):
    """|v_tcp| <= max_speed at ``frame``, through the Jacobian of its origin (a Jacobian per
    sample is the expensive part, so fewer samples than for the joints)."""

    FRACTIONS = np.array([0.5])

    def __init__(self, model: RobotModel, frame: str, max_speed: float) -> None:
        super().__init__(np.array([float(max_speed)]))
        self.model = model
        self.frame = frame
        self.dof = model.dof
        self._format_string = f"    TCP speed limit: {max_speed} m/s at {frame}\n"

    def speed_factors(self, path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.model.frame_speeds(path(s), path(s, 1), self.frame)[:, None]


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

    def _state(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], bool]:
        t_arr = np.asarray(t, dtype=float)
        scalar = t_arr.ndim == 0
        t_arr = np.clip(np.atleast_1d(t_arr), 0.0, self.duration)
        i = np.clip(np.searchsorted(self.breakpoints, t_arr, side="right") - 1, 0, len(self.sdd) - 1)
        tau = t_arr - self.breakpoints[i]
        s = np.minimum(self.gridpoints[i] + self.sd[i] * tau + 0.5 * self.sdd[i] * tau * tau, self.gridpoints[i + 1])
        sd = self.sd[i] + self.sdd[i] * tau
        return s, sd, self.sdd[i], scalar

    def position(self, t: ArrayLike) -> NDArray[np.float64]:
        s, _, _, scalar = self._state(t)
        q = self.path(s)
        return q[0] if scalar else q

    def velocity(self, t: ArrayLike) -> NDArray[np.float64]:
        s, sd, _, scalar = self._state(t)
        qd = self.path(s, 1) * sd[:, None]
        return qd[0] if scalar else qd

    def acceleration(self, t: ArrayLike) -> NDArray[np.float64]:
        s, sd, sdd, scalar = self._state(t)
        qdd = self.path(s, 2) * (sd * sd)[:, None] + self.path(s, 1) * sdd[:, None]
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
        """Worst |qd|/vmax and |qdd|/amax over the check times."""
        s, sd, sdd, _ = self._state(self.check_times())
        qs = self.path(s, 1)
        qd = qs * sd[:, None]
        qdd = self.path(s, 2) * (sd * sd)[:, None] + qs * sdd[:, None]
        return float(np.max(np.abs(qd) / limits.velocity)), float(np.max(np.abs(qdd) / limits.acceleration))


def timing_constraints(
    limits: JointLimits,
    model: RobotModel | None = None,
    torque_limits: bool = False,
    tcp_frame: str | None = None,
    max_tcp_speed: float | None = None,
) -> list[constraint.Constraint]:
    """The toppra constraints of a cell: joint velocity and acceleration always; joint torque
    (RNEA) where asked for and the model has effort limits and masses; TCP speed where asked for."""
    out: list[constraint.Constraint] = [
        JointVelocityConstraint(limits.velocity),
        JointAccelerationConstraint(limits.acceleration),
    ]
    if torque_limits and model is not None and model.has_dynamics and np.all(np.isfinite(limits.effort)):
        out.append(
            constraint.JointTorqueConstraint(
                model.inverse_dynamics,
                np.column_stack((-limits.effort, limits.effort)),
                np.zeros(limits.dof),
                discretization_scheme=constraint.DiscretizationType.Collocation,
            )
        )
    if max_tcp_speed is not None:
        if model is None or tcp_frame is None:
            raise ValueError("a TCP speed limit needs the robot model and the TCP frame")
        out.append(TcpSpeedConstraint(model, tcp_frame, max_tcp_speed))
    return out


class LeanTOPPRA(algo.TOPPRA):
    """toppra's TOPPRA, with the per-stage bookkeeping of its two passes done once up front.

    Same algorithm, same solver wrapper, same results: the backward pass (controllable sets) and
    the forward pass call the seidel solver exactly as toppra does, but without re-allocating the
    objective vectors and re-checking NaNs through numpy at every stage, which is where most of
    the time of a coarse-grid solve goes.
    """

    def __init__(
        self, constraint_list: list[constraint.Constraint], path: JointPath, gridpoints: NDArray[np.float64]
    ) -> None:
        # toppra's ReachabilityAlgorithm.__init__ would first probe the importable solvers (a
        # file-system search on every plan); the solver here is always seidel, so set it up directly
        ParameterizationAlgorithm.__init__(self, constraint_list, path, gridpoints=gridpoints)
        self.solver_wrapper = seidelWrapper(self.constraints, self.path, self.gridpoints, solve_lp1d=True)
        n_vars = self.solver_wrapper.get_no_vars()
        self._g_max_x = np.zeros(n_vars)
        self._g_max_x[0], self._g_max_x[1] = 1e-9, -1.0
        self._g_min_x = -self._g_max_x
        deltas = self.solver_wrapper.get_deltas()
        self._g_forward = np.zeros((len(deltas), n_vars))
        self._g_forward[:, 0] = -2.0 * deltas
        self._g_forward[:, 1] = -1.0

    def compute_controllable_sets(self, sdmin: float, sdmax: float) -> NDArray[np.float64]:
        n = self._N
        K = np.zeros((n + 1, 2))
        K[n] = (sdmin**2, sdmax**2)
        solve = self.solver_wrapper.solve_stagewise_optim
        self.solver_wrapper.setup_solver()
        lo, hi = K[n, 0], K[n, 1]
        for i in range(n - 1, -1, -1):
            x_hi = solve(i, None, self._g_max_x, np.nan, np.nan, lo, hi)[1]
            x_lo = solve(i, None, self._g_min_x, np.nan, np.nan, lo, hi)[1]
            lo, hi = max(x_lo, 0.0), x_hi
            K[i, 0], K[i, 1] = lo, hi
            if lo != lo or hi != hi:  # NaN: no controllable state at this stage
                K[i] = np.nan
                return K
        self.solver_wrapper.close_solver()
        return K

    def compute_parameterization(self, sd_start: float, sd_end: float, return_data: bool = False):  # type: ignore[override]
        """toppra's forward pass (greedy: the largest controllable x at every stage), same safeguards."""
        K = self.compute_controllable_sets(sd_end, sd_end)
        if np.isnan(K).any():
            return (None, None, None, K) if return_data else (None, None, None)
        x_start = sd_start**2
        if x_start + SMALL < K[0, 0] or K[0, 1] + SMALL < x_start:
            return (None, None, None, K) if return_data else (None, None, None)
        n = self._N
        deltas = self.solver_wrapper.get_deltas()
        xs = np.zeros(n + 1)
        us = np.zeros(n)
        xs[0] = x_start
        solve = self.solver_wrapper.solve_stagewise_optim
        self.solver_wrapper.setup_solver()
        i, tries, x = 0, 0, x_start
        while i < n:
            k_lo, k_hi = K[i + 1, 0], K[i + 1, 1]
            u = solve(i, None, self._g_forward[i], x, x, k_lo, k_hi)[0]
            if u != u:  # slightly infeasible from round-off: back off x a little, as toppra does
                if tries >= MAX_TRIES:
                    xs[i + 1 :] = np.nan
                    break
                x = max(x - TINY, 0.999 * x)
                xs[i] = x
                tries += 1
                continue
            tries = 0
            us[i] = u
            x_next = x + 2.0 * deltas[i] * u
            x_next = max(x_next - TINY, 0.9999 * x_next)
            x = min(k_hi, max(k_lo, x_next))
            xs[i + 1] = x
            i += 1
        self.solver_wrapper.close_solver()
        sd = np.sqrt(xs)
        return (us, sd, None, K) if return_data else (us, sd, None)


# Starting from and stopping at rest is where a coarse grid loses most of its time (the profile
# s'(s) ~ sqrt(s) there is far from what one constant s'' per interval can follow): the first and
# last uniform intervals are split geometrically.
END_REFINEMENT = 0.5 ** np.arange(1, 7)


def make_gridpoints(path: JointPath, n: int) -> NDArray[np.float64]:
    """n uniform intervals, every waypoint, and a geometric refinement towards both ends."""
    length = path.length
    h = length / n
    ends = np.concatenate((h * END_REFINEMENT, length - h * END_REFINEMENT))
    grid = np.union1d(np.union1d(np.linspace(0.0, length, n + 1), path.waypoint_s), ends)
    # drop slivers left by the union (they only cost time), never an end point
    keep = np.concatenate(([True], np.diff(grid) > 1e-3 * h * END_REFINEMENT[-1]))
    grid = grid[keep]
    grid[-1] = length
    return grid


def parameterize(
    path: JointPath,
    limits: JointLimits,
    constraints: list[constraint.Constraint],
    gridpoints: int = DEFAULT_GRIDPOINTS,
) -> Trajectory:
    """The time-optimal rest-to-rest trajectory along ``path`` under ``constraints``.

    ``limits`` are the joint limits the constraints were built from: the result is checked
    against them between the gridpoints and slowed down uniformly where it exceeds them.
    """
    grid = make_gridpoints(path, gridpoints)
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


__all__ = [
    "DEFAULT_GRIDPOINTS",
    "JointAccelerationConstraint",
    "JointVelocityConstraint",
    "LeanTOPPRA",
    "TcpSpeedConstraint",
    "Trajectory",
    "make_gridpoints",
    "parameterize",
    "timing_constraints",
]
