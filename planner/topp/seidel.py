"""toppra's seidel LP solver (``cy_solve_lp1d``, ``cy_solve_lp2d``) compiled with numba: its operations in its
order, its tolerances, its warm starts, so the controllable sets are toppra's bit for bit."""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

# rows whose u-coefficient is smaller than this are not a bound on u (toppra's seidel solver, TINY)
SEIDEL_TINY = 1e-10


# toppra's seidel solver: its tolerances and the bounds of its 1-D sub-problems
SEIDEL_SMALL = 1e-8
SEIDEL_INF = 1e10


@njit(cache=True)
def seidel_lp1d(
    v0: float, nrows: int, a: NDArray[np.float64], b: NDArray[np.float64], low: float, high: float
) -> tuple[bool, float, int]:
    """toppra's seidel ``cy_solve_lp1d``: max v0 x subject to a x + b <= 0 and low <= x <= high
    (rows with |a| <= TINY skipped); feasible, x and the index of the active row (-1, -2: a bound)."""
    cur_min, cur_max, active_min, active_max = low, high, -1, -2
    for i in range(nrows):
        if a[i] > SEIDEL_TINY:
            x = -b[i] / a[i]
            if x < cur_max:
                cur_max, active_max = x, i
        elif a[i] < -SEIDEL_TINY:
            x = -b[i] / a[i]
            if x > cur_min:
                cur_min, active_min = x, i
    if cur_min > cur_max:
        return False, math.nan, 0
    if abs(v0) < SEIDEL_TINY or v0 < 0:
        return True, cur_min, active_min
    return True, cur_max, active_max


@njit(cache=True)
def seidel_lp2d(
    v: NDArray[np.float64],
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    c: NDArray[np.float64],
    low: NDArray[np.float64],
    high: NDArray[np.float64],
    active: NDArray[np.int64],
    index_map: NDArray[np.int64],
    a_1d: NDArray[np.float64],
    b_1d: NDArray[np.float64],
) -> tuple[bool, float, float]:
    """toppra's seidel ``cy_solve_lp2d`` (Seidel's incremental 2-D LP), the same operations in the
    same order: max v . (u, x) subject to a u + b x + c <= 0 and the box [low, high], the rows
    ``active`` (the last solve's active pair, warm start) tried first. Feasible, u, x; ``active``
    is updated as toppra's solver wrapper updates it on success."""
    nrows = len(a)
    optvar = np.empty(2)
    act0, act1 = 0, 0
    for i in range(2):
        if low[i] > high[i]:
            return False, math.nan, math.nan
        if v[i] > SEIDEL_TINY:
            optvar[i] = high[i]
            if i == 0:
                act0 = -2
            else:
                act1 = -4
        else:
            optvar[i] = low[i]
            if i == 0:
                act0 = -1
            else:
                act1 = -3
    if 0 <= active[0] < nrows and 0 <= active[1] < nrows and active[0] != active[1]:
        index_map[0], index_map[1] = active[1], active[0]
        row = 2
        for i in range(nrows):
            if i != active[0] and i != active[1]:
                index_map[row] = i
                row += 1
    else:
        for i in range(nrows):
            index_map[i] = i
    for k in range(nrows):
        i = index_map[k]
        if a[i] * optvar[0] + b[i] * optvar[1] + c[i] < SEIDEL_TINY:
            continue
        act0 = i
        norm = a[i] * a[i] + b[i] * b[i]
        zero0 = -a[i] * c[i] / norm
        zero1 = -b[i] * c[i] / norm
        tan0, tan1 = -b[i], a[i]
        v_1d = tan0 * v[0] + tan1 * v[1]
        for j in range(k + 4):
            if j == k:
                aj, bj, cj = -1.0, 0.0, low[0]
            elif j == k + 1:
                aj, bj, cj = 1.0, 0.0, -high[0]
            elif j == k + 2:
                aj, bj, cj = 0.0, -1.0, low[1]
            elif j == k + 3:
                aj, bj, cj = 0.0, 1.0, -high[1]
            else:
                aj, bj, cj = a[index_map[j]], b[index_map[j]], c[index_map[j]]
            denom = tan0 * aj + tan1 * bj
            if denom > SEIDEL_TINY:
                a_1d[j], b_1d[j] = 1.0, (cj + zero1 * bj + zero0 * aj) / denom
            elif denom < -SEIDEL_TINY:
                a_1d[j], b_1d[j] = -1.0, -(cj + zero1 * bj + zero0 * aj) / denom
            else:
                if cj + zero1 * bj + zero0 * aj > SEIDEL_SMALL:
                    return False, math.nan, math.nan
                a_1d[j], b_1d[j] = 0.0, -1.0
        ok, t, act = seidel_lp1d(v_1d, k + 4, a_1d, b_1d, -SEIDEL_INF, SEIDEL_INF)
        if not ok:
            return False, math.nan, math.nan
        optvar[0] = zero0 + t * tan0
        optvar[1] = zero1 + t * tan1
        if 0 <= act < k:
            act1 = index_map[act]
        elif act == k:
            act1 = -1
        elif act == k + 1:
            act1 = -2
        elif act == k + 2:
            act1 = -3
        elif act == k + 3:
            act1 = -4
        else:  # a bound of the 1-D sub-problem: toppra's solver gives up
            return False, math.nan, math.nan
    active[0], active[1] = act0, act1
    return True, optvar[0], optvar[1]


@njit(cache=True)
def stage_x(
    highest: bool,
    rows: NDArray[np.float64],
    i: int,
    two_delta: float,
    lo: float,
    hi: float,
    low: NDArray[np.float64],
    high: NDArray[np.float64],
    active: NDArray[np.int64],
    index_map: NDArray[np.int64],
    a_1d: NDArray[np.float64],
    b_1d: NDArray[np.float64],
) -> float:
    """The largest (lowest) x at stage i from which some u lands x + two_delta u in [lo, hi]: toppra's
    ``solve_stagewise_optim`` for g = (1e-9, -1) (its lower solver) or (-1e-9, 1) (its upper one),
    ``rows`` (3, n, m + 2) the stage's rows after the two of the next set; NaN where it gives up."""
    a, b, c = rows[0, i], rows[1, i], rows[2, i]
    a[0], b[0], c[0] = -two_delta, -1.0, lo
    a[1], b[1], c[1] = two_delta, 1.0, -hi
    v = np.array([-1e-9, 1.0]) if highest else np.array([1e-9, -1.0])
    ok, _u, x = seidel_lp2d(v, a, b, c, low, high, active, index_map, a_1d, b_1d)
    return x if ok else math.nan
