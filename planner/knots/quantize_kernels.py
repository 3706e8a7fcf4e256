"""Step 3 of knot placement compiled with numba (``planner.knots.quantize``): the integer repair.

Where rounding pushes a cubic over a limit, the records of a run are nudged together (each by a
count and two velocity units, and with ``shift`` its knot by a ms) and the best combination is
found exactly, as a shortest path over the candidates: integers need an integer search.

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
    cubic_peak_acceleration,
    cubic_peak_speed,
    hermite,
)
from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.knots.check_kernels import leaves, probe_deviation

_F = NDArray[np.float64]
_I = NDArray[np.int64]


# A record may move by up to _DP counts and _DV velocity units off its rounding: nudge e of a record
# moves it by nudge_dp(e) counts and nudge_dv(e) units (nudge 0 moves nothing).
_DP, _DV = 1, 2
N_NUDGES = (2 * _DP + 1) * (2 * _DV + 1)
_PROBES = np.array([0.25, 0.5, 0.75])  # where inside a segment the deviation of a nudge is judged
EXCESS_WEIGHT = 1e6  # a ratio excess of 1e-5 outweighs a chain's deviations (counts): excess first


@njit(cache=True)
def nudge_dp(e: int) -> int:
    e = (e + _DP * (2 * _DV + 1) + _DV) % N_NUDGES  # nudge 0 first: the record as it is
    return e // (2 * _DV + 1) - _DP


@njit(cache=True)
def nudge_dv(e: int) -> int:
    e = (e + _DP * (2 * _DV + 1) + _DV) % N_NUDGES
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
    dev = max(dev, probe_deviation(c0, c1, c2, c3, T, k0, plan, _PROBES))
    if dev > tol:
        return np.inf, dev
    if leaves(c0, c1, c2, c3, T, p1, v1, pos_lo, pos_hi):
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
    n = (2 * shift + 1) * N_NUDGES
    t, p, v = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    c = 0
    for ds in range(-shift, shift + 1):
        tk = knots[k] + (0 if ds == 0 else ds)
        if ds == 0:
            p0, v0 = P[k], V[k]
        else:
            p0 = int(np.rint(plan[tk]))
            v0 = int(min(max(np.rint(plan_v[tk] / f), -v_units), v_units))
        for e in range(N_NUDGES):
            t[c], p[c], v[c] = tk, p0 + nudge_dp(e), v0 + nudge_dv(e)
            c += 1
    if shift:  # the record as it is first
        t[0], t[shift * N_NUDGES] = t[shift * N_NUDGES], t[0]
        p[0], p[shift * N_NUDGES] = p[shift * N_NUDGES], p[0]
        v[0], v[shift * N_NUDGES] = v[shift * N_NUDGES], v[0]
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
    nc = (2 * shift + 1) * N_NUDGES
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
                cost = S[e0] + EXCESS_WEIGHT * max(r - 1.0, 0.0) + D[j, e0, e1]
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
def free_chains(knots: _I, segments: _I, reach: int, shift: int, stride: int) -> _I:
    """The chains ``repair_chains`` repairs, (n, 2): the first and last knot of each run of knots
    within ``reach`` of a segment of ``segments`` on its axis, none at an axis end (never moved)
    nor, with ``shift``, next to one."""
    nk = len(knots)
    free = np.zeros(nk, dtype=np.bool_)
    for s in segments:
        a = knots[s] // stride
        for k in range(max(s - reach + 1, 0), min(s + reach, nk - 1) + 1):
            r = knots[k] - a * stride
            if shift < r < stride - 1 - shift:
                free[k] = True
    out = np.empty((nk, 2), dtype=np.int64)
    n = 0
    k = 0
    while k < nk:
        if not free[k]:
            k += 1
            continue
        out[n, 0] = k
        while k + 1 < nk and free[k + 1]:
            k += 1
        out[n, 1] = k
        n += 1
        k += 1
    return out[:n]


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
    chain (``free_chains``), repaired as a whole (``_repair_chain``). Whether any record moved."""
    moved = False
    for c in free_chains(knots, segments, reach, shift, stride):
        a = knots[c[0]] // stride
        moved |= _repair_chain(
            knots, P, V, c[0], c[1], shift, stride, f[a], rv_per[a], ra_per[a], pos_lo[a], pos_hi[a], v_units[a],
            plan, plan_v, tol,
        )  # fmt: skip
    return moved


NO_MEMO_AT = np.zeros(1, dtype=np.int64)  # a memo of no chain (``repair_chains_memo``)
NO_MEMO_ROWS = np.zeros((0, 5), dtype=np.int64)


@njit(cache=True)
def _memo_find(at: _I, rows: _I, n: int, knots: _I, P: _I, V: _I, i0: int, i1: int) -> int:
    """The entry of the memo whose chain had the records of knots i0 - 1 .. i1 + 1 (times,
    counts, velocity units), or -1."""
    m = i1 - i0 + 3
    for e in range(n):
        if at[e + 1] - at[e] != m or rows[at[e], 0] != knots[i0 - 1]:
            continue
        same = True
        for r in range(m):
            k, row = i0 - 1 + r, at[e] + r
            if rows[row, 0] != knots[k] or rows[row, 1] != P[k] or rows[row, 2] != V[k]:
                same = False
                break
        if same:
            return e
    return -1


@njit(cache=True)
def repair_chains_memo(
    knots: _I,
    P: _I,
    V: _I,
    segments: _I,
    reach: int,
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
    memo_at: _I,
    memo_rows: _I,
    used: NDArray[np.bool_],
) -> tuple[bool, _I, _I, NDArray[np.bool_]]:
    """``repair_chains`` without ``shift``, with a memo of the chains repaired before on the same
    plan: a chain's repair reads only the records of its knots and of the fixed knot on either
    side (and the plan, the axis's constants, the tolerance), so a chain whose records are those
    of a memo entry gets that entry's records, without the search. ``memo_at`` (entries + 1): each
    entry's first row in ``memo_rows`` (time, count, velocity units before; count, velocity
    units after); ``used``: per entry, whether this placement round used it. Returns whether any
    record moved and the memo with this call's chains added."""
    moved = False
    for c in free_chains(knots, segments, reach, 0, stride):
        i0, i1 = c[0], c[1]
        n = len(memo_at) - 1
        e = _memo_find(memo_at, memo_rows, n, knots, P, V, i0, i1)
        if e < 0:
            m = i1 - i0 + 3
            rows = np.empty((len(memo_rows) + m, 5), dtype=np.int64)
            rows[: len(memo_rows)] = memo_rows
            for r in range(m):
                k = i0 - 1 + r
                rows[len(memo_rows) + r, 0], rows[len(memo_rows) + r, 1] = knots[k], P[k]
                rows[len(memo_rows) + r, 2] = V[k]
            a = knots[i0] // stride
            _repair_chain(
                knots, P, V, i0, i1, 0, stride, f[a], rv_per[a], ra_per[a], pos_lo[a], pos_hi[a], v_units[a],
                plan, plan_v, tol,
            )  # fmt: skip
            for r in range(m):
                rows[len(memo_rows) + r, 3], rows[len(memo_rows) + r, 4] = P[i0 - 1 + r], V[i0 - 1 + r]
            at = np.empty(n + 2, dtype=np.int64)
            at[: n + 1] = memo_at
            at[n + 1] = len(rows)
            u = np.empty(n + 1, dtype=np.bool_)
            u[:n] = used
            memo_at, memo_rows, used, e = at, rows, u, n
        else:
            for r in range(1, i1 - i0 + 2):
                P[i0 - 1 + r], V[i0 - 1 + r] = memo_rows[memo_at[e] + r, 3], memo_rows[memo_at[e] + r, 4]
        used[e] = True
        for row in range(memo_at[e], memo_at[e + 1]):
            moved |= memo_rows[row, 1] != memo_rows[row, 3] or memo_rows[row, 2] != memo_rows[row, 4]
    return moved, memo_at, memo_rows, used
