"""Steps 1-2 of knot placement compiled with numba (``planner.knots.refine``): knots at the
acceleration switches, segments halved until their cubics follow the plan, and the least-squares
cubics (a block-tridiagonal system over the knots' positions and velocities) fitted to the plan.

Layout (as in ``planner.knots.flat.Flat``): all EPOS2 axes' plan samples end to end, axis
``a``'s ms ``j`` at flat index ``a * stride + j``; ``knots`` are sorted flat indices; a knot segment whose two
knots lie on different axes is the step between two axes, not a segment, and is skipped. Units
are the drive's: qc, velocity units (``f`` qc/ms each), ms.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import (
    hermite,
)
from pvtflow.planner.knots.check_kernels import prev_segment, probe_deviation

_F = NDArray[np.float64]
_I = NDArray[np.int64]


@njit(cache=True)
def refine(knots: _I, p: _F, v: _F, probes: _F, target: float, max_rounds: int, t_max: int) -> _I:
    """Halve knot segments until the cubic through the exact samples stays within ``target`` of
    the plan at the whole ms ``floor(T * probes)`` (a cheap first cut), or is 1 ms long; none
    longer than ``t_max``. Round by round: each round judges the halves the last one made. A
    half's new knot lies strictly inside its segment: the knots are the given ones and the new
    ones, sorted (no array over every ms)."""
    lows, highs = knots[:-1].copy(), knots[1:].copy()  # the segments to judge
    added = [np.empty(0, dtype=np.int64)]  # the new knots of each round
    for _ in range(max_rounds):
        new_lows, new_highs = np.empty(2 * len(lows), dtype=np.int64), np.empty(2 * len(lows), dtype=np.int64)
        made = np.empty(len(lows), dtype=np.int64)
        n_split = 0
        for i in range(len(lows)):
            lo, hi = lows[i], highs[i]
            T = float(hi - lo)
            c0, c1, c2, c3 = hermite(p[lo], v[lo], p[hi], v[hi], T)
            worst = probe_deviation(c0, c1, c2, c3, T, lo, p, probes)
            if (worst > target and hi - lo >= 2) or hi - lo > t_max:
                mid = (lo + hi) // 2
                made[n_split // 2] = mid
                new_lows[n_split], new_highs[n_split] = lo, mid
                new_lows[n_split + 1], new_highs[n_split + 1] = mid, hi
                n_split += 2
        if not n_split:
            break
        added.append(made[: n_split // 2])
        lows, highs = new_lows[:n_split], new_highs[:n_split]
    total = len(knots)
    for a in added:
        total += len(a)
    out = np.empty(total, dtype=np.int64)
    out[: len(knots)] = knots
    j = len(knots)
    for a in added:
        out[j : j + len(a)] = a
        j += len(a)
    return np.sort(out)


@njit(cache=True)
def switch_knots(switch_ms: _F, jump: _F, threshold: float, n_ms: int, min_gap: int) -> _I:
    """Whole ms at the acceleration switches whose jump exceeds ``threshold``, largest jumps first,
    none within ``min_gap`` of a knot already taken or of the motion's start and end (sorted). Only
    the jumps over the threshold are sorted (a few tens of the gridpoints'), and a candidate is
    held against the knots taken, not against every ms."""
    over = np.empty(len(jump), dtype=np.int64)
    n = 0
    for i in range(len(jump)):
        if jump[i] > threshold:
            over[n] = i
            n += 1
    cand = over[:n]
    taken = np.empty(n, dtype=np.int64)
    m = 0
    for i in cand[np.argsort(-jump[cand])]:
        t = int(np.rint(switch_ms[i]))
        if t < min_gap or t > n_ms - min_gap:
            continue
        near = False
        for u in taken[:m]:
            if abs(t - u) < min_gap:
                near = True
                break
        if not near:
            taken[m] = t
            m += 1
    return np.sort(taken[:m])


@njit(cache=True)
def switch_flat_knots(switch_ms: _F, jump: _F, cols: _I, thresholds: _F, n_ms: int, min_gap: int, t_max: int) -> _I:
    """``switch_knots`` of every axis (column ``cols[a]`` of ``jump``, threshold ``thresholds[a]``)
    laid end to end as ``Flat.flat_knots`` lays them: axis a's ms j at a * (n_ms + 1) + j, both ends
    of every axis, and every gap longer than ``t_max`` split evenly (``flat.within_record_time``)."""
    stride = n_ms + 1
    col = np.empty(len(switch_ms))
    switches = np.empty((len(cols), len(switch_ms)), dtype=np.int64)  # each axis's, sorted, first ``taken[a]``
    taken = np.empty(len(cols), dtype=np.int64)
    n = 0
    for a in range(len(cols)):
        for i in range(len(switch_ms)):
            col[i] = jump[i, cols[a]]
        sw = switch_knots(switch_ms, col, thresholds[a], n_ms, min_gap)
        switches[a, : len(sw)] = sw
        taken[a] = len(sw)
        n += len(sw) + 2 + (n_ms + len(sw)) // t_max  # at most this many after the splits
    out = np.empty(n, dtype=np.int64)
    n = 0
    for a in range(len(cols)):
        base = a * stride
        out[n] = base
        n += 1
        last = 0
        for i in range(taken[a] + 1):
            t = switches[a, i] if i < taken[a] else n_ms
            if t <= 0 or (t >= n_ms and i < taken[a]):  # the ends are the axis's own
                continue
            gap = t - last
            if gap > t_max:
                pieces = -(-gap // t_max)
                for j in range(1, pieces):
                    out[n] = base + last + (gap * j) // pieces
                    n += 1
            out[n] = base + t
            n += 1
            last = t
    return out[:n]


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
        j, same_k = prev_segment(prev_knots, j, k0, k1)
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
        # the time a knot stands for: half its two segments; the first and last knot of the whole,
        # their one segment; next to another axis's knot, that one counts as 1 ms away (where the
        # axes lie end to end it is: an axis is placed as in the layout, whichever axes left)
        if k == 0:
            tw = float(knots[1] - knots[0])
        elif k == nk - 1:
            tw = float(knots[k] - knots[k - 1])
        else:
            a = knots[k] // stride
            lo = knots[k - 1] if knots[k - 1] // stride == a else knots[k] - 1
            hi = knots[k + 1] if knots[k + 1] // stride == a else knots[k] + 1
            tw = 0.5 * float(hi - lo)
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


@njit(cache=True)
def split_at(knots: _I, segments: _I) -> _I:
    """``knots`` with each of the given segments (sorted, unique) halved; those of 1 ms are left alone."""
    n_new = 0
    for s in segments:
        n_new += knots[s + 1] - knots[s] >= 2
    out = np.empty(len(knots) + n_new, dtype=np.int64)
    j, b = 0, 0
    for k in range(len(knots)):
        out[j] = knots[k]
        j += 1
        if b < len(segments) and segments[b] == k:
            if knots[k + 1] - knots[k] >= 2:
                out[j] = (knots[k] + knots[k + 1]) // 2
                j += 1
            b += 1
    return out


@njit(cache=True)
def fit_rounds(
    knots: _I,
    stride: int,
    plan: _F,
    plan_v: _F,
    values: _F,
    offset: _I,
    gram: _F,
    target: float,
    max_rounds: int,
    t_max: int,
) -> tuple[bool, _I, _I, _F, _F, _F, _F]:
    """Least-squares fits (``lsq_rhs``, ``lsq_solve``, ``lsq_worst``) and splits, round by round in
    one call, until every segment's fit is within ``target`` (or 1 ms long) and none is longer than
    ``t_max``. Returns (solved, the knots, the knots of the last fit, its right-hand side, P, V and
    per-segment worst): the two knot sets differ only where ``max_rounds`` ran out."""
    fit_knots = knots
    r = np.zeros((4, 0))
    P, V, worst = np.zeros(0), np.zeros(0), np.zeros(0)
    prev_knots = np.zeros(0, dtype=np.int64)
    for _ in range(max_rounds):
        r, same, where = lsq_rhs(knots, stride, plan, values, offset, prev_knots, r)
        ends = np.empty(len(knots), dtype=np.bool_)
        for k in range(len(knots)):
            m = knots[k] % stride
            ends[k] = m == 0 or m == stride - 1
        P_new, V_new, ok = lsq_solve(knots, stride, r, gram, plan, plan_v, ends)
        if not ok:
            return False, knots, knots, r, P_new, V_new, worst
        worst = lsq_worst(knots, stride, plan, values, offset, P_new, V_new, target, same, where, P, V, worst)
        P, V, fit_knots, prev_knots = P_new, V_new, knots, knots
        n_bad = 0
        bad = np.empty(len(knots) - 1, dtype=np.int64)
        for k in range(len(knots) - 1):
            span = knots[k + 1] - knots[k]
            if (worst[k] > target and span >= 2) or span > t_max:
                bad[n_bad] = k
                n_bad += 1
        if not n_bad:
            break
        knots = split_at(knots, bad[:n_bad])
    return True, knots, fit_knots, r, P, V, worst
