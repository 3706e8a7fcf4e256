"""The jerk-limited timing's result: q(t) = path(s(t)) with s''' constant between gridpoints, its
derivatives read back exactly (the interval's Taylor polynomial of the path) and its dense check
against the joint and TCP limits (what ``planner.jerk`` slows it down by).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
import toppra.constraint as constraint
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath
from pvtflow.planner.timing import (
    TcpAngularSpeedConstraint,
    TcpSpeedConstraint,
)
from pvtflow.planner.trajectory import PathTiming

_CHECK_SUBSAMPLES = 32
# a solver's optimum slowed by at most this for torque is still called optimal: about the slow-down
# that the dense check of velocity and acceleration gives every answer (4e-4 measured)
TORQUE_OPTIMAL_SLACK = 1e-3
_BISECTIONS = 40  # a peak's time to 1e-12 of the samples' spacing


def interval_coefficients(path: JointPath, grid: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
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
    torque_scale: float = 1.0  # the slow-down that torque between the solver's rows asked for (within time_scale)
    coefficients: tuple[NDArray[np.float64], ...] = field(default=(), repr=False, compare=False)
    check_subsamples: ClassVar[int] = _CHECK_SUBSAMPLES

    def __post_init__(self) -> None:
        if not self.coefficients:
            object.__setattr__(self, "coefficients", interval_coefficients(self.path, self.gridpoints))

    @property
    def waypoint_times(self) -> NDArray[np.float64]:
        """When the trajectory passes each waypoint [s] (waypoints are gridpoints)."""
        idx = np.clip(np.searchsorted(self.gridpoints, self.path.waypoint_s - 1e-12), 0, len(self.gridpoints) - 1)
        return self.breakpoints[idx]

    def slowed(self, k: float) -> JerkTrajectory:
        """The same motion k times slower (s' / k, s'' / k^2, s''' / k^3)."""
        return replace(
            self,
            sd=self.sd / k,
            sdd=self.sdd / (k * k),
            sddd=self.sddd / (k * k * k),
            breakpoints=self.breakpoints * k,
            time_scale=self.time_scale * k,
        )

    @property
    def torque_slowed(self) -> bool:
        """Whether a solver's answer was slowed by more than ``TORQUE_OPTIMAL_SLACK`` after the solve
        to hold the torque limits between its rows: then it is that solver's optimum no more."""
        return self.torque_scale > 1.0 + TORQUE_OPTIMAL_SLACK

    def subdivided(self, pieces: ArrayLike) -> JerkTrajectory:
        """The same motion with interval i split into ``pieces[i]`` equal times: more gridpoints, the
        same s(t) (each piece's Taylor coefficients shifted from its interval's), for a check that
        looks at the ends and the middle of every interval to see inside the long ones."""
        pieces = np.maximum(np.asarray(pieces, dtype=np.int64), 1)
        idx = np.repeat(np.arange(len(self.sddd)), pieces)
        first = np.repeat(np.cumsum(pieces) - pieces, pieces)
        tau = (np.arange(len(idx)) - first) / pieces[idx] * np.diff(self.breakpoints)[idx]
        sd, a, j = self.sd[idx], self.sdd[idx], self.sddd[idx]
        sigma = tau * (sd + tau * (0.5 * a + tau * j / 6.0))
        q0, q1, q2, q3 = (c[idx] for c in self.coefficients)
        sg = sigma[:, None]
        coefficients = (
            q0 + sg * (q1 + sg * (0.5 * q2 + sg * q3 / 6.0)),
            q1 + sg * (q2 + 0.5 * sg * q3),
            q2 + sg * q3,
            q3,
        )
        return replace(
            self,
            gridpoints=np.append(self.gridpoints[idx] + sigma, self.gridpoints[-1]),
            sd=np.append(sd + tau * (a + 0.5 * j * tau), self.sd[-1]),
            sdd=np.append(a + j * tau, self.sdd[-1]),
            sddd=j,
            breakpoints=np.append(self.breakpoints[idx] + tau, self.breakpoints[-1]),
            coefficients=coefficients,
        )

    def _path_state(self, t: ArrayLike) -> tuple[NDArray[np.float64], ...]:
        """Interval index, sigma = s - s_k, s', s'', s''' at the times t (clipped to the motion)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)).ravel(), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.breakpoints, t, side="right") - 1, 0, len(self.sddd) - 1)
        tau = t - self.breakpoints[k]
        sd, a, j = self.sd[k], self.sdd[k], self.sddd[k]
        sigma = tau * (sd + tau * (0.5 * a + tau * j / 6.0))
        return k, sigma, sd + tau * (a + 0.5 * j * tau), a + j * tau, j

    def _joint(self, t: ArrayLike, order: int, joint: NDArray[np.intp] | None = None) -> NDArray[np.float64]:
        """(len(t), dof): the order-th time derivative of q at t (0..3), from the interval's exact
        Taylor polynomial of the path; with ``joint`` (one per time), (len(t),): that joint's only (the
        same numbers: the peaks' bisection asks for one joint per peak, a sixth of the work)."""
        return self._joints(t, (order,), joint)[0]

    def _joints(
        self, t: ArrayLike, orders: tuple[int, ...], joint: NDArray[np.intp] | None = None
    ) -> list[NDArray[np.float64]]:
        """``_joint`` of each of ``orders`` at the same times, the path's state there found once."""
        k, sg, sd, sdd, sddd = self._path_state(t)
        if joint is None:
            q0, q1, q2, q3 = (c[k] for c in self.coefficients)
            sg, sd, sdd, sddd = sg[:, None], sd[:, None], sdd[:, None], sddd[:, None]
        else:
            q0, q1, q2, q3 = (c[k, joint] for c in self.coefficients)
        q_s = q1 + sg * (q2 + 0.5 * sg * q3)
        q_ss = q2 + sg * q3
        derivatives = {
            0: lambda: q0 + sg * (q1 + sg * (0.5 * q2 + sg * q3 / 6.0)),
            1: lambda: q_s * sd,
            2: lambda: q_ss * (sd * sd) + q_s * sdd,
            3: lambda: q3 * (sd**3) + 3.0 * q_ss * (sd * sdd) + q_s * sddd,
        }
        return [derivatives[order]() for order in orders]

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
        velocity, acceleration, jerk = self._joints(t, (1, 2, 3))
        rv = float(np.max(np.abs(velocity) / limits.velocity))
        ra = float(np.max(np.abs(acceleration) / limits.acceleration))
        return (
            max(rv, self._peak_ratio(t2d, 1, limits.velocity, acceleration)),
            max(ra, self._peak_ratio(t2d, 2, limits.acceleration, jerk)),
            float(np.max(np.abs(jerk) / jmax)),
        )

    def _peak_ratio(
        self, t2d: NDArray[np.float64], order: int, bound: NDArray[np.float64], following: NDArray[np.float64]
    ) -> float:
        """Worst |order-th derivative| / bound at its extrema between consecutive check times of an
        interval (rows of ``t2d``; ``following``: the next derivative at them): where the next derivative
        changes sign, found by bisection. The samples alone can miss a peak between them by 1e-4 of the limit."""
        d = following.reshape(*t2d.shape, -1)
        i, p, j = np.nonzero(d[:, :-1] * d[:, 1:] < 0.0)
        if len(i) == 0:
            return 0.0
        lo, hi, f_lo = t2d[i, p], t2d[i, p + 1], d[i, p, j]
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            f_mid = self._joint(mid, order + 1, j)
            left = np.sign(f_mid) == np.sign(f_lo)
            lo, f_lo, hi = np.where(left, mid, lo), np.where(left, f_mid, f_lo), np.where(left, hi, mid)
        return float(np.max(np.abs(self._joint(0.5 * (lo + hi), order, j)) / bound[j]))

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
