"""TOPP-RA's two passes over the stacked rows, each one compiled loop: the backward pass (controllable sets,
LPs skipped where the answer is known in closed form) and the greedy forward pass."""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray
from toppra.constants import MAX_TRIES, TINY

from pvtflow.planner.topp.seidel import SEIDEL_TINY, stage_x


@njit(cache=True)
def forward_pass(
    A: NDArray[np.float64],
    B: NDArray[np.float64],
    C: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    x_lo: NDArray[np.float64],
    x_hi: NDArray[np.float64],
    K: NDArray[np.float64],
    two_delta: NDArray[np.float64],
    x_start: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """toppra's greedy forward pass: at every stage the largest u whose x + 2 delta u lands in the
    next controllable set. With x fixed, the stage's LP has one variable, and it is solved as
    toppra's seidel wrapper solves it then (its 1-D LP: the tightest row above and below, rows with
    |a| <= TINY skipped, infeasible when they cross); same safeguards (back off x by TINY or 0.1 %,
    at most MAX_TRIES times, when a stage is infeasible from round-off). Returns u per stage and x
    per gridpoint (NaN from where it gave up)."""
    n = len(two_delta)
    us, xs = np.zeros(n), np.full(n + 1, np.nan)
    xs[0] = x_start
    i, tries, x = 0, 0, x_start
    while i < n:
        k_lo, k_hi = K[i + 1, 0], K[i + 1, 1]
        lo, hi = u_lo[i], u_hi[i]
        for j in range(A.shape[1]):
            a = A[i, j]
            if a > SEIDEL_TINY:
                hi = min(hi, -(B[i, j] * x + C[i, j]) / a)
            elif a < -SEIDEL_TINY:
                lo = max(lo, -(B[i, j] * x + C[i, j]) / a)
        hi = min(hi, (k_hi - x) / two_delta[i])
        lo = max(lo, (k_lo - x) / two_delta[i])
        if lo > hi or x < x_lo[i] or x > x_hi[i]:  # slightly infeasible from round-off: back off x a little
            if tries >= MAX_TRIES:
                return us, xs
            x = max(x - TINY, 0.999 * x)
            xs[i] = x
            tries += 1
            continue
        tries = 0
        us[i] = hi
        x_next = x + two_delta[i] * hi
        x_next = max(x_next - TINY, 0.9999 * x_next)
        x = min(k_hi, max(k_lo, x_next))
        xs[i + 1] = x
        i += 1
    return us, xs


@njit(cache=True)
def known_stages(
    i: int,
    lo: float,
    hi: float,
    x_top: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    rest: NDArray[np.bool_],
    two_delta: NDArray[np.float64],
    K: NDArray[np.float64],
) -> tuple[int, float, float]:
    """The backward pass from stage ``i`` down (next set [lo, hi]) over the stages whose controllable
    set needs no LP: its upper end is x_top (some allowed u there lands in the next set) and its
    lower end 0 (standing still is allowed and 0 is in the next set). Writes them into ``K`` and
    returns the first stage that needs more (-1: none left) with the set after it. The same float
    operations as ``LeanTOPPRA.compute_controllable_sets`` (Python's max and min included)."""
    while i >= 0:
        x = x_top[i]
        if x != x or not (lo == 0.0 and rest[i]):
            return i, lo, hi
        y = (lo - x) / two_delta[i]
        first = y if y > u_lo[i] else u_lo[i]
        z = (hi - x) / two_delta[i]
        if not first + 1e-9 * (1.0 + abs(first)) <= (z if z < u_hi[i] else u_hi[i]):
            return i, lo, hi
        lo, hi = 0.0, x
        K[i, 0], K[i, 1] = lo, hi
        i -= 1
    return i, lo, hi


# what ``backward_pass`` stopped for
DONE, NO_STATE, HIGHEST_LP, LOWEST_LP = 0, 1, 2, 3


@njit(cache=True)
def backward_pass(
    rows: NDArray[np.float64],
    boxes: NDArray[np.float64],
    x_top: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    rest: NDArray[np.bool_],
    two_delta: NDArray[np.float64],
    K: NDArray[np.float64],
    i: int,
    lo: float,
    hi: float,
    given_x_hi: bool,
    x_hi: float,
    active_up: NDArray[np.int64],
    active_down: NDArray[np.int64],
) -> tuple[int, float, float, int, float]:
    """``LeanTOPPRA.compute_controllable_sets`` from stage i down (next set [lo, hi]), toppra's
    seidel LPs where the answer is not known in closed form. Stops at the first stage whose LP the
    seidel solver gives up on although it may be feasible (``HIGHEST_LP``: x_hi; ``LOWEST_LP``:
    x_lo, returned with x_hi), for ``StageRows.x_extreme``; ``given_x_hi``: stage i resumes with
    that x_hi. Returns the stage, the next set, why it stopped and x_hi."""
    m = rows.shape[2]
    index_map = np.zeros(m, dtype=np.int64)
    a_1d, b_1d = np.zeros(m + 4), np.zeros(m + 4)
    low, high = np.empty(2), np.empty(2)
    while True:
        if not given_x_hi:
            i, lo, hi = known_stages(i, lo, hi, x_top, u_lo, u_hi, rest, two_delta, K)
            if i < 0:
                return i, lo, hi, DONE, math.nan
        low[0], low[1], high[0], high[1] = boxes[0, i], boxes[1, i], boxes[2, i], boxes[3, i]
        if not given_x_hi:
            # a u feasible at x_top[i] that lands in [lo, hi]: x_top[i] is the LP's maximum
            x = x_top[i]
            y = (lo - x) / two_delta[i]
            first = y if y > u_lo[i] else u_lo[i]
            z = (hi - x) / two_delta[i]
            if first + 1e-9 * (1.0 + abs(first)) <= (z if z < u_hi[i] else u_hi[i]):
                x_hi = x
            else:
                x_hi = stage_x(True, rows, i, two_delta[i], lo, hi, low, high, active_down, index_map, a_1d, b_1d)
                if x_hi != x_hi:
                    return i, lo, hi, HIGHEST_LP, x_hi
        given_x_hi = False
        # standing still is allowed here and 0 is in [lo, hi]: the minimum is 0
        if lo == 0.0 and rest[i]:
            x_lo = 0.0
        else:
            x_lo = stage_x(False, rows, i, two_delta[i], lo, hi, low, high, active_up, index_map, a_1d, b_1d)
        if x_lo != x_lo and x_hi == x_hi:
            return i, lo, hi, LOWEST_LP, x_hi
        lo, hi = (0.0 if x_lo < 0.0 else x_lo), x_hi
        if lo != lo or hi != hi:  # NaN: no controllable state at this stage (K stays NaN there)
            return i, lo, hi, NO_STATE, x_hi
        K[i, 0], K[i, 1] = lo, hi
        i -= 1
