"""pvtflow's TOPP-RA constraints: toppra's ``LinearConstraint`` rows, held inside every grid
interval (joint velocity and acceleration, TCP speeds) and batched through Pinocchio (torque)."""

from __future__ import annotations

import math

import numpy as np
import toppra.constraint as constraint
from numba import njit
from numpy.typing import NDArray

from planner.limits import JointLimits
from planner.model import RobotModel
from planner.path import JointPath
from planner.trajectory import Trajectory

_X_MAX = 1e8  # bound on s'^2 where nothing binds (the solver wants finite numbers)


@njit(cache=True)
def _interval_samples(gridpoints: NDArray[np.float64], fractions: NDArray[np.float64]) -> NDArray[np.float64]:
    """The gridpoints, then s_i + fraction * (s_i+1 - s_i) for every interval i and every fraction
    below 1 (interval by interval): where ``_IntervalSpeedConstraint`` holds its bound."""
    n = len(gridpoints)
    inner = fractions[fractions < 1.0]
    s = np.empty(n + (n - 1) * len(inner))
    s[:n] = gridpoints
    k = n
    for i in range(n - 1):
        delta = gridpoints[i + 1] - gridpoints[i]
        for x in inner:
            s[k] = gridpoints[i] + delta * x
            k += 1
    return s


@njit(cache=True, error_model="numpy")  # x / 0 is inf, as numpy's: a sample where nothing moves allows any speed
def _interval_rows(
    factors: NDArray[np.float64],
    limit: NDArray[np.float64],
    gridpoints: NDArray[np.float64],
    fractions: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The rows of ``_IntervalSpeedConstraint`` from the speed factors at ``_interval_samples``:
    per stage and fraction 2 sigma (the u coefficient) and -x_max there (the largest s'^2 the
    sample allows, min over the bounded quantities of limit^2 / factor^2, capped at ``_X_MAX``;
    an interval's end is the next gridpoint's), and the box [0, x_max] on x at the gridpoints."""
    n, f = len(gridpoints), len(fractions)
    x_max = np.empty(len(factors))
    for k in range(len(factors)):
        m = np.inf
        for j in range(len(limit)):
            m = min(m, (limit[j] * limit[j]) / (factors[k, j] * factors[k, j]))
        x_max[k] = min(m, _X_MAX)
    two_sigma, bound, xbound = np.empty((n, f)), np.empty((n, f)), np.zeros((n, 2))
    k = n
    for i in range(n):
        delta = gridpoints[i + 1] - gridpoints[i] if i < n - 1 else 0.0
        for j in range(f):
            two_sigma[i, j] = 2.0 * (delta * fractions[j])
            if i == n - 1:
                bound[i, j] = -x_max[n - 1]
            elif fractions[j] < 1.0:
                bound[i, j] = -x_max[k]
                k += 1
            else:
                bound[i, j] = -x_max[i + 1]
        xbound[i, 1] = x_max[i]
    return two_sigma, bound, xbound


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
        # the end of interval i is gridpoint i + 1: the gridpoints and the inner samples in one evaluation
        factors = self.speed_factors(path, _interval_samples(gridpoints, self.FRACTIONS))
        two_sigma, bound, xbound = _interval_rows(factors, self.limit, gridpoints, self.FRACTIONS)
        # rows 2 sigma u + x - bound <= 0
        f = len(self.FRACTIONS)
        return two_sigma, np.ones((len(gridpoints), f)), bound, np.eye(f), np.zeros(f), None, xbound


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
    batched Pinocchio call (3 N Python calls cost more than the rest of the timing).
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

    def slowdown(self, traj: Trajectory) -> float:
        """The uniform slow-down k >= 1 that holds |tau| <= effort between the gridpoints too: the
        collocation holds it at each gridpoint with the s'' of the interval after it, not at the end
        of the interval before nor inside one (measured: 2.6 % over on a binding arm6 path). Slowed
        by k, tau = g(q) + (tau - g(q)) / k^2 (M(q) q'' and C(q, q') q' are quadratic in the time
        derivatives, gravity is not): k from the worst of the check times, one-sided at both ends
        of every interval and at its middle. inf where gravity alone is over a limit."""
        t = traj.check_times(1)
        q, qd, qdd = traj.position(t), traj.velocity(t), traj.acceleration(t)
        tau = self.model.inverse_dynamics_rows(q, qd, qdd)
        effort = self.effort
        if np.all(np.abs(tau) <= effort):
            return 1.0  # within every limit as it is: gravity is needed only to size a slow-down
        zero = np.zeros_like(qd)
        gravity = self.model.inverse_dynamics_rows(q, zero, zero)
        dynamic = tau - gravity
        if np.any(np.abs(gravity) > effort):
            return math.inf
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(
                dynamic > 0, (effort - gravity) / dynamic, np.where(dynamic < 0, (effort + gravity) / -dynamic, np.inf)
            )
        x = min(1.0, float(room.min()))
        return math.inf if x <= 0.0 else 1.0 / math.sqrt(x)


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
