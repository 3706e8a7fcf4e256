"""One round of steps 3-4 of knot placement compiled with numba (``planner.knots.quantize.quantize_checked``):
the knots' positions and velocities rounded to the drive's integers, their exact check, and the
integer repair of the records around every segment over a limit, checked again, in one call.

The pieces are the other kernels' (``check_kernels.check_segments``, ``quantize_kernels.repair_chains``):
this loop only strings them together, so that a round of a placement is one call from Python,
not a dozen numpy calls on a few hundred numbers.

Layout (as in ``planner.knots.flat.Flat``): all EPOS2 axes' plan samples end to end, axis
``a``'s ms ``j`` at flat index ``a * stride + j``; ``knots`` are sorted flat indices. Units are
the drive's: qc, velocity units (``f`` qc/ms each), ms.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import LIMIT_RTOL
from pvtflow.axes.drive.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN
from pvtflow.planner.knots.check_kernels import check_segments
from pvtflow.planner.knots.quantize_kernels import repair_chains_memo

_F = NDArray[np.float64]
_I = NDArray[np.int64]
_B = NDArray[np.bool_]

POSITION_RANGE, VELOCITY_RANGE = 1, 2  # what ``round_check_repair`` could not round (its first return)
_OVER = 1.0 * (1.0 + LIMIT_RTOL)  # axes.drive.interpolation.exceeds(ratio, 1.0)


@njit(cache=True)
def _over(rv: _F, ra: _F) -> _I:
    """The segments whose exact |a| or |v| ratio exceeds 1 (``planner.knots.check.over_limit``)."""
    n = 0
    idx = np.empty(len(rv), dtype=np.int64)
    for k in range(len(rv)):
        if ra[k] > _OVER or rv[k] > _OVER:
            idx[n] = k
            n += 1
    return idx[:n]


@njit(cache=True)
def round_check_repair(
    knots: _I,
    p_fit: _F,
    v_fit: _F,
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
    reach: int,
    repairs: int,
    prev_knots: _I,
    prev_P: _I,
    prev_V: _I,
    prev_dev: _F,
    prev_rv: _F,
    prev_ra: _F,
    prev_out: _B,
    memo_at: _I,
    memo_rows: _I,
) -> tuple[int, int, _I, _I, _I, _I, _F, _F, _F, _B, _I, _I]:
    """Round (positions to counts inside 0x607D, velocities to units inside 0x607F, each axis's
    ends at rest), check (reusing the verdicts of ``prev_*``), then up to ``repairs`` times: repair
    the records within ``reach`` knots of the segments over a limit and check again.

    Returns (0 or what did not fit a record: ``POSITION_RANGE``, ``VELOCITY_RANGE``, the first knot
    that did not), the records P, V, the records the check judged (they differ from P, V only
    where a repair moved nothing) and the check: per segment deviation, |v| and |a| ratios,
    whether it leaves 0x607D."""
    nk = len(knots)
    P = np.empty(nk, dtype=np.int64)
    V = np.empty(nk, dtype=np.int64)
    for k in range(nk):
        r = np.rint(p_fit[k])
        if r < INT32_MIN or r > INT32_MAX:
            return POSITION_RANGE, k, P, V, P, V, prev_dev, prev_rv, prev_ra, prev_out, memo_at, memo_rows
    for k in range(nk):
        a = knots[k] // stride
        P[k] = np.int64(min(max(np.rint(p_fit[k]), pos_lo[a]), pos_hi[a]))
    for k in range(nk):
        a = knots[k] // stride
        u = min(max(np.rint(v_fit[k] / f[a]), -v_units[a]), v_units[a])
        if u < INT24_MIN or u > INT24_MAX:
            return VELOCITY_RANGE, k, P, V, P, V, prev_dev, prev_rv, prev_ra, prev_out, memo_at, memo_rows
        m = knots[k] % stride
        V[k] = 0 if m == 0 or m == stride - 1 else np.int64(u)
    dev, rv, ra, out = check_segments(
        knots,
        P,
        V,
        stride,
        f,
        rv_per,
        ra_per,
        pos_lo,
        pos_hi,
        plan,
        prev_knots,
        prev_P,
        prev_V,
        prev_dev,
        prev_rv,
        prev_ra,
        prev_out,
    )
    cP, cV = P, V
    used = np.zeros(len(memo_at) - 1, dtype=np.bool_)
    for _ in range(repairs):
        segments = _over(rv, ra)
        if not len(segments):
            break
        P, V = P.copy(), V.copy()
        moved, memo_at, memo_rows, used = repair_chains_memo(
            knots, P, V, segments, reach, stride, f, rv_per, ra_per, pos_lo, pos_hi, v_units, plan, plan_v, tol,
            memo_at, memo_rows, used,
        )  # fmt: skip
        if not moved:
            break
        dev, rv, ra, out = check_segments(
            knots, P, V, stride, f, rv_per, ra_per, pos_lo, pos_hi, plan, knots, cP, cV, dev, rv, ra, out
        )
        cP, cV = P, V
    kept_at, kept_rows = _memo_used(memo_at, memo_rows, used)
    return 0, 0, P, V, cP, cV, dev, rv, ra, out, kept_at, kept_rows


@njit(cache=True)
def _memo_used(at: _I, rows: _I, used: _B) -> tuple[_I, _I]:
    """The entries of a chain memo that ``used`` marks (the next round's memo)."""
    n_rows = 0
    for e in range(len(used)):
        if used[e]:
            n_rows += at[e + 1] - at[e]
    kept_at = np.zeros(int(used.sum()) + 1, dtype=np.int64)
    kept_rows = np.empty((n_rows, rows.shape[1]), dtype=np.int64)
    n, r = 0, 0
    for e in range(len(used)):
        if used[e]:
            m = at[e + 1] - at[e]
            kept_rows[r : r + m] = rows[at[e] : at[e + 1]]
            r += m
            n += 1
            kept_at[n] = r
    return kept_at, kept_rows


@njit(cache=True)
def split_verdict(
    knots: _I,
    stride: int,
    dev: _F,
    out: _B,
    rv: _F,
    ra: _F,
    tol: float,
    jerk_stuck: _I,
    last_stuck: _I,
    min_split: int,
) -> tuple[_I, _I, _B]:
    """What a checked round splits (``planner.knots.epos2.place_epos2``): the segments of 2 ms or
    more that stray from the plan or leave 0x607D, and those over a limit (or in ``jerk_stuck``,
    the window jerk's) of at least ``min_split`` ms on an axis that has not given up. An axis gives
    up where it strays nowhere and its segments over a limit are no fewer than ``last_stuck`` (per
    axis). Returns the segments to split (sorted), and per axis its segments over a limit and
    whether it strays."""
    nseg = len(knots) - 1
    n_axes = len(last_stuck)
    stuck = np.zeros(nseg, dtype=np.bool_)
    for k in range(nseg):
        stuck[k] = ra[k] > _OVER or rv[k] > _OVER
    for s in jerk_stuck:
        stuck[s] = True
    n_stuck = np.zeros(n_axes, dtype=np.int64)
    strays = np.zeros(n_axes, dtype=np.bool_)
    bad = np.zeros(nseg, dtype=np.bool_)
    for k in range(nseg):
        a = knots[k] // stride
        if (dev[k] > tol or out[k]) and knots[k + 1] - knots[k] >= 2:
            bad[k] = True
            strays[a] = True
        if stuck[k]:
            n_stuck[a] += 1
    n_split = 0
    split = np.empty(nseg, dtype=np.int64)
    for k in range(nseg):
        a = knots[k] // stride
        give_up = n_stuck[a] > 0 and not strays[a] and n_stuck[a] >= last_stuck[a]
        if bad[k] or (stuck[k] and not give_up and knots[k + 1] - knots[k] >= min_split):
            split[n_split] = k
            n_split += 1
    return split[:n_split], n_stuck, strays
