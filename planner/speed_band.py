"""Fewer acceleration switches for fewer records: TOPP-RA's profile flattened within a speed band.

TOPP-RA's profile has s'' constant between gridpoints, and along a phase at a limit s'' changes at
every gridpoint: the joints' acceleration is a staircase with a step every 20-30 ms. The drive's
cubics (linear acceleration) follow a step within a count only with a record on it, and a constant
s'' other than 0 makes q(t) = path(s(t)) a polynomial of degree 6 that a cubic follows only
briefly: on gantry3 that is 27 records per axis per second, and 27 with 1500 gridpoints too
(bench/RESULTS.md, "Issue 25 item 4").

Here s'^2, linear in s on every grid interval, is replaced by a piecewise linear function with
fewer breaks (spans of several grid intervals with one s'' each, the gridpoints kept), that

- stays within ``[(1 - band)^2 x, x]`` of TOPP-RA's x = s'^2 at every gridpoint (the path speed
  at most ``band`` below TOPP-RA's, never above it anywhere: no velocity-type constraint, joint
  or TCP speed, can be crossed, and the motion is at most 1 / (1 - band) times longer);
- keeps the joints' velocity and acceleration within the limits on every span, exactly (on one
  path piece, q'' = q_ss s'^2 + q_s s'' is a quadratic in s: its peak is at an end or at its
  vertex), and from each span's end the next grid interval as TOPP-RA has it stays possible;
- takes s'' = 0 (constant path speed) where the band allows it: on one path piece q(t) is then a
  cubic, which one record follows exactly; otherwise the fastest line in the band.

Greedy, from the start: each span reaches as far as these rules allow, across waypoints too
(where the path is C2, one s'' makes no jump there; the limits are checked piece by piece).
Torque limits are held where TOPP-RA holds them, at the gridpoints: ``planner.timing`` keeps
TOPP-RA's own profile where the flattened one does not. Jerk-limited plans start from TOPP-RA's
own profile (their lower bound), not from this one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from planner.limits import JointLimits
from planner.path import spline_at, spline_piece
from planner.trajectory import Trajectory

# the path speed may drop this fraction below TOPP-RA's (bench/RESULTS.md, "Issue 25 item 4": the
# records and the motion time of 0.01 .. 0.1)
DEFAULT_SPEED_BAND = 0.05


@njit(cache=True)
def span_ratios(
    s0: float,
    s1: float,
    x0: float,
    x1: float,
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    vmax: NDArray[np.float64],
    amax: NDArray[np.float64],
) -> tuple[float, float]:
    """max |q'| / vmax and max |q''| / amax over [s0, s1] (inside one path piece) with s'^2 linear
    from x0 to x1, exactly: q'' is a quadratic in s there (through its values at both ends and the
    middle), |q'| peaks at an end or where q'' = 0 (as ``trajectory._interval_peaks``)."""
    delta = s1 - s0
    u = (x1 - x0) / (2.0 * delta)
    rv, ra = 0.0, 0.0
    f = np.empty(3)
    i = 0
    for j in range(c.shape[2]):
        for m in range(3):
            i, h = spline_piece(x, s0, s0 + 0.5 * m * delta, i)
            _, q_s, q_ss = spline_at(c, i, h, j)
            xm = x0 + u * m * delta
            f[m] = q_ss * xm + q_s * u
            if m != 1:
                rv = max(rv, abs(q_s) * math.sqrt(max(xm, 0.0)) / vmax[j])
                ra = max(ra, abs(f[m]) / amax[j])
        a = 2.0 * (f[0] - 2.0 * f[1] + f[2])
        b = 4.0 * f[1] - 3.0 * f[0] - f[2]
        r = -b / (2.0 * a) if a != 0.0 else -1.0
        if 0.0 < r < 1.0:
            ra = max(ra, abs(f[0] + (b + a * r) * r) / amax[j])
        r0, r1 = math.nan, math.nan
        if a != 0.0:
            disc = b * b - 4.0 * a * f[0]
            if disc >= 0.0:
                sq = math.sqrt(disc)
                r0, r1 = (-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)
        elif b != 0.0:
            r0 = -f[0] / b
        for rr in (r0, r1):
            if 0.0 < rr < 1.0:
                sigma = rr * delta
                i, h = spline_piece(x, s0, s0 + sigma, i)
                _, q_s, _ = spline_at(c, i, h, j)
                rv = max(rv, abs(q_s) * math.sqrt(max(x0 + 2.0 * u * sigma, 0.0)) / vmax[j])
    return rv, ra


@njit(cache=True)
def line_ratios(
    a: int,
    b: int,
    ya: float,
    yb: float,
    grid: NDArray[np.float64],
    joins: NDArray[np.bool_],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    vmax: NDArray[np.float64],
    amax: NDArray[np.float64],
) -> tuple[float, float]:
    """``span_ratios`` of s'^2 linear from ya at gridpoint a to yb at gridpoint b, piece by piece
    (``joins``: the gridpoints where two path pieces meet, the waypoints)."""
    slope = (yb - ya) / (grid[b] - grid[a])
    rv, ra = 0.0, 0.0
    start = a
    for k in range(a + 1, b + 1):
        if joins[k] or k == b:
            y0 = ya + slope * (grid[start] - grid[a])
            y1 = yb if k == b else ya + slope * (grid[k] - grid[a])
            r_v, r_a = span_ratios(grid[start], grid[k], y0, y1, x, c, vmax, amax)
            rv, ra = max(rv, r_v), max(ra, r_a)
            start = k
    return rv, ra


@njit(cache=True)
def _within(rv: float, ra: float, rv_max: float, ra_max: float) -> bool:
    return rv <= rv_max and ra <= ra_max


@njit(cache=True)
def band_profile(
    grid: NDArray[np.float64],
    sd: NDArray[np.float64],
    joins: NDArray[np.bool_],
    x: NDArray[np.float64],
    c: NDArray[np.float64],
    vmax: NDArray[np.float64],
    amax: NDArray[np.float64],
    low: float,
) -> NDArray[np.float64]:
    """s' at every gridpoint of the flattened profile (module docstring): ``low`` is the least
    fraction of TOPP-RA's s'^2 allowed, ``joins`` the gridpoints where two path pieces meet."""
    n = len(grid)
    xs = sd * sd
    y = xs.copy()
    a = 0
    ya = xs[0]
    while a < n - 1:
        lo, hi = -math.inf, math.inf  # the slopes of s'^2 from (grid[a], ya) inside the band so far
        best, best_y = -1, 0.0
        for b in range(a + 1, n):
            ds = grid[b] - grid[a]
            lo = max(lo, (low * xs[b] - ya) / ds)
            hi = min(hi, (xs[b] - ya) / ds)
            if lo > hi or (b == n - 1 and xs[b] < ya + lo * ds):
                break
            found = False
            yb = xs[b]
            for slope in (min(max(0.0, lo), hi), hi, min(max((xs[b] - xs[a]) / ds, lo), hi), 0.5 * (lo + hi), lo):
                yb = xs[b] if b == n - 1 else ya + slope * ds
                rv, ra = line_ratios(a, b, ya, yb, grid, joins, x, c, vmax, amax)
                if not _within(rv, ra, 1.0, 1.0):
                    continue
                if b < n - 1 and yb != xs[b]:  # TOPP-RA's next interval must stay possible from there
                    rv1, ra1 = span_ratios(grid[b], grid[b + 1], yb, xs[b + 1], x, c, vmax, amax)
                    rv0, ra0 = span_ratios(grid[b], grid[b + 1], xs[b], xs[b + 1], x, c, vmax, amax)
                    if not _within(rv1, ra1, max(1.0, rv0), max(1.0, ra0)):
                        continue
                found = True
                break
            if not found:
                break
            best, best_y = b, yb
        if best < 0:  # no span: the next interval as TOPP-RA has it (possible from here, see above)
            best, best_y = a + 1, xs[a + 1]
        slope = (best_y - ya) / (grid[best] - grid[a])
        for k in range(a + 1, best):
            y[k] = ya + slope * (grid[k] - grid[a])
        y[best] = best_y
        a, ya = best, best_y
    return np.sqrt(np.maximum(y, 0.0))


def flattened(traj: Trajectory, limits: JointLimits, band: float) -> Trajectory:
    """``traj`` (TOPP-RA's, within ``limits``) flattened within the speed band: the same grid,
    s'' constant over spans of it (module docstring). ``band`` 0: ``traj`` itself."""
    if band <= 0.0:
        return traj
    grid = traj.gridpoints
    sd = band_profile(
        grid,
        np.maximum(traj.sd, 0.0),
        np.isin(grid, traj.path.waypoint_s),
        *traj.path.pieces,
        np.asarray(limits.velocity, dtype=float),
        np.asarray(limits.acceleration, dtype=float),
        (1.0 - band) ** 2,
    )
    flat = Trajectory.from_path_velocities(traj.path, grid, sd, traj.joint_names)
    return Trajectory(flat.path, grid, flat.sd, flat.sdd, flat.breakpoints, flat.joint_names, traj.time_scale)
