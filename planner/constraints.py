"""pvtflow's TOPP-RA constraints: toppra's ``LinearConstraint`` rows, held inside every grid
interval (joint velocity and acceleration, TCP speeds) and batched through Pinocchio (torque)."""

from __future__ import annotations

import math

import numpy as np
import toppra.constraint as constraint
from numba import njit
from numpy.typing import NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.model import RobotModel
from pvtflow.planner.path import JointPath, spline_at, spline_piece
from pvtflow.planner.trajectory import Trajectory, along_interval

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
        self._rows: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # F and g: the same every grid

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        a, b = _acceleration_rows(gridpoints, self.FRACTIONS, *path.pieces)
        if self._rows is None or self._rows[0].shape[1] != a.shape[1]:
            m = a.shape[1]
            self._rows = (np.vstack((np.eye(m), -np.eye(m))), np.tile(self.amax, 2 * len(self.FRACTIONS)))
        F, g = self._rows
        return a, b, np.zeros_like(a), F, g, None, None


@njit(cache=True)
def _acceleration_rows(
    gridpoints: NDArray[np.float64], fractions: NDArray[np.float64], x: NDArray[np.float64], c: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``IntervalJointAccelerationConstraint``'s a = q' + 2 sigma q'' and b = q'' at s_i + sigma,
    sigma = fraction * (s_i+1 - s_i) (0 at the last gridpoint), (n, fractions * dof) each, every
    sample on its interval's own piece: q_ss may jump at a waypoint (a gridpoint), and the interval
    that ends there is held with the q_ss of the piece that ends there."""
    n, f, dof = len(gridpoints), len(fractions), c.shape[2]
    a, b = np.empty((n, f * dof)), np.empty((n, f * dof))
    p = 0
    for i in range(n):
        delta = gridpoints[i + 1] - gridpoints[i] if i < n - 1 else 0.0
        for k in range(f):
            sigma = delta * fractions[k]
            p, h = spline_piece(x, gridpoints[i], gridpoints[i] + sigma, p)
            for j in range(dof):
                _, q_s, q_ss = spline_at(c, p, h, j)
                a[i, k * dof + j] = q_s + 2.0 * sigma * q_ss
                b[i, k * dof + j] = q_ss
    return a, b


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
        q, q_s, _ = path.states_on_piece_of(s, s)
        return self.model.frame_speeds(q, q_s, self.frame)[:, None]


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
        q, q_s, _ = path.states_on_piece_of(s, s)
        return self.model.frame_angular_speeds(q, q_s, self.frame)[:, None]


def torque_slowdown(tau: NDArray[np.float64], gravity: NDArray[np.float64], effort: NDArray[np.float64]) -> float:
    """The uniform slow-down k >= 1 that brings the torques ``tau`` (rows of samples) within ``effort``:
    slowed by k, the torque is gravity + (tau - gravity) / k^2 (gravity does not scale with time);
    inf where gravity alone is over a limit."""
    dynamic = tau - gravity
    if np.any(np.abs(gravity) > effort):
        return math.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(
            dynamic > 0, (effort - gravity) / dynamic, np.where(dynamic < 0, (effort + gravity) / -dynamic, np.inf)
        )
    x = min(1.0, float(room.min()))
    return math.inf if x <= 0.0 else 1.0 / math.sqrt(x)


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
        self.mass_matrix_bound = model.mass_matrix_bound()

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

    def check(self, traj: Trajectory) -> TorqueCheck:
        """TOPP-RA's ``traj`` (s'' constant on every grid interval) checked against this constraint
        at both ends of every interval, cheaply (``TorqueCheck``): ``holds_on`` and ``slowdown``'s
        answers for it, which ``planner.timing.parameterize`` takes."""
        return TorqueCheck(self, traj)

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
        return torque_slowdown(tau, self.model.inverse_dynamics_rows(q, zero, zero), effort)


# where an interval's end is within this fraction of the effort limit, its middle is checked too:
# measured, the inside of an interval exceeds the larger of its ends by at most 1.6 % of the limit
# (arm6, 180 paths at 0.3 to 1 x its efforts, 20 samples per interval; tests/planner/test_timing.py)
TORQUE_MIDDLE_MARGIN = 0.1

# the samples of ``_interval_states``: an interval's start (its s''), middle (in time) and end
_START, _MIDDLE, _END = 0, 1, 2


@njit(cache=True)
def _interval_states(
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    intervals: NDArray[np.int64],
    where: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """q, q', q'' (each (len(intervals), dof)) at the start, middle (in time) or end (``where``) of
    grid interval ``intervals[k]``, exactly: s'' constant on it, every sample on the interval's
    own piece (the end's q_ss is of the piece that ends at a waypoint), and that piece."""
    dof = c.shape[2]
    n = len(intervals)
    q, qd, qdd = np.empty((n, dof)), np.empty((n, dof)), np.empty((n, dof))
    pieces = np.empty(n, dtype=np.int64)
    p = 0
    for k in range(n):
        g = intervals[k]
        u = sdd[g]
        if where[k] == _START:
            s, s_d = gridpoints[g], sd[g]
        elif where[k] == _END:
            s, s_d = gridpoints[g + 1], sd[g + 1]
        else:
            tau = (gridpoints[g + 1] - gridpoints[g]) / (sd[g] + sd[g + 1])  # half the interval's time
            s, s_d = along_interval(gridpoints, sd, u, g, tau)
        p, h = spline_piece(x, gridpoints[g], s, p)
        pieces[k] = p
        for j in range(dof):
            q[k, j], q_s, q_ss = spline_at(c, p, h, j)
            qd[k, j] = q_s * s_d
            qdd[k, j] = q_ss * (s_d * s_d) + q_s * u
    return q, qd, qdd, pieces


@njit(cache=True)
def _gridpoint_states(
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """q, q', q'' at every gridpoint with the s'' of the interval after it (the last one: before)."""
    m = len(sdd)
    intervals = np.empty(m + 1, dtype=np.int64)
    where = np.full(m + 1, _START, dtype=np.int64)
    intervals[:m] = np.arange(m)
    intervals[m], where[m] = m - 1, _END
    q, qd, qdd, _ = _interval_states(gridpoints, sd, sdd, x, c, intervals, where)
    return q, qd, qdd


@njit(cache=True)
def _unbounded_ends(
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    qdd_grid: NDArray[np.float64],
    tau_grid: NDArray[np.float64],
    effort: NDArray[np.float64],
    mass_bound: float,
    clear: float,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The ends of the intervals but the last (gridpoints 1 .. m - 1 with the s'' of the interval
    before) that ``TorqueCheck`` cannot bound: on the next start's piece (off the waypoints), its
    torque is within max_j |tau_j| / effort_j there plus mass_bound |q''_end - q''_start| / min
    effort; at most ``clear`` is bounded enough. Returns those intervals, their q, q', q'', and every
    end's bound (NaN where not bounded)."""
    m, dof = len(sdd), c.shape[2]
    intervals = np.arange(m - 1)
    where = np.full(m - 1, _END, dtype=np.int64)
    q, qd, qdd, piece = _interval_states(gridpoints, sd, sdd, x, c, intervals, where)
    least = effort.min()
    ratio = np.full(m - 1, np.nan)
    keep = np.zeros(m - 1, dtype=np.bool_)
    p = 0
    for i in range(m - 1):
        p, _ = spline_piece(x, gridpoints[i + 1], gridpoints[i + 1], p)
        worst, step = 0.0, 0.0
        for j in range(dof):
            worst = max(worst, abs(tau_grid[i + 1, j]) / effort[j])
            d = qdd[i, j] - qdd_grid[i + 1, j]
            step += d * d
        bound = worst + mass_bound * math.sqrt(step) / least
        if piece[i] == p and bound <= clear:
            ratio[i] = bound
        else:
            keep[i] = True
    ends = np.flatnonzero(keep)
    return ends, q[ends], qd[ends], qdd[ends], ratio


@njit(cache=True)
def _torque_summary(
    tau_grid: NDArray[np.float64],
    ends: NDArray[np.int64],
    tau_ends: NDArray[np.float64],
    end_ratio: NDArray[np.float64],
    effort: NDArray[np.float64],
    clear: float,
) -> tuple[bool, bool, NDArray[np.int64]]:
    """Within the limits at every gridpoint; at every gridpoint and interval end; the intervals with
    an end above ``clear`` of a limit (bounded ends are at most ``clear``)."""
    m, dof = len(tau_grid) - 1, len(effort)
    start = np.zeros(m + 1)
    for i in range(m + 1):
        for j in range(dof):
            start[i] = max(start[i], abs(tau_grid[i, j]) / effort[j])
    end = np.zeros(m)
    end[: m - 1] = end_ratio
    end[m - 1] = start[m]
    for k in range(len(ends)):
        r = 0.0
        for j in range(dof):
            r = max(r, abs(tau_ends[k, j]) / effort[j])
        end[ends[k]] = r
    holds = bool(np.all(start <= 1.0))
    within = holds and bool(np.all(end <= 1.0))
    near = np.flatnonzero((start[:m] > clear) | (end > clear))
    return holds, within, near


class TorqueCheck:
    """The joint torques of one trajectory at both ends of every grid interval, what
    ``parameterize`` asks of them, and the slow-down that holds the limits between gridpoints.

    ``holds``: within the limits at every gridpoint with the s'' of the interval after it (where the
    collocation holds them; the last gridpoint with the last interval's). ``slowdown``: the
    collocation does not hold them at the end of the interval before a gridpoint (a binding arm6
    path: 2.6 % over) nor inside an interval. An interval's middle is checked where one of its ends
    is within ``TORQUE_MIDDLE_MARGIN`` of a limit (the inside of an interval adds far less over its
    ends), and everywhere as soon as any sample is over a limit.

    The gridpoints take one batched RNEA. The end of an interval is a gridpoint too, where the next
    interval starts: off the waypoints it has the same q and q' (the same path piece), so its torque
    differs from the next start's by M(q) (q''_end - q''_start) only, at most
    ``RobotModel.mass_matrix_bound`` x |q''_end - q''_start| per joint. Where that leaves it outside
    the margin, it needs no RNEA of its own (within a flattened span, where s'' barely changes, and
    wherever the limits are far): the decisions are the same as with every end's torque computed.
    """

    def __init__(self, constraint: RneaJointTorqueConstraint, traj: Trajectory) -> None:
        self.constraint = constraint
        self.traj = traj
        t, effort = traj, constraint.effort
        pieces = (t.gridpoints, t.sd, t.sdd, *t.path.pieces)
        q, qd, qdd = _gridpoint_states(*pieces)
        self._tau_grid = constraint.model.inverse_dynamics_rows(q, qd, qdd)
        self._ends, q, qd, qdd, self._end_ratio = _unbounded_ends(
            *pieces, qdd, self._tau_grid, effort, constraint.mass_matrix_bound, 1.0 - TORQUE_MIDDLE_MARGIN
        )
        self._tau_ends = constraint.model.inverse_dynamics_rows(q, qd, qdd)
        self.holds, self._within, self._near = _torque_summary(
            self._tau_grid, self._ends, self._tau_ends, self._end_ratio, effort, 1.0 - TORQUE_MIDDLE_MARGIN
        )

    @property
    def bounded(self) -> NDArray[np.bool_]:
        """Which samples (every interval's start, then every interval's end) were bounded, not computed."""
        m = len(self.traj.sdd)
        out = np.zeros(2 * m, dtype=bool)
        out[m : 2 * m - 1] = True
        out[m + self._ends] = False
        return out

    @property
    def tau(self) -> NDArray[np.float64]:
        """The torques computed, at every interval's start, then every interval's end (NaN: bounded)."""
        m = len(self.traj.sdd)
        out = np.full((2 * m, self.constraint.dof), np.nan)
        out[:m], out[2 * m - 1] = self._tau_grid[:m], self._tau_grid[m]
        out[m + self._ends] = self._tau_ends
        return out

    def _states(
        self, intervals: NDArray[np.int64], where: NDArray[np.int64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        t = self.traj
        return _interval_states(t.gridpoints, t.sd, t.sdd, *t.path.pieces, intervals, where)

    def _middles(self, intervals: NDArray[np.int64]) -> tuple[NDArray[np.float64], ...]:
        """q, q', q'' and tau at the middle of ``intervals``."""
        q, qd, qdd, _ = self._states(intervals, np.full(len(intervals), _MIDDLE))
        return q, qd, qdd, self.constraint.model.inverse_dynamics_rows(q, qd, qdd)

    def slowdown(self) -> float:
        """The uniform slow-down k >= 1 that holds |tau| <= effort at both ends and the middle of
        every interval. Slowed by k, tau = g(q) + (tau - g(q)) / k^2 (M(q) q'' and C(q, q') q' are
        quadratic in the time derivatives, gravity is not): k from the worst sample. inf where
        gravity alone is over a limit."""
        effort = self.constraint.effort
        if self._within:
            if not len(self._near):
                return 1.0
            _, _, _, tau = self._middles(self._near)
            if np.all(np.abs(tau) <= effort):
                return 1.0  # within every limit as it is: gravity is needed only to size a slow-down
        # over a limit somewhere: every end and middle, and gravity at every sample, size the slow-down
        m = len(self.traj.sdd)
        intervals = np.tile(np.arange(m), 3)
        where = np.repeat(np.array([_START, _END, _MIDDLE]), m)
        q, qd, qdd, _ = self._states(intervals, where)
        tau = self.constraint.model.inverse_dynamics_rows(q, qd, qdd)
        zero = np.zeros_like(q)
        return torque_slowdown(tau, self.constraint.model.inverse_dynamics_rows(q, zero, zero), effort)


def middles_warm_up(x: NDArray[np.float64], c: NDArray[np.float64]) -> None:
    """Load ``TorqueCheck``'s middles' compiled loop with the types it takes (path pieces ``x``,
    ``c``): only a trajectory near a torque limit calls it (``planner.timing.warm_up``)."""
    middle = np.full(1, _MIDDLE, dtype=np.int64)
    _interval_states(x[:2], np.ones(2), np.zeros(1), x, c, np.zeros(1, dtype=np.int64), middle)


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
