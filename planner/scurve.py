"""A jerk-limited timing that needs no solver: rest to rest, one S-curve in the path parameter.

The jerk-limited timing (planner/jerk) is anytime: where its nonlinear program has not found
a solution by the plan's deadline, the motion still has to be one that holds every limit. This
is that floor. Between two rests (the ends and every C1 waypoint, where the jerk-limited motion
stops anyway) s(t) follows the classic seven-phase profile (jerk +J, 0, -J, cruise, -J, 0, +J)
with one speed V, acceleration A and jerk J of the path parameter chosen from the largest
|q_s|, |q_ss|, |q_sss| of each joint on that section, so that

    |q'| <= |q_s| V,   |q''| <= |q_ss| V^2 + |q_s| A,   |q'''| <= |q_sss| V^3 + 3 |q_ss| V A + |q_s| J

share each joint's limit out (acceleration: half to each term; jerk: a third). The maxima are
taken on samples, so the result is only nearly inside: the caller's dense check and uniform
slow-down (``JerkTrajectory.slowed``) make it exact, as for the solver's answers.

Each waypoint segment of a section gets its own V, A, J (its own maxima): a cruise at a speed
c_k <= V_k, and between two segments a jerk-limited change of speed inside the faster one (with its
A and J: the speeds of the change are within its V), at rest with s'' = 0 at the section's ends. A
segment too short for its changes gets a lower c_k (bisection), until every segment holds its changes
(the speeds only fall, so this ends; ``_MAX_PASSES``, else one speed for the section as a whole).

Far from time-optimal (the shares of A and J, cruises between the changes), but found in about a
millisecond and always: no solver, no convergence.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath

_SAMPLES = 64  # per waypoint segment, for the path's derivative maxima
_SHARE_A = 0.5  # of a joint's acceleration limit: the centripetal term q_ss V^2, the rest q_s A
_SHARE_J = 1.0 / 3.0  # of its jerk limit, to each of the three terms


def _phases(length: float, v: float, a: float, j: float) -> list[tuple[float, float]]:
    """(duration, jerk) of the rest-to-rest profile over ``length`` with |s'| <= v, |s''| <= a,
    |s'''| <= j (zero-length phases dropped)."""

    def ramp(speed: float) -> tuple[float, float, float]:
        """Jerk time, constant-acceleration time, and the distance of a rest-to-``speed`` ramp."""
        if speed * j >= a * a:
            tj, ta = a / j, speed / a - a / j
        else:
            tj, ta = np.sqrt(speed / j), 0.0
        return tj, ta, speed * (2.0 * tj + ta) / 2.0

    tj, ta, d = ramp(v)
    if 2.0 * d > length:  # no cruise at v: the highest speed whose two ramps fit, by bisection
        lo, hi = 0.0, v
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if 2.0 * ramp(mid)[2] <= length else (lo, mid)
        v = lo
        tj, ta, d = ramp(v)
    tc = max(0.0, (length - 2.0 * d) / v) if v > 0.0 else 0.0
    out = [(tj, j), (ta, 0.0), (tj, -j), (tc, 0.0), (tj, -j), (ta, 0.0), (tj, j)]
    return [(t, jk) for t, jk in out if t > 0.0]


def _change(u: float, w: float, a: float, j: float) -> tuple[float, float, float]:
    """Jerk time, constant-acceleration time and distance of a jerk-limited change of speed from
    ``u`` to ``w`` (s'' = 0 at both ends, |s''| <= a, |s'''| <= j)."""
    dv = abs(w - u)
    if dv == 0.0:
        return 0.0, 0.0, 0.0
    tj, ta = (a / j, dv / a - a / j) if dv * j >= a * a else (float(np.sqrt(dv / j)), 0.0)
    return tj, ta, 0.5 * (u + w) * (2.0 * tj + ta)


_MAX_PASSES = 200  # over a section's segments, lowering the speeds that do not fit (see the module docstring)


def _segment_phases(lengths: list[float], bounds: list[tuple[float, ...]]) -> list[tuple[float, float]] | None:
    """(duration, jerk) of a section whose waypoint segments have these lengths and (V, A, J), at rest
    at both ends: a cruise per segment, the changes of speed inside the faster segment of each pair;
    None where the speeds did not settle within ``_MAX_PASSES``."""
    m = len(lengths)
    c = [b[0] for b in bounds]

    def needed(k: int, ck: float) -> float:
        _, a, j = bounds[k]
        before, after = (c[k - 1] if k > 0 else 0.0), (c[k + 1] if k < m - 1 else 0.0)
        up = _change(before, ck, a, j)[2] if before < ck else 0.0
        return up + (_change(ck, after, a, j)[2] if after < ck else 0.0)

    for _ in range(_MAX_PASSES):
        lowered = False
        for k in range(m):
            if needed(k, c[k]) > lengths[k]:
                lo, hi = 0.0, c[k]
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if needed(k, mid) <= lengths[k] else (lo, mid)
                c[k], lowered = lo, True
        if not lowered:
            break
    else:
        return None
    phases: list[tuple[float, float]] = []
    for k in range(m):
        _, a, j = bounds[k]
        before, after = (c[k - 1] if k > 0 else 0.0), (c[k + 1] if k < m - 1 else 0.0)
        up = _change(before, c[k], a, j) if before < c[k] else (0.0, 0.0, 0.0)
        down = _change(c[k], after, a, j) if after < c[k] else (0.0, 0.0, 0.0)
        cruise = max(0.0, lengths[k] - up[2] - down[2]) / c[k] if c[k] > 0.0 else 0.0
        phases += [(up[0], j), (up[1], 0.0), (up[0], -j), (cruise, 0.0), (down[0], -j), (down[1], 0.0), (down[0], j)]
    return [(t, jk) for t, jk in phases if t > 0.0]


def _section_phases(
    path: JointPath, lo: float, hi: float, limits: JointLimits, jmax: NDArray[np.float64]
) -> list[tuple[float, float]]:
    """(duration, jerk) of the section [lo, hi] between two rests (see the module docstring): the
    shorter of a speed per waypoint segment and one for the whole section (a segment's own A can be
    lower than the section's: its higher V takes more of the jerk's share, ``_bounds``)."""
    inner = path.waypoint_s[(path.waypoint_s > lo + 1e-12) & (path.waypoint_s < hi - 1e-12)]
    edges = np.concatenate(([lo], inner, [hi]))
    bounds = [_bounds(path, a, b, limits, jmax) for a, b in itertools.pairwise(edges)]
    per_segment = _segment_phases([float(d) for d in np.diff(edges)], bounds)
    whole = _phases(hi - lo, *_bounds(path, lo, hi, limits, jmax))
    if per_segment is None or sum(t for t, _ in whole) <= sum(t for t, _ in per_segment):
        return whole
    return per_segment


def _bounds(path: JointPath, lo: float, hi: float, limits: JointLimits, jmax: NDArray[np.float64]) -> tuple[float, ...]:
    """V, A, J of the path parameter on [lo, hi] (see the module docstring)."""
    inner = path.waypoint_s[(path.waypoint_s > lo) & (path.waypoint_s < hi)]
    edges = np.concatenate(([lo], inner, [hi]))
    s = np.concatenate([np.linspace(a, b, _SAMPLES) for a, b in itertools.pairwise(edges)])
    qs, qss = np.max(np.abs(path(s, 1)), axis=0), np.max(np.abs(path(s, 2)), axis=0)
    x, c = path.pieces
    piece = np.clip(np.searchsorted(x, 0.5 * (edges[:-1] + edges[1:]), side="right") - 1, 0, len(x) - 2)
    qsss = np.max(np.abs(6.0 * c[0][piece]), axis=0)
    with np.errstate(divide="ignore"):
        v = np.min(limits.velocity / qs)
        v = min(v, float(np.min(np.sqrt(_SHARE_A * limits.acceleration / qss))))
        v = min(v, float(np.min(np.cbrt(_SHARE_J * jmax / qsss))))
        acc = float(np.min((1.0 - _SHARE_A) * limits.acceleration / qs))
        acc = min(acc, float(np.min(_SHARE_J * jmax / (3.0 * qss * v))))
        jerk = float(np.min(_SHARE_J * jmax / qs))
    return float(v), acc, jerk


def rest_to_rest(
    path: JointPath, rests: NDArray[np.float64], limits: JointLimits, max_jerk: NDArray[np.float64]
) -> tuple[NDArray[np.float64], ...]:
    """The S-curve timing of ``path``, at rest at every s of ``rests`` (0 and the length included):
    gridpoints (every phase switch and every waypoint), s' and s'' there, s''' on each interval,
    and the gridpoints' times."""
    knots_s, knots_t, sd, sdd, jerks = [0.0], [0.0], [0.0], [0.0], []
    for lo, hi in itertools.pairwise(rests):
        waypoints = path.waypoint_s[(path.waypoint_s > lo + 1e-12) & (path.waypoint_s < hi - 1e-12)]
        phases = _section_phases(path, lo, hi, limits, max_jerk)
        snap = 1e-9 * (hi - lo)  # a phase that ends at a waypoint (a segment's end) ends there exactly
        s0, v0, a0 = lo, 0.0, 0.0
        for n, (dt, jk) in enumerate(phases):
            t0 = knots_t[-1]

            def at(tau: float, v0: float = v0, a0: float = a0, jk: float = jk) -> tuple[float, float, float]:
                """sigma, s', s'' at tau into the phase."""
                return tau * (v0 + tau * (0.5 * a0 + tau * jk / 6.0)), v0 + tau * (a0 + 0.5 * jk * tau), a0 + jk * tau

            last = n == len(phases) - 1
            end = hi if last else s0 + at(dt)[0]
            near = waypoints[np.abs(waypoints - end) <= snap]
            end = float(near[0]) if len(near) and not last else end
            inside = waypoints[(waypoints > s0 + snap) & (waypoints < end - snap)]
            for w in inside:  # a waypoint inside: its time, by bisection
                t_lo, t_hi = 0.0, dt
                for _ in range(60):
                    mid = 0.5 * (t_lo + t_hi)
                    t_lo, t_hi = (mid, t_hi) if s0 + at(mid)[0] < w else (t_lo, mid)
                _, v_w, a_w = at(0.5 * (t_lo + t_hi))
                knots_s.append(float(w))
                knots_t.append(t0 + 0.5 * (t_lo + t_hi))
                sd.append(max(v_w, 0.0))
                sdd.append(a_w)
                jerks.append(jk)
            _, v1, a1 = at(dt)
            v0, a0 = (0.0, 0.0) if last else (max(v1, 0.0), a1)
            knots_s.append(end)
            knots_t.append(t0 + dt)
            sd.append(v0)
            sdd.append(a0)
            jerks.append(jk)
            s0 = end
    return np.array(knots_s), np.array(sd), np.array(sdd), np.array(jerks), np.array(knots_t)
