"""The per-segment loops of knot placement (planner.knots), compiled with numba.

Knot placement judges hundreds of short cubics many times over: each judgement is a handful of
flops, whose cost in numpy would be the fixed price of the calls, not the arithmetic. These loops
do the judgements segment by segment in compiled code. They hold no formula of their own: the
cubic and its extrema are ``axes.interpolation``'s (``hermite``, ``cubic_peak_speed``, ...).

Layout (as in ``planner.knots.flat.Flat``): all EPOS2 axes' plan samples end to end, axis
``a``'s ms ``j`` at flat index ``a * stride + j``; ``knots`` are sorted flat indices; a knot segment whose two
knots lie on different axes is the step between two axes, not a segment, and is skipped. Units
are the drive's: qc, velocity units (``f`` qc/ms each), ms.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from axes.interpolation import (
    LIMIT_RTOL,
    Interpolation,
    central_velocity,
    cubic_peak_acceleration,
    cubic_peak_speed,
    cubic_position_range,
    hermite,
    linear_segment,
    linear_step_acceleration,
)
from axes.program import TIME_MAX_MS
from planner.slowdown import slowdown

_F = NDArray[np.float64]
_I = NDArray[np.int64]


@njit(cache=True)
def _horner(c0: float, c1: float, c2: float, c3: float, tau: float) -> float:
    return c0 + tau * (c1 + tau * (c2 + tau * c3))


@njit(cache=True)
def _probe_deviation(c0: float, c1: float, c2: float, c3: float, T: float, k0: int, plan: _F, probes: _F) -> float:
    """Worst |cubic - plan| at the whole ms ``floor(T * x)`` of a segment that starts at plan index
    ``k0`` (a cheap judgement: a few probes, not every ms)."""
    worst = 0.0
    last = len(plan) - 1
    for x in probes:
        tau = np.floor(T * x)
        worst = max(worst, abs(_horner(c0, c1, c2, c3, tau) - plan[min(k0 + int(tau), last)]))
    return worst


@njit(cache=True)
def _leaves(c0: float, c1: float, c2: float, c3: float, T: float, p1: float, v1: float, lo: float, hi: float) -> bool:
    """Whether a segment's cubic (from c0 to p1, end velocity v1) leaves [lo, hi] (0x607D): solved
    exactly only where the cheap bound (within T (|V0| + |V1|) 4/27 of its ends) reaches a limit."""
    reach = T * (abs(c1) + abs(v1)) * (4.0 / 27.0)
    if min(c0, p1) - reach >= lo and max(c0, p1) + reach <= hi:
        return False
    p_lo, p_hi = cubic_position_range(c0, c1, c2, c3, T)
    return p_lo < lo or p_hi > hi


@njit(cache=True)
def _prev_segment(prev_knots: _I, j: int, k0: int, k1: int) -> tuple[int, bool]:
    """Advance ``j`` to the previous knots' segment starting at k0; whether it is k0 .. k1."""
    while j < len(prev_knots) - 2 and prev_knots[j] < k0:
        j += 1
    return j, len(prev_knots) >= 2 and prev_knots[j] == k0 and prev_knots[j + 1] == k1


@njit(cache=True)
def check_segments(
    knots: _I,
    P: _I,
    V: _I,
    stride: int,
    f: _F,
    rv_per: _F,
    ra_per: _F,
    pos_lo: _F,
    pos_hi: _F,
    plan: _F,
    prev_knots: _I,
    prev_P: _I,
    prev_V: _I,
    prev_dev: _F,
    prev_rv: _F,
    prev_ra: _F,
    prev_out: NDArray[np.bool_],
) -> tuple[_F, _F, _F, NDArray[np.bool_]]:
    """Per knot segment, the quantized records' cubic judged exactly: worst |cubic - plan| at every
    ms (an axis's last segment also at its goal), max |v| / 0x607F, max |a| / 0x60C5, and whether
    it leaves 0x607D. A segment whose two records equal the previous check's keeps its verdict."""
    nseg = len(knots) - 1
    dev, rv, ra = np.zeros(nseg), np.zeros(nseg), np.zeros(nseg)
    out = np.zeros(nseg, dtype=np.bool_)
    j = 0
    for k in range(nseg):
        k0, k1 = knots[k], knots[k + 1]
        a = k0 // stride
        if k1 // stride != a:
            continue
        j, same = _prev_segment(prev_knots, j, k0, k1)
        if same and prev_P[j] == P[k] and prev_P[j + 1] == P[k + 1] and prev_V[j] == V[k] and prev_V[j + 1] == V[k + 1]:
            dev[k], rv[k], ra[k], out[k] = prev_dev[j], prev_rv[j], prev_ra[j], prev_out[j]
            continue
        T = float(k1 - k0)
        p0, p1 = float(P[k]), float(P[k + 1])
        v1 = V[k + 1] * f[a]
        c0, c1, c2, c3 = hermite(p0, V[k] * f[a], p1, v1, T)
        rv[k] = cubic_peak_speed(c1, c2, c3, T) * rv_per[a]
        ra[k] = cubic_peak_acceleration(c2, c3, T) * ra_per[a]
        out[k] = _leaves(c0, c1, c2, c3, T, p1, v1, pos_lo[a], pos_hi[a])
        worst = 0.0
        for t in range(k1 - k0):
            worst = max(worst, abs(_horner(c0, c1, c2, c3, float(t)) - plan[k0 + t]))
        if k == nseg - 1 or knots[k + 2] // stride != a:  # the axis's goal sample belongs to its last segment
            worst = max(worst, abs(_horner(c0, c1, c2, c3, T) - plan[k1]))
        dev[k] = worst
    return dev, rv, ra, out


@njit(cache=True)
def refine(knots: _I, p: _F, v: _F, probes: _F, target: float, max_rounds: int, t_max: int) -> _I:
    """Halve knot segments until the cubic through the exact samples stays within ``target`` of
    the plan at the whole ms ``floor(T * probes)`` (a cheap first cut), or is 1 ms long; none
    longer than ``t_max``. Round by round: each round judges the halves the last one made."""
    is_knot = np.zeros(len(p), dtype=np.bool_)
    is_knot[knots] = True
    lows, highs = knots[:-1].copy(), knots[1:].copy()  # the segments to judge
    for _ in range(max_rounds):
        new_lows, new_highs = np.empty(2 * len(lows), dtype=np.int64), np.empty(2 * len(lows), dtype=np.int64)
        n_split = 0
        for i in range(len(lows)):
            lo, hi = lows[i], highs[i]
            T = float(hi - lo)
            c0, c1, c2, c3 = hermite(p[lo], v[lo], p[hi], v[hi], T)
            worst = _probe_deviation(c0, c1, c2, c3, T, lo, p, probes)
            if (worst > target and hi - lo >= 2) or hi - lo > t_max:
                mid = (lo + hi) // 2
                is_knot[mid] = True
                new_lows[n_split], new_highs[n_split] = lo, mid
                new_lows[n_split + 1], new_highs[n_split + 1] = mid, hi
                n_split += 2
        if not n_split:
            break
        lows, highs = new_lows[:n_split], new_highs[:n_split]
    return np.flatnonzero(is_knot)


@njit(cache=True)
def switch_knots(switch_ms: _F, jump: _F, threshold: float, n_ms: int, min_gap: int) -> _I:
    """Whole ms at the acceleration switches whose jump exceeds ``threshold``, largest jumps first,
    none within ``min_gap`` of a knot already taken or of the motion's start and end."""
    taken = np.zeros(n_ms + 1, dtype=np.bool_)
    for i in np.argsort(-jump):
        if not jump[i] > threshold:
            break
        t = int(np.rint(switch_ms[i]))
        if t < min_gap or t > n_ms - min_gap:
            continue
        near = False
        for u in range(max(t - min_gap + 1, 0), min(t + min_gap - 1, n_ms) + 1):
            if taken[u]:
                near = True
                break
        if not near:
            taken[t] = True
    return np.flatnonzero(taken)


@njit(cache=True)
def lsq_rhs(
    knots: _I, stride: int, plan: _F, values: _F, offset: _I, prev_knots: _I, prev_rhs: _F
) -> tuple[_F, NDArray[np.bool_], _I]:
    """Per knot segment, its four basis cubics against the plan summed over its samples (the
    least-squares right-hand side; ``values[:, offset[T] + tau]`` is basis cubic b at tau for
    length T). Reused from ``prev_rhs`` where the segment is unchanged. Also returns, per
    segment, whether it is unchanged and its index in ``prev_knots``."""
    nseg = len(knots) - 1
    r = np.zeros((4, nseg))
    same = np.zeros(nseg, dtype=np.bool_)
    where = np.zeros(nseg, dtype=np.int64)
    j = 0
    for k in range(nseg):
        k0, k1 = knots[k], knots[k + 1]
        j, same_k = _prev_segment(prev_knots, j, k0, k1)
        where[k] = j
        if k1 // stride != k0 // stride:
            continue
        if same_k:
            same[k] = True
            for b in range(4):
                r[b, k] = prev_rhs[b, j]
            continue
        base = offset[k1 - k0]
        s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
        for t in range(k1 - k0):
            x = plan[k0 + t]
            s0 += values[0, base + t] * x
            s1 += values[1, base + t] * x
            s2 += values[2, base + t] * x
            s3 += values[3, base + t] * x
        r[0, k], r[1, k], r[2, k], r[3, k] = s0, s1, s2, s3
    return r, same, where


@njit(cache=True)
def lsq_worst(
    knots: _I,
    stride: int,
    plan: _F,
    values: _F,
    offset: _I,
    P: _F,
    V: _F,
    target: float,
    same: NDArray[np.bool_],
    where: _I,
    prev_P: _F,
    prev_V: _F,
    prev_worst: _F,
) -> _F:
    """Per knot segment, the worst |least-squares cubic - plan| over its samples, as far as the
    comparison with ``target`` needs it: an unchanged segment whose cubic moved by at most d (its
    ends by dP, dV: d <= max |dP| + 4/27 T (|dV0| + |dV1|)) keeps its previous worst when that is
    more than d away from the target (``prev_worst`` empty: no previous fit)."""
    nseg = len(knots) - 1
    worst = np.zeros(nseg)
    for k in range(nseg):
        k0, k1 = knots[k], knots[k + 1]
        if k1 // stride != k0 // stride:
            continue
        T = float(k1 - k0)
        if same[k] and len(prev_worst):
            i = where[k]
            d = max(abs(P[k] - prev_P[i]), abs(P[k + 1] - prev_P[i + 1])) + (4.0 / 27.0) * T * (
                abs(V[k] - prev_V[i]) + abs(V[k + 1] - prev_V[i + 1])
            )
            d = d * (1.0 + 1e-9) + 1e-9
            w = prev_worst[i]
            if w + d <= target or w - d > target:
                worst[k] = w
                continue
        base = offset[k1 - k0]
        w = 0.0
        for t in range(k1 - k0):
            fit = (
                P[k] * values[0, base + t]
                + V[k] * values[1, base + t]
                + P[k + 1] * values[2, base + t]
                + V[k + 1] * values[3, base + t]
            )
            w = max(w, abs(fit - plan[k0 + t]))
        worst[k] = w
    return worst


@njit(cache=True)
def lsq_system(knots: _I, stride: int, r: _F, gram: _F, p: _F, v: _F, ends: NDArray[np.bool_]) -> tuple[_F, _F, _F]:
    """The least-squares normal equations over each knot's (P, V), block tridiagonal: per knot its
    symmetric 2x2 diagonal block ``D[k] = (d_PP, d_PV, d_VV)``, the 2x2 block ``E[k] = (e_PP,
    e_PV, e_VP, e_VV)`` that couples it to knot k + 1 (rows k, columns k + 1), and its right-hand
    side ``b[k]``. Each segment adds its Gram matrix and right-hand side, a faint pull towards the
    exact samples keeps the system regular, and each axis's end knots are pinned at the plan, at
    rest. The step between two axes couples nothing: each axis's block is solved as it would be
    alone."""
    nk = len(knots)
    D, E, b = np.zeros((nk, 3)), np.zeros((nk, 4)), np.zeros((nk, 2))
    for k in range(nk - 1):
        k0, k1 = knots[k], knots[k + 1]
        if k1 // stride != k0 // stride:
            continue
        n = k1 - k0  # gram[n]: over (P0, V0, P1, V1), symmetric
        D[k, 0] += gram[n, 0, 0]
        D[k, 1] += gram[n, 0, 1]
        D[k, 2] += gram[n, 1, 1]
        D[k + 1, 0] += gram[n, 2, 2]
        D[k + 1, 1] += gram[n, 2, 3]
        D[k + 1, 2] += gram[n, 3, 3]
        E[k, 0], E[k, 1], E[k, 2], E[k, 3] = gram[n, 0, 2], gram[n, 0, 3], gram[n, 1, 2], gram[n, 1, 3]
        b[k, 0] += r[0, k]
        b[k, 1] += r[1, k]
        b[k + 1, 0] += r[2, k]
        b[k + 1, 1] += r[3, k]
    for k in range(nk):
        tw = (
            float(knots[k + 1] - knots[k])
            if k == 0
            else (float(knots[k] - knots[k - 1]) if k == nk - 1 else 0.5 * float(knots[k + 1] - knots[k - 1]))
        )
        reg_v = 1e-3 * tw * tw
        D[k, 0] += 1e-3
        D[k, 2] += reg_v
        b[k, 0] += 1e-3 * p[knots[k]]
        b[k, 1] += reg_v * v[knots[k]]
    # pin each axis's ends, with a weight far above its block's diagonal
    k = 0
    while k < nk:
        a = knots[k] // stride
        e = k
        big = 0.0
        while e < nk and knots[e] // stride == a:
            big = max(big, abs(D[e, 0]), abs(D[e, 2]))
            e += 1
        big = 1e9 * (1.0 + big)
        for i in (k, e - 1):
            if ends[i]:
                D[i, 0] += big
                b[i, 0] += big * p[knots[i]]
                D[i, 2] += big
        k = e
    return D, E, b


@njit(cache=True)
def _solve_block_tridiagonal(D: _F, E: _F, b: _F) -> bool:
    """Solve the symmetric block tridiagonal system of ``lsq_system`` in place (z in ``b``): block
    elimination with 2x2 blocks (S_k = D_k - E_k-1^T S_k-1^-1 E_k-1, then back substitution), a
    few scalar operations per knot. False if a pivot block is not positive definite (the normal
    equations are then not either)."""
    n = len(D)
    W = np.empty((n, 3))  # S_k^-1, symmetric
    w00, w01, w11 = 0.0, 0.0, 0.0
    for k in range(n):
        s00, s01, s11 = D[k, 0], D[k, 1], D[k, 2]
        y0, y1 = b[k, 0], b[k, 1]
        if k > 0:
            e00, e01, e10, e11 = E[k - 1, 0], E[k - 1, 1], E[k - 1, 2], E[k - 1, 3]
            # F = W_k-1 E_k-1; S -= E^T F; y -= F^T y_k-1
            f00, f01 = w00 * e00 + w01 * e10, w00 * e01 + w01 * e11
            f10, f11 = w01 * e00 + w11 * e10, w01 * e01 + w11 * e11
            s00 -= e00 * f00 + e10 * f10
            s01 -= e00 * f01 + e10 * f11
            s11 -= e01 * f01 + e11 * f11
            p0, p1 = b[k - 1, 0], b[k - 1, 1]
            y0 -= f00 * p0 + f10 * p1
            y1 -= f01 * p0 + f11 * p1
        det = s00 * s11 - s01 * s01
        if not (s00 > 0.0 and det > 0.0):
            return False
        w00, w01, w11 = s11 / det, -s01 / det, s00 / det
        W[k, 0], W[k, 1], W[k, 2] = w00, w01, w11
        b[k, 0], b[k, 1] = y0, y1
    z0, z1 = 0.0, 0.0
    for k in range(n - 1, -1, -1):
        y0, y1 = b[k, 0], b[k, 1]
        if k < n - 1:
            y0 -= E[k, 0] * z0 + E[k, 1] * z1
            y1 -= E[k, 2] * z0 + E[k, 3] * z1
        z0 = W[k, 0] * y0 + W[k, 1] * y1
        z1 = W[k, 1] * y0 + W[k, 2] * y1
        b[k, 0], b[k, 1] = z0, z1
    return True


@njit(cache=True)
def lsq_solve(knots: _I, stride: int, r: _F, gram: _F, p: _F, v: _F, ends: NDArray[np.bool_]) -> tuple[_F, _F, bool]:
    """The least-squares knot positions and velocities: ``lsq_system`` solved by block elimination,
    each axis's ends exactly at the plan, at rest. The flag is False if the solve failed."""
    D, E, z = lsq_system(knots, stride, r, gram, p, v, ends)
    ok = _solve_block_tridiagonal(D, E, z)
    P, V = z[:, 0].copy(), z[:, 1].copy()
    for k in range(len(knots)):
        if ends[k]:
            P[k], V[k] = p[knots[k]], 0.0
    return P, V, ok


# --- the integer repair --------------------------------------------------------------------------
# A record may move by up to _DP counts and _DV velocity units off its rounding: nudge e of a record
# moves it by _dp(e) counts and _dv(e) units (nudge 0 moves nothing).
_DP, _DV = 1, 2
_N_NUDGES = (2 * _DP + 1) * (2 * _DV + 1)
_PROBES = np.array([0.25, 0.5, 0.75])  # where inside a segment the deviation of a nudge is judged
_EXCESS_WEIGHT = 1e6  # a ratio excess of 1e-5 outweighs a chain's deviations (counts): excess first


@njit(cache=True)
def _dp(e: int) -> int:
    e = (e + _DP * (2 * _DV + 1) + _DV) % _N_NUDGES  # nudge 0 first: the record as it is
    return e // (2 * _DV + 1) - _DP


@njit(cache=True)
def _dv(e: int) -> int:
    e = (e + _DP * (2 * _DV + 1) + _DV) % _N_NUDGES
    return e % (2 * _DV + 1) - _DV


@njit(cache=True)
def _chain_cubic(
    p0: float,
    v0: float,
    p1: float,
    v1: float,
    T: float,
    k0: int,
    plan: _F,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
    tol: float,
) -> tuple[float, float]:
    """A candidate cubic's worst limit ratio (inf where it strays more than ``tol`` from the plan at
    its ends and probes, or leaves 0x607D) and that deviation."""
    c0, c1, c2, c3 = hermite(p0, v0, p1, v1, T)
    dev = max(abs(p0 - plan[k0]), abs(p1 - plan[k0 + int(T)]))
    dev = max(dev, _probe_deviation(c0, c1, c2, c3, T, k0, plan, _PROBES))
    if dev > tol:
        return np.inf, dev
    if _leaves(c0, c1, c2, c3, T, p1, v1, pos_lo, pos_hi):
        return np.inf, dev
    ratio = max(cubic_peak_speed(c1, c2, c3, T) * rv_per, cubic_peak_acceleration(c2, c3, T) * ra_per)
    return ratio, dev


@njit(cache=True)
def _candidates(
    knots: _I, P: _I, V: _I, k: int, shift: int, plan: _F, plan_v: _F, f: float, v_units: float
) -> tuple[_I, _I, _I]:
    """Knot k's candidate records (time, count, velocity units): its record nudged by up to _DP
    counts and _DV units, in nudge order (``_STILL`` first of all: the record as it is); with
    ``shift``, also the knot moved by up to ``shift`` ms, from the plan's sample there, rounded,
    and nudged the same way (a record's cubics change with their length: moving a knot changes
    which accelerations the integers can make)."""
    n = (2 * shift + 1) * _N_NUDGES
    t, p, v = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    c = 0
    for ds in range(-shift, shift + 1):
        tk = knots[k] + (0 if ds == 0 else ds)
        if ds == 0:
            p0, v0 = P[k], V[k]
        else:
            p0 = int(np.rint(plan[tk]))
            v0 = int(min(max(np.rint(plan_v[tk] / f), -v_units), v_units))
        for e in range(_N_NUDGES):
            t[c], p[c], v[c] = tk, p0 + _dp(e), v0 + _dv(e)
            c += 1
    if shift:  # the record as it is first
        t[0], t[shift * _N_NUDGES] = t[shift * _N_NUDGES], t[0]
        p[0], p[shift * _N_NUDGES] = p[shift * _N_NUDGES], p[0]
        v[0], v[shift * _N_NUDGES] = v[shift * _N_NUDGES], v[0]
    return t, p, v


@njit(cache=True)
def _repair_chain(
    knots: _I,
    P: _I,
    V: _I,
    i0: int,
    i1: int,
    shift: int,
    stride: int,
    f: float,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
    v_units: float,
    plan: _F,
    plan_v: _F,
    tol: float,
) -> bool:
    """Re-choose the records of knots i0 .. i1 (in place, between the fixed knots i0 - 1 and
    i1 + 1) among their ``_candidates``: the combination whose worst limit ratio over the chain's
    segments is the least (a bottleneck path), and among those that keep every segment under
    max(that, 1), the one with the least summed excess over 1 (fewest segments left for the
    splits), then the closest to the plan (a shortest path). Whether it moved anything."""
    L = i1 - i0 + 1
    nc = (2 * shift + 1) * _N_NUDGES
    ct, cp, cv = (
        np.empty((L + 2, nc), dtype=np.int64),
        np.empty((L + 2, nc), dtype=np.int64),
        np.empty((L + 2, nc), dtype=np.int64),
    )
    n_cand = np.empty(L + 2, dtype=np.int64)
    for j in range(L + 2):
        k = i0 - 1 + j
        if j == 0 or j == L + 1:  # the fixed ends: the record as it is
            ct[j, 0], cp[j, 0], cv[j, 0], n_cand[j] = knots[k], P[k], V[k], 1
        else:
            t, p, v = _candidates(knots, P, V, k, shift, plan, plan_v, f, v_units)
            # a candidate further than tol from the plan at its own time is out whatever its neighbours
            # (the record as it is stays first, to judge the chain as it is)
            n = 0
            for c in range(nc):
                if c == 0 or abs(p[c] - plan[t[c]]) <= tol:
                    ct[j, n], cp[j, n], cv[j, n] = t[c], p[c], v[c]
                    n += 1
            n_cand[j] = n
    R = np.full((L + 1, nc, nc), np.inf)
    D = np.zeros((L + 1, nc, nc))
    for j in range(L + 1):
        for e0 in range(n_cand[j]):
            for e1 in range(n_cand[j + 1]):
                T = ct[j + 1, e1] - ct[j, e0]
                if T < 1 or T > TIME_MAX_MS:
                    continue
                R[j, e0, e1], D[j, e0, e1] = _chain_cubic(
                    float(cp[j, e0]),
                    cv[j, e0] * f,
                    float(cp[j + 1, e1]),
                    cv[j + 1, e1] * f,
                    float(T),
                    ct[j, e0],
                    plan,
                    rv_per,
                    ra_per,
                    pos_lo,
                    pos_hi,
                    tol,
                )
    now = 0.0
    for j in range(L + 1):
        now = max(now, R[j, 0, 0])
    # pass 1: the least worst ratio
    M = np.full(nc, np.inf)
    M[0] = 0.0
    for j in range(L + 1):
        M_next = np.full(nc, np.inf)
        for e1 in range(n_cand[j + 1]):
            for e0 in range(n_cand[j]):
                M_next[e1] = min(M_next[e1], max(M[e0], R[j, e0, e1]))
        M = M_next
    best = M[0]
    if not best < now:
        return False
    # pass 2: under max(best, 1), the least excess, then the closest to the plan
    cap = max(best, 1.0)
    S = np.full(nc, np.inf)
    S[0] = 0.0
    back = np.zeros((L + 1, nc), dtype=np.int64)
    for j in range(L + 1):
        S_next = np.full(nc, np.inf)
        for e1 in range(n_cand[j + 1]):
            for e0 in range(n_cand[j]):
                r = R[j, e0, e1]
                cost = S[e0] + _EXCESS_WEIGHT * max(r - 1.0, 0.0) + D[j, e0, e1]
                if r <= cap and cost < S_next[e1]:
                    S_next[e1] = cost
                    back[j, e1] = e0
        S = S_next
    e = 0
    moved = False
    for j in range(L, 0, -1):
        e = back[j, e]
        k = i0 - 1 + j
        knots[k], P[k], V[k] = ct[j, e], cp[j, e], cv[j, e]
        moved |= e != 0
    return moved


@njit(cache=True)
def repair_chains(
    knots: _I,
    P: _I,
    V: _I,
    segments: _I,
    reach: int,
    shift: int,
    stride: int,
    f: _F,
    rv_per: _F,
    ra_per: _F,
    pos_lo: _F,
    pos_hi: _F,
    v_units: _F,
    plan: _F,
    plan_v: _F,
    tol: float,
) -> bool:
    """Re-round the records within ``reach`` knots of every segment of ``segments`` (in place;
    with ``shift``, the knots may move by up to that many ms): each run of such knots is one
    chain, repaired as a whole (``_repair_chain``). Whether any record moved."""
    nk = len(knots)
    free = np.zeros(nk, dtype=np.bool_)
    for s in segments:
        a = knots[s] // stride
        for k in range(max(s - reach + 1, 0), min(s + reach, nk - 1) + 1):
            r = knots[k] - a * stride
            if shift < r < stride - 1 - shift:  # on the segment's axis, no axis end (never moved) nor next to one
                free[k] = True
    moved = False
    k = 0
    while k < nk:
        if not free[k]:
            k += 1
            continue
        i0 = k
        while k + 1 < nk and free[k + 1]:
            k += 1
        a = knots[i0] // stride
        moved |= _repair_chain(
            knots,
            P,
            V,
            i0,
            k,
            shift,
            stride,
            f[a],
            rv_per[a],
            ra_per[a],
            pos_lo[a],
            pos_hi[a],
            v_units[a],
            plan,
            plan_v,
            tol,
        )
        k += 1
    return moved


# --- fixed-period profiles: the exact integer search ---------------------------------------------------
# The reconstructions a fixed-period drive applies to its setpoints (axes.interpolation's
# ``linear``, ``cubic_pv``, ``cubic_p``). Each judges a segment on a window of consecutive points of
# the records padded with copies of their first and last point (velocity 0 there), so that the rest
# at both ends comes out of each segment's own rule: linear [R0, R0, R0, R1 .. RN, RN] (the velocity
# before the first segment is 0), cubic_pv [(R0, 0), R0 .. RN, (RN, 0)], cubic_p [R0, R0, R0, R1 ..
# RN, RN, RN] (the central velocities at both ends are 0).
# The kinds as ints for numba, from ``Interpolation.code``
LINEAR, CUBIC_PV, CUBIC_P = Interpolation.LINEAR.code, Interpolation.CUBIC_PV.code, Interpolation.CUBIC_P.code
_FP_PROBES = np.array([0.25, 0.5, 0.75])  # where inside a segment its deviation from the plan is judged


@njit(cache=True)
def _fp_layout(kind: int) -> tuple[int, int, int, int]:
    """(points per window, pad points before record 0, after the last record, where in the window
    the judged segment starts)."""
    if kind == LINEAR:
        return 3, 2, 1, 1
    if kind == CUBIC_PV:
        return 2, 1, 1, 0
    return 4, 2, 2, 1


@njit(cache=True)
def _count_nudge(e: int) -> int:
    """Nudge e of a setpoint without a velocity: 0, +1, -1, +2, -2 ... counts."""
    return (e + 1) // 2 if e % 2 else -(e // 2)


@njit(cache=True)
def _fp_judge(
    kind: int,
    q0: float,
    q1: float,
    q2: float,
    q3: float,
    u0: float,
    u1: float,
    T: float,
    k0: int,
    n_real: int,
    plan: _F,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
) -> tuple[float, float, float]:
    """One segment of a fixed-period reconstruction from its window of points (positions q, for
    cubic_pv velocities u in qc/ms): max |v| / 0x607F and max |a| / 0x60C5 (both inf where it
    leaves 0x607D), and its summed squared deviation from the plan at its end and probes if it runs
    from record k0 to record k0 + 1 of the n_real + 1 records (0 for the padding's segments)."""
    if kind == LINEAR:
        v_prev = linear_segment(q0, q1, T)[1]
        c0, c1 = linear_segment(q1, q2, T)
        c2 = c3 = 0.0
        acceleration = linear_step_acceleration(v_prev, c1, T)
        p1, v1 = q2, c1
    elif kind == CUBIC_PV:
        c0, c1, c2, c3 = hermite(q0, u0, q1, u1, T)
        acceleration = cubic_peak_acceleration(c2, c3, T)
        p1, v1 = q1, u1
    else:
        v1 = central_velocity(q1, q3, T)
        c0, c1, c2, c3 = hermite(q1, central_velocity(q0, q2, T), q2, v1, T)
        acceleration = cubic_peak_acceleration(c2, c3, T)
        p1 = q2
    if kind != LINEAR and _leaves(c0, c1, c2, c3, T, p1, v1, pos_lo, pos_hi):
        return np.inf, np.inf, 0.0  # a linear segment stays between its ends, which are inside
    dev = 0.0
    if 0 <= k0 < n_real:
        last = len(plan) - 1
        t0 = k0 * int(T)
        dev = (p1 - plan[min(t0 + int(T), last)]) ** 2
        for x in _FP_PROBES:
            tau = np.floor(T * x)
            dev += (_horner(c0, c1, c2, c3, tau) - plan[min(t0 + int(tau), last)]) ** 2
    return cubic_peak_speed(c1, c2, c3, T) * rv_per, acceleration * ra_per, dev


@njit(cache=True)
def fixed_period_ratios(
    kind: int,
    p: _F,
    v: _F,
    plan: _F,
    period: int,
    f: float,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
) -> tuple[_F, _F]:
    """Per segment of the reconstruction (``kind``) of the records at positions ``p`` and velocity
    units ``v`` (floats: the plan's exact samples as well as integers), max |v| / 0x607F and max
    |a| / 0x60C5."""
    W, pad_l, pad_r, _ = _fp_layout(kind)
    n = len(p) - 1
    L = pad_l + n + 1 + pad_r
    T = float(period)
    q, u = np.zeros(4), np.zeros(4)
    rv, ra = np.empty(L - W + 1), np.empty(L - W + 1)
    for i in range(W - 1, L):
        for d in range(W):
            j = i - W + 1 + d - pad_l
            q[d] = p[min(max(j, 0), n)]
            u[d] = v[j] * f if 0 <= j <= n else 0.0
        rv[i - W + 1], ra[i - W + 1], _ = _fp_judge(
            kind, q[0], q[1], q[2], q[3], u[0], u[1], T, -1, n, plan, rv_per, ra_per, pos_lo, pos_hi
        )
    return rv, ra


@njit(cache=True)
def _fp_window(cp: _I, cv: _I, nc: _I, i: int, s: int, W: int, f: float, q: _F, u: _F) -> None:
    """The window of points i - W + 1 .. i - 1 for the state ``s`` (their choices, the newest the
    lowest digit of a mixed radix), into q (positions) and u (velocities, qc/ms)."""
    for d in range(1, W):
        c = s % nc[i - d]
        s //= nc[i - d]
        q[W - 1 - d], u[W - 1 - d] = cp[i - d, c], cv[i - d, c] * f


@njit(cache=True)
def track_fixed_period(
    kind: int,
    P: _I,
    V: _I,
    plan: _F,
    period: int,
    f: float,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
    v_units: float,
    reach: int,
) -> tuple[_I, _I, float]:
    """The integer setpoints of a fixed-period axis whose reconstruction (``kind``) stays inside the
    limits, from their rounding ``P``, ``V``: the rounding itself where it is inside already, else
    the best combination of the candidates of every record between the first and the last, found
    exactly by a Viterbi pass over the reconstruction's windows (the state: the choices of a
    window's first points). Candidates: cubic_pv, the EPOS2 nudges (a count, two velocity units);
    a position alone, a count, and up to ``reach`` counts within ``reach`` points of a segment the
    rounding puts over a limit (where the plan's acceleration jumps between two records, a cubic
    through its samples overshoots: the records have to leave the plan there). The least slow-down
    the segments call for first (a bottleneck path), then, among the combinations that keep every
    segment under max(that, 1), the least summed excess over 1, then the closest to the plan.
    Returns the records' positions and velocities, and the slow-down they call for (1: none)."""
    W, pad_l, pad_r, at = _fp_layout(kind)
    n = len(P) - 1
    L = pad_l + n + 1 + pad_r
    T = float(period)
    rv, ra = fixed_period_ratios(kind, P * 1.0, V * 1.0, plan, period, f, rv_per, ra_per, pos_lo, pos_hi)
    plain = 1.0
    near = np.zeros(L, dtype=np.int64)  # per point: how far it may move off its rounding
    for w in range(len(rv)):
        need = slowdown(rv[w], ra[w])
        if not need <= 1.0 + LIMIT_RTOL:
            plain = max(plain, need)
            for j in range(max(w - reach, 0), min(w + W - 1 + reach, L - 1) + 1):
                near[j] = reach
    if plain == 1.0:
        return P.copy(), V.copy(), 1.0
    C = _N_NUDGES if kind == CUBIC_PV else 2 * max(reach, 1) + 1
    cp, cv = np.empty((L, C), dtype=np.int64), np.zeros((L, C), dtype=np.int64)
    nc = np.ones(L, dtype=np.int64)
    for i in range(L):
        cp[i, 0] = P[min(max(i - pad_l, 0), n)]
        if pad_l <= i <= pad_l + n:
            cv[i, 0] = V[i - pad_l]
    for i in range(pad_l + 1, pad_l + n):  # the ends stay where the plan starts and stops
        m = 1
        for e in range(1, _N_NUDGES if kind == CUBIC_PV else 2 * max(near[i], 1) + 1):
            dp, dv = (_dp(e), _dv(e)) if kind == CUBIC_PV else (_count_nudge(e), 0)
            p, v = cp[i, 0] + dp, cv[i, 0] + dv
            if pos_lo <= p <= pos_hi and abs(v) <= v_units:
                cp[i, m], cv[i, m] = p, v
                m += 1
        nc[i] = m
    # the verdicts of every (previous state, choice) of every point, laid end to end
    offset = np.zeros(L + 1, dtype=np.int64)
    for i in range(L):
        states = 1
        if i >= W - 1:
            for d in range(1, W):
                states *= nc[i - d]
        offset[i + 1] = offset[i] + states * nc[i]
    R = np.empty(offset[L])
    D = np.empty(offset[L])
    q, u = np.zeros(4), np.zeros(4)
    # pass 1: every segment's verdict, and the least slow-down (a bottleneck path)
    B = np.zeros(1)  # the first W - 1 points: the padding and record 0, one candidate each
    for i in range(W - 1, L):
        kept = 1  # the weight of the oldest digit of the previous state: the part the next state keeps
        for d in range(1, W - 1):
            kept *= nc[i - d]
        B_next = np.full(kept * nc[i], np.inf)
        k0 = i - W + 1 + at - pad_l
        for s in range(len(B)):
            _fp_window(cp, cv, nc, i, s, W, f, q, u)
            for c in range(nc[i]):
                q[W - 1], u[W - 1] = cp[i, c], cv[i, c] * f
                j = offset[i] + s * nc[i] + c
                r_v, r_a, D[j] = _fp_judge(
                    kind, q[0], q[1], q[2], q[3], u[0], u[1], T, k0, n, plan, rv_per, ra_per, pos_lo, pos_hi
                )
                R[j] = slowdown(r_v, r_a)
                s_next = (s % kept) * nc[i] + c
                B_next[s_next] = min(B_next[s_next], max(B[s], R[j]))
        B = B_next
    best = B[0]  # the last W - 1 points are the last record and the padding: one candidate each
    # pass 2: under max(best, 1), the least excess, then the closest to the plan (a shortest path)
    cap = max(best, 1.0 + LIMIT_RTOL)
    G = np.zeros(1)
    back = np.zeros(offset[L], dtype=np.int64)  # per point and next state: the previous state
    for i in range(W - 1, L):
        kept = 1
        for d in range(1, W - 1):
            kept *= nc[i - d]
        G_next = np.full(kept * nc[i], np.inf)
        for s in range(len(G)):
            if G[s] == np.inf:
                continue
            for c in range(nc[i]):
                j = offset[i] + s * nc[i] + c
                if not R[j] <= cap:
                    continue
                cost = G[s] + _EXCESS_WEIGHT * max(R[j] - 1.0, 0.0) + D[j]
                s_next = (s % kept) * nc[i] + c
                if cost < G_next[s_next]:
                    G_next[s_next] = cost
                    back[offset[i] + s_next] = s
        G = G_next
    P_out, V_out = P.copy(), V.copy()
    s = 0
    for i in range(L - 1, W - 2, -1):
        c = s % nc[i]
        if pad_l < i < pad_l + n:
            P_out[i - pad_l], V_out[i - pad_l] = cp[i, c], cv[i, c]
        s = back[offset[i] + s]
    return P_out, V_out, max(best, 1.0)
