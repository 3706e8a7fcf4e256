"""The trajectory TOPP-RA gives: s'' constant between gridpoints, read back exactly, and its dense
check against the limits."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError, PlanResult, interval, spline_at, spline_piece

# sub-samples per grid interval for the post-check
_CHECK_SUBSAMPLES = 8


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
    s, s_d = along_interval(gridpoints, sd, sdd[i], i, t - breakpoints[i])
    return s, s_d, sdd[i], i


@njit(cache=True)
def along_interval(
    gridpoints: NDArray[np.float64], sd: NDArray[np.float64], u: float, i: int, tau: float
) -> tuple[float, float]:
    """s and s' ``tau`` into grid interval ``i`` at its constant s'' ``u`` (s kept inside the
    interval: rounding must not carry it onto the next spline piece)."""
    s = min(gridpoints[i] + sd[i] * tau + 0.5 * u * tau * tau, gridpoints[i + 1])
    return s, sd[i] + u * tau


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
def _check_times(breakpoints: NDArray[np.float64], subsamples: int) -> NDArray[np.float64]:
    """``PathTiming.check_times``, the same numbers in one pass."""
    eps = 1e-9 * max(breakpoints[-1], 1.0)
    m = subsamples + 2
    t = np.empty((len(breakpoints) - 1) * m)
    for i in range(len(breakpoints) - 1):
        span = breakpoints[i + 1] - breakpoints[i]
        for k in range(m):
            t[i * m + k] = breakpoints[i] + span * (k / (subsamples + 1))
        t[i * m] += eps
        t[i * m + m - 1] -= eps
    return t


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


@njit(cache=True)
def _acceleration_jumps(
    gridpoints: NDArray[np.float64],
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``Trajectory.acceleration_jumps``' |q_s (s''_i - s''_i-1) + (q_ss+ - q_ss-) s'^2| at every inner
    gridpoint, (n - 2, dof), in one pass: q_s and q_ss+ on the piece that starts there, q_ss- on the
    piece of the interval that ends there."""
    n, dof = len(gridpoints), c.shape[2]
    out = np.empty((n - 2, dof))
    after, before = 0, 0
    for i in range(1, n - 1):
        s = gridpoints[i]
        after, h = spline_piece(x, s, s, after)
        before, h_before = spline_piece(x, gridpoints[i - 1], s, before)
        step, speed2 = sdd[i] - sdd[i - 1], sd[i] ** 2
        for j in range(dof):
            _, q_s, q_ss = spline_at(c, after, h, j)
            _, _, q_ss_before = spline_at(c, before, h_before, j)
            out[i - 1, j] = abs(q_s * step + (q_ss - q_ss_before) * speed2)
    return out


@njit(cache=True, error_model="numpy")  # x / 0 is inf or NaN, as numpy's: a stall is reported, not raised
def _profile(
    gridpoints: NDArray[np.float64], sd: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], bool]:
    """s' (negative round-off cut to 0), the constant s'' of every interval and the gridpoints'
    times (each interval's dt = 2 ds / (s'_i + s'_i+1), summed in order), and whether some dt is not
    finite (the profile stops on the path)."""
    n = len(gridpoints)
    v = np.maximum(sd, 0.0)
    sdd, t = np.empty(n - 1), np.empty(n)
    t[0] = 0.0
    stalls = False
    for i in range(n - 1):
        ds = gridpoints[i + 1] - gridpoints[i]
        dt = 2.0 * ds / (v[i] + v[i + 1])
        stalls |= not math.isfinite(dt)
        sdd[i] = (v[i + 1] * v[i + 1] - v[i] * v[i]) / (2.0 * ds)
        t[i + 1] = t[i] + dt
    return v, sdd, t, stalls


class PathTiming:
    """What every timing of a path shares, q(t) = path(s(t)) on a grid: TOPP-RA's (``Trajectory``,
    s'' constant between gridpoints) and the jerk-limited one (``planner.jerk.JerkTrajectory``, the
    third derivative of s constant). ``breakpoints`` are the gridpoints' times; the dense checks look
    inside every interval at ``check_subsamples`` times (more where the profile is of higher degree)."""

    path: JointPath
    gridpoints: NDArray[np.float64]  # s at the grid
    sd: NDArray[np.float64]  # s' at the grid
    breakpoints: NDArray[np.float64]  # t at the grid [s]
    joint_names: tuple[str, ...]
    check_subsamples: ClassVar[int] = _CHECK_SUBSAMPLES

    @property
    def duration(self) -> float:
        return float(self.breakpoints[-1])

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def check_times(self, subsamples: int | None = None) -> NDArray[np.float64]:
        """Gridpoint times plus ``subsamples`` (default ``check_subsamples``) evenly spaced times inside
        every interval, one-sided at its ends: both sides of a switch at a gridpoint are seen."""
        return _check_times(self.breakpoints, self.check_subsamples if subsamples is None else subsamples)


@dataclass(frozen=True)
class Trajectory(PathTiming):
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
        sd, sdd, t, stalls = _profile(np.asarray(gridpoints, dtype=float), np.asarray(sd, dtype=float))
        if stalls:
            raise PlanError(PlanResult.INFEASIBLE, "the time-optimal profile stalls on the path (zero path velocity)")
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
        return self.breakpoints[1:-1], _acceleration_jumps(self.gridpoints, self.sd, self.sdd, *self.path.pieces)

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

    def limit_ratios(self, limits: JointLimits) -> tuple[float, float]:
        """Worst |qd|/vmax and |qdd|/amax at both ends of every grid interval (one-sided) and at their
        peaks inside it (exact: ``_interval_peaks``): no time between them is worse, so the check
        times inside the intervals add nothing."""
        vmax, amax = np.asarray(limits.velocity, dtype=float), np.asarray(limits.acceleration, dtype=float)
        rv, ra = _worst_ratios(self.check_times(0), *self._profile_and_path(), vmax, amax)
        rv_in, ra_in = _interval_peaks(self.gridpoints, self.sd, self.sdd, *self.path.pieces, vmax, amax)
        return max(rv, rv_in), max(ra, ra_in)
