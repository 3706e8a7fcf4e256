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
- keeps the joints' acceleration within the limits at the start, middle and end of every grid
  interval (on one span, q'' = q_ss s'^2 + q_s s'' is linear in the span's slope of s'^2: each
  sample narrows the slopes allowed, as the band does); between the samples ``planner.timing``
  checks the result densely and slows it down uniformly where it exceeds them (1 of 80 pvt_quality
  paths needed it, by 3e-5);
- has the fewest spans, a span whose s'' is not 0 counting ``CURVED_SPAN_COST`` more (with
  s'' = 0 on one path piece q(t) is a cubic, which one record follows exactly; otherwise knot
  placement puts records inside the span), then the least time: a shortest path over the
  gridpoints, each with ``LEVELS`` geometric levels of s'^2 in the band and TOPP-RA's own value.
  A greedy split (each span as long as possible from the start) would end spans at the band's
  lower edge and start the next span there: a straight move would cruise 5 % below TOPP-RA's
  speed, and the plans would need more records.

Torque limits are held where TOPP-RA holds them, at the gridpoints: ``planner.timing`` keeps
TOPP-RA's own profile where the flattened one does not. Jerk-limited plans start from TOPP-RA's
own profile (their lower bound), not from this one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.trajectory import Trajectory

# the path speed may drop this fraction below TOPP-RA's (bench/RESULTS.md, "Issue 25 item 4": the
# records and the motion time of 0.01 .. 0.1)
DEFAULT_SPEED_BAND = 0.05
# levels of s'^2 per band, and the extra cost of a span whose s'' is not 0 (its joints' motion is
# not a cubic: knot placement puts records inside it): bench/RESULTS.md, "Issue 25 items 4 and 5"
LEVELS = 4
CURVED_SPAN_COST = 2.0


def flattened(traj: Trajectory, limits: JointLimits, band: float) -> Trajectory:
    """``traj`` (TOPP-RA's, within ``limits``) flattened within the speed band: the same grid,
    s'' constant over spans of it (module docstring). ``band`` 0: ``traj`` itself."""
    if band <= 0.0:
        return traj
    grid = traj.gridpoints
    sd = np.maximum(traj.sd, 0.0)
    anchor = np.repeat(grid[:-1], 3)  # each interval's samples on its own path piece
    s_at = np.column_stack((grid[:-1], 0.5 * (grid[:-1] + grid[1:]), grid[1:])).ravel()
    _, q_s, q_ss = traj.path.states_on_piece_of(anchor, s_at)
    y = fewest_spans(grid, sd * sd, s_at, q_s, q_ss, np.asarray(limits.acceleration, dtype=float), (1.0 - band) ** 2)
    flat = Trajectory.from_path_velocities(traj.path, grid, np.sqrt(np.maximum(y, 0.0)), traj.joint_names)
    return Trajectory(flat.path, grid, flat.sd, flat.sdd, flat.breakpoints, flat.joint_names, traj.time_scale)


@njit(cache=True)
def fewest_spans(
    grid: NDArray[np.float64],
    xs: NDArray[np.float64],
    s_at: NDArray[np.float64],
    q_s: NDArray[np.float64],
    q_ss: NDArray[np.float64],
    amax: NDArray[np.float64],
    low: float,
    levels: int = LEVELS,
    curved: float = CURVED_SPAN_COST,
) -> NDArray[np.float64]:
    """s'^2 at every gridpoint (module docstring): the shortest path from rest to rest over the
    states (gridpoint, level of s'^2), ``levels`` geometric levels in the band and TOPP-RA's own
    value ``xs``; a span costs 1, and ``curved`` more where its s'' is not 0; equal costs: the
    least time. ``s_at``, ``q_s``, ``q_ss``: the path at 3 samples per grid interval (start,
    middle, end, on the interval's own piece)."""
    n = len(grid)
    width = levels + 2
    logr = -math.log(low) / (levels - 1)
    yv = np.zeros((n, width))
    cnt = np.zeros(n, np.int64)
    for k in range(n):
        if xs[k] <= 0.0 or k == 0 or k == n - 1:
            yv[k, 0] = xs[k]
            cnt[k] = 1
            continue
        g = math.ceil(math.log(low * xs[k]) / logr)
        while cnt[k] < width - 1 and math.exp(g * logr) < xs[k]:
            yv[k, cnt[k]] = math.exp(g * logr)
            cnt[k] += 1
            g += 1
        yv[k, cnt[k]] = xs[k]
        cnt[k] += 1
    root = np.sqrt(yv)
    big = math.inf
    spans = np.full((n, width), big)
    time = np.full((n, width), math.inf)
    prev = np.full((n, width, 2), -1, np.int64)
    spans[0, 0] = 0.0
    time[0, 0] = 0.0
    lo = np.empty(width)
    hi = np.empty(width)
    alive = np.zeros(width, np.bool_)
    dof = len(amax)
    rows = 3 * dof
    slope, inv, top = np.empty(rows), np.empty(rows), np.empty(rows)
    for a in range(n - 1):
        left = 0
        na = cnt[a]
        for ma in range(na):
            alive[ma] = spans[a, ma] < big
            lo[ma], hi[ma] = -math.inf, math.inf
            left += alive[ma]
        for b in range(a + 1, n):
            if left == 0:
                break
            ds = grid[b] - grid[a]
            # the acceleration at interval b - 1's samples: q'' = q_ss ya + m (q_ss (s - s_a) + q_s / 2)
            # per sample and joint: the bound on m is (top - q_ss ya) / b0 above, (-top - q_ss ya) / b0 below
            for t in range(3):
                idx = 3 * (b - 1) + t
                for j in range(dof):
                    k = t * dof + j
                    b0 = q_ss[idx, j] * (s_at[idx] - grid[a]) + 0.5 * q_s[idx, j]
                    slope[k] = q_ss[idx, j]
                    inv[k] = 1.0 / b0 if b0 != 0.0 else 0.0
                    top[k] = amax[j] if b0 > 0.0 else -amax[j]
            for ma in range(na):
                if not alive[ma]:
                    continue
                ya, h, g = yv[a, ma], hi[ma], lo[ma]
                for k in range(rows):
                    a0 = slope[k] * ya
                    if inv[k] != 0.0:
                        h = min(h, (top[k] - a0) * inv[k])
                        g = max(g, (-top[k] - a0) * inv[k])
                    elif abs(a0) > amax[k % dof]:
                        g, h = 1.0, -1.0
                hi[ma], lo[ma] = h, g
            for ma in range(na):
                if not alive[ma]:
                    continue
                if lo[ma] > hi[ma]:
                    alive[ma] = False
                    left -= 1
                    continue
                ya = yv[a, ma]
                for mb in range(cnt[b]):
                    yb = yv[b, mb]
                    m = (yb - ya) / ds
                    if m < lo[ma] or m > hi[ma] or ya + yb <= 0.0:
                        continue
                    sp = spans[a, ma] + 1.0 + (0.0 if yb == ya else curved)
                    if sp > spans[b, mb]:
                        continue
                    tm = time[a, ma] + 2.0 * ds / (root[a, ma] + root[b, mb])
                    if sp < spans[b, mb] or tm < time[b, mb]:
                        spans[b, mb] = sp
                        time[b, mb] = tm
                        prev[b, mb, 0] = a
                        prev[b, mb, 1] = ma
                lo[ma] = max(lo[ma], (low * xs[b] - ya) / ds)
                hi[ma] = min(hi[ma], (xs[b] - ya) / ds)
                if lo[ma] > hi[ma]:
                    alive[ma] = False
                    left -= 1
    y = xs.copy()
    if spans[n - 1, 0] == big:
        return y
    b, mb = n - 1, 0
    while b > 0:
        a, ma = prev[b, mb, 0], prev[b, mb, 1]
        ya, yb = yv[a, ma], yv[b, mb]
        for k in range(a, b + 1):
            y[k] = ya + (yb - ya) * (grid[k] - grid[a]) / (grid[b] - grid[a])
        y[b] = yb
        b, mb = a, ma
    return y
