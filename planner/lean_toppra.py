"""toppra's TOPP-RA algorithm with its per-stage bookkeeping done once up front (``LeanTOPPRA``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import toppra.algorithm as algo
import toppra.constraint as constraint
from numba import njit
from numpy.typing import NDArray
from scipy.optimize import linprog
from toppra.algorithm.algorithm import ParameterizationData
from toppra.constants import MAX_TRIES, SMALL, TINY
from toppra.parametrizer import ParametrizeSpline
from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

from pvtflow.planner.path import JointPath


class _Computed(constraint.LinearConstraint):
    """A constraint's parameters on one grid, computed once: the solver wrapper and the rest check
    of LeanTOPPRA both read them."""

    def __init__(self, source: constraint.Constraint, params: tuple) -> None:
        super().__init__()
        self.identical = source.identical
        self.params = params

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        return self.params


# the solver wrapper's box on u and x at every stage (toppra's seidel VAR_MIN / VAR_MAX)
_VAR_MAX = 1e8


def _times(F: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """F v at every stage: F the same at every stage (2-D) or one per stage (3-D)."""
    return v @ F.T if F.ndim == 2 else np.einsum("ikj,ij->ik", F, v)


@njit(cache=True)
def _stage_rows(
    F: NDArray[np.float64],
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    c: NDArray[np.float64],
    h: NDArray[np.float64],
    A: NDArray[np.float64],
    B: NDArray[np.float64],
    C: NDArray[np.float64],
    col: int,
) -> None:
    """F a, F b and F c - h at every stage into columns ``col`` on of A, B, C, the zeros of F
    skipped: pvtflow's F are identities and [I; -I] (one product per row, not a matrix product)."""
    k, m = F.shape
    count, where = np.zeros(k, dtype=np.int64), np.empty((k, m), dtype=np.int64)
    for j in range(k):
        for p in range(m):
            if F[j, p] != 0.0:
                where[j, count[j]] = p
                count[j] += 1
    for i in range(a.shape[0]):
        for j in range(k):
            ra, rb, rc = 0.0, 0.0, 0.0
            for e in range(count[j]):
                p = where[j, e]
                f = F[j, p]
                ra += f * a[i, p]
                rb += f * b[i, p]
                rc += f * c[i, p]
            A[i, col + j], B[i, col + j], C[i, col + j] = ra, rb, rc - h[j]


@dataclass(frozen=True)
class _StageRows:
    """Every stage's rows A u + B x + C <= 0 (all constraints stacked, as the solver wrapper does)
    and its boxes on x and u, (n, m) and (n,) arrays: what the LP skips of LeanTOPPRA read."""

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    x_lo: NDArray[np.float64]
    x_hi: NDArray[np.float64]
    u_lo: NDArray[np.float64]
    u_hi: NDArray[np.float64]

    @classmethod
    def stack(cls, params: list[tuple], n: int) -> _StageRows:
        x_lo, x_hi = np.full(n, -_VAR_MAX), np.full(n, _VAR_MAX)
        u_lo, u_hi = np.full(n, -_VAR_MAX), np.full(n, _VAR_MAX)
        m = sum(p[3].shape[-2] for p in params if p[0] is not None)
        A, B, C = np.empty((n, m)), np.empty((n, m)), np.empty((n, m))
        col = 0
        for a, b, c, F, h, ubound, xbound in params:
            if a is not None:
                k = F.shape[-2]
                if F.ndim == 2 and np.ndim(h) == 1:  # pvtflow's constraints: one F for every stage
                    _stage_rows(F, a, b, c, h, A, B, C, col)
                else:
                    A[:, col : col + k], B[:, col : col + k] = _times(F, a), _times(F, b)
                    C[:, col : col + k] = _times(F, c) - h
                col += k
            if xbound is not None:
                x_lo, x_hi = np.maximum(x_lo, xbound[:, 0]), np.minimum(x_hi, xbound[:, 1])
            if ubound is not None:
                u_lo, u_hi = np.maximum(u_lo, ubound[:, 0]), np.minimum(u_hi, ubound[:, 1])
        return cls(A, B, C, x_lo, x_hi, u_lo, u_hi)

    def rest_feasible(self) -> NDArray[np.bool_]:
        """Stages at which (u, x) = (0, 0), standing still, satisfies every row and box."""
        return np.all(self.C <= 0.0, axis=1) & (self.x_lo <= 0.0) & (self.u_lo <= 0.0) & (self.u_hi >= 0.0)

    def x_extreme(self, i: int, two_delta: float, lo: float, hi: float, highest: bool) -> float:
        """The largest (lowest) x at stage i from which some u satisfies every row and box and
        lands x + two_delta u in [lo, hi]; NaN where none does. HiGHS, for the rare stage whose LP
        toppra's seidel solver gives up on although it is feasible: next to a point where the path
        stops (q' = 0 at a waypoint in a corner of the joint box, or where it reverses), the rows
        there span u from 1e-16 to 1e4 and the seidel solver returns NaN, stock toppra's too."""
        rows = np.column_stack((self.A[i], self.B[i]))
        a_ub = np.vstack((rows, [[two_delta, 1.0], [-two_delta, -1.0]]))
        b_ub = np.concatenate((-self.C[i], [hi, -lo]))
        bounds = [(self.u_lo[i], self.u_hi[i]), (max(self.x_lo[i], 0.0), self.x_hi[i])]
        res = linprog([0.0, -1.0 if highest else 1.0], A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
        return float(res.x[1]) if res.status == 0 else math.nan

    def u_range_at(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The exact range [lo, hi] of u that satisfies every row and box at x (one x per stage;
        lo = inf where none does)."""
        return _u_range(self.A, self.B, self.C, self.u_lo, self.u_hi, self.x_lo, self.x_hi, x)


@njit(cache=True)
def _nan_min(a: float, b: float) -> float:
    """numpy's minimum: NaN if either is."""
    return a if a != a or a < b else b


@njit(cache=True)
def _nan_max(a: float, b: float) -> float:
    """numpy's maximum: NaN if either is."""
    return a if a != a or a > b else b


@njit(cache=True)
def _u_range(
    A: NDArray[np.float64],
    B: NDArray[np.float64],
    C: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    x_lo: NDArray[np.float64],
    x_hi: NDArray[np.float64],
    x: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``_StageRows.u_range_at`` in one pass over the rows: each row's bound -(B x + C) / A on u
    where A is not 0 (an upper bound where A > 0, a lower where A < 0); a row with A = 0 that
    B x + C > 0 breaks, or x outside its box, leaves no u (lo = inf)."""
    n, m = A.shape
    lo, hi = np.empty(n), np.empty(n)
    for i in range(n):
        top, bottom, broken = np.inf, -np.inf, False
        for k in range(m):
            r = B[i, k] * x[i] + C[i, k]
            a = A[i, k]
            if a > 0.0:
                top = _nan_min(top, -r / a)
            elif a < 0.0:
                bottom = _nan_max(bottom, -r / a)
            elif a == 0.0 and r > 0.0:
                broken = True
        hi[i] = _nan_min(u_hi[i], top)
        lo[i] = np.inf if broken or x[i] < x_lo[i] or x[i] > x_hi[i] else _nan_max(u_lo[i], bottom)
    return lo, hi


# rows whose u-coefficient is smaller than this are not a bound on u (toppra's seidel solver, TINY)
_SEIDEL_TINY = 1e-10


@njit(cache=True)
def _forward_pass(
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
            if a > _SEIDEL_TINY:
                hi = min(hi, -(B[i, j] * x + C[i, j]) / a)
            elif a < -_SEIDEL_TINY:
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
def _known_stages(
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


# toppra's seidel solver: its tolerances and the bounds of its 1-D sub-problems
_SEIDEL_SMALL = 1e-8
_SEIDEL_INF = 1e10


@njit(cache=True)
def _seidel_lp1d(
    v0: float, nrows: int, a: NDArray[np.float64], b: NDArray[np.float64], low: float, high: float
) -> tuple[bool, float, int]:
    """toppra's seidel ``cy_solve_lp1d``: max v0 x subject to a x + b <= 0 and low <= x <= high
    (rows with |a| <= TINY skipped); feasible, x and the index of the active row (-1, -2: a bound)."""
    cur_min, cur_max, active_min, active_max = low, high, -1, -2
    for i in range(nrows):
        if a[i] > _SEIDEL_TINY:
            x = -b[i] / a[i]
            if x < cur_max:
                cur_max, active_max = x, i
        elif a[i] < -_SEIDEL_TINY:
            x = -b[i] / a[i]
            if x > cur_min:
                cur_min, active_min = x, i
    if cur_min > cur_max:
        return False, math.nan, 0
    if abs(v0) < _SEIDEL_TINY or v0 < 0:
        return True, cur_min, active_min
    return True, cur_max, active_max


@njit(cache=True)
def _seidel_lp2d(
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
        if v[i] > _SEIDEL_TINY:
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
        if a[i] * optvar[0] + b[i] * optvar[1] + c[i] < _SEIDEL_TINY:
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
            if denom > _SEIDEL_TINY:
                a_1d[j], b_1d[j] = 1.0, (cj + zero1 * bj + zero0 * aj) / denom
            elif denom < -_SEIDEL_TINY:
                a_1d[j], b_1d[j] = -1.0, -(cj + zero1 * bj + zero0 * aj) / denom
            else:
                if cj + zero1 * bj + zero0 * aj > _SEIDEL_SMALL:
                    return False, math.nan, math.nan
                a_1d[j], b_1d[j] = 0.0, -1.0
        ok, t, act = _seidel_lp1d(v_1d, k + 4, a_1d, b_1d, -_SEIDEL_INF, _SEIDEL_INF)
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
def _stage_x(
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
    ok, _u, x = _seidel_lp2d(v, a, b, c, low, high, active, index_map, a_1d, b_1d)
    return x if ok else math.nan


# what ``_backward_pass`` stopped for
_DONE, _NO_STATE, _HIGHEST_LP, _LOWEST_LP = 0, 1, 2, 3


@njit(cache=True)
def _backward_pass(
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
    seidel solver gives up on although it may be feasible (``_HIGHEST_LP``: x_hi; ``_LOWEST_LP``:
    x_lo, returned with x_hi), for ``_StageRows.x_extreme``; ``given_x_hi``: stage i resumes with
    that x_hi. Returns the stage, the next set, why it stopped and x_hi."""
    m = rows.shape[2]
    index_map = np.zeros(m, dtype=np.int64)
    a_1d, b_1d = np.zeros(m + 4), np.zeros(m + 4)
    low, high = np.empty(2), np.empty(2)
    while True:
        if not given_x_hi:
            i, lo, hi = _known_stages(i, lo, hi, x_top, u_lo, u_hi, rest, two_delta, K)
            if i < 0:
                return i, lo, hi, _DONE, math.nan
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
                x_hi = _stage_x(True, rows, i, two_delta[i], lo, hi, low, high, active_down, index_map, a_1d, b_1d)
                if x_hi != x_hi:
                    return i, lo, hi, _HIGHEST_LP, x_hi
        given_x_hi = False
        # standing still is allowed here and 0 is in [lo, hi]: the minimum is 0
        if lo == 0.0 and rest[i]:
            x_lo = 0.0
        else:
            x_lo = _stage_x(False, rows, i, two_delta[i], lo, hi, low, high, active_up, index_map, a_1d, b_1d)
        if x_lo != x_lo and x_hi == x_hi:
            return i, lo, hi, _LOWEST_LP, x_hi
        lo, hi = (0.0 if x_lo < 0.0 else x_lo), x_hi
        if lo != lo or hi != hi:  # NaN: no controllable state at this stage (K stays NaN there)
            return i, lo, hi, _NO_STATE, x_hi
        K[i, 0], K[i, 1] = lo, hi
        i -= 1


class LeanTOPPRA(algo.TOPPRA):
    """toppra's TOPPRA, with the per-stage bookkeeping of its two passes done once up front.

    Same algorithm, same LPs, same results: the backward pass (controllable sets) is one compiled
    loop (``_backward_pass``) that solves each stage's 2-D LP as toppra's seidel solver does
    (``_seidel_lp2d``: its operations in its order, its warm starts; the same controllable sets,
    bit for bit, as the Cython solver on 400 arm6 and gantry3 solves of 20 to 300 gridpoints,
    tests/planner/test_timing.py), without building toppra's solver wrapper (a Python loop over
    every stage's rows) or calling it stage by stage, which is where most of the time of a
    coarse-grid solve goes. The forward pass fixes x at every stage, so its LP has one variable: it is solved
    in one compiled loop by the rule toppra's seidel wrapper applies to it (``_forward_pass``; the
    same u, bit for bit, on 70,000 stages of arm6 and gantry3 plans). LPs of the backward pass are
    skipped where their answer is known exactly (checked in closed form, with every stage's rows
    stacked once up front):

    - the lower end of a controllable set is 0 wherever standing still is allowed and leads into
      a set that contains 0 (a rest-to-rest move: almost every stage);
    - its upper end is the stage's own bound x_top (speed limits) wherever some u allowed at
      x_top leads into the next set (cruising at a speed limit: most stages);
    """

    def __init__(
        self, constraint_list: list[constraint.Constraint], path: JointPath, gridpoints: NDArray[np.float64]
    ) -> None:
        # toppra's ReachabilityAlgorithm.__init__ would first probe the importable solvers (a
        # file-system search on every plan) and build its solver wrapper; the LPs here are
        # toppra's seidel solver's, compiled (``_seidel_lp2d``), on the rows stacked once
        # (and ParameterizationAlgorithm.__init__ checks the grid gridpoint by gridpoint in Python)
        self.constraints = constraint_list
        self.path = path
        self._problem_data = ParameterizationData()
        grid = np.array(gridpoints, dtype=float)
        if path.path_interval[0] != grid[0] or path.path_interval[1] != grid[-1]:
            raise ValueError("Invalid manually supplied gridpoints.")
        if np.any(grid[1:] <= grid[:-1]):
            raise ValueError("Bad input gridpoints.")
        self.gridpoints, self._problem_data.gridpoints, self._N = grid, grid.copy(), len(grid) - 1
        self.parametrizer = ParametrizeSpline
        self._params = [c.compute_constraint_params(self.path, self.gridpoints) for c in self.constraints]
        rows = self._rows = _StageRows.stack(self._params, len(self.gridpoints))
        self._rest = rows.rest_feasible()
        self._x_top = rows.x_hi
        self._u_top = rows.u_range_at(rows.x_hi)
        self._two_delta = 2.0 * np.diff(self.gridpoints)
        # the seidel solver's warm starts (its upper and lower solver's last active rows)
        self._active_up, self._active_down = np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.int64)
        self._seidel: seidelWrapper | None = None

    @property
    def solver_wrapper(self) -> seidelWrapper:
        """toppra's seidel solver wrapper on the same rows, for toppra's own methods (the passes
        here do not use it)."""
        if self._seidel is None:
            computed = [_Computed(c, p) for c, p in zip(self.constraints, self._params, strict=True)]
            self._seidel = seidelWrapper(computed, self.path, self.gridpoints, solve_lp1d=True)
        return self._seidel

    def compute_controllable_sets(self, sdmin: float, sdmax: float) -> NDArray[np.float64]:
        n = self._N
        K = np.full((n + 1, 2), np.nan)
        K[n] = (sdmin**2, sdmax**2)
        r = self._rows
        m = r.A.shape[1]
        stage_rows = np.zeros((3, n + 1, m + 2))
        stage_rows[0, :, 2:], stage_rows[1, :, 2:], stage_rows[2, :, 2:] = r.A, r.B, r.C
        boxes = np.stack((r.u_lo, r.x_lo, r.u_hi, r.x_hi))
        two_delta = self._two_delta
        lo, hi, i = float(K[n, 0]), float(K[n, 1]), n - 1
        given, x_hi = False, math.nan
        while True:
            i, lo, hi, stop, x_hi = _backward_pass(
                stage_rows, boxes, self._x_top, *self._u_top, self._rest, two_delta, K, i, lo, hi, given, x_hi,
                self._active_up, self._active_down,
            )  # fmt: skip
            given = False
            if stop == _HIGHEST_LP:
                x_hi, given = r.x_extreme(i, float(two_delta[i]), lo, hi, highest=True), True
            elif stop == _LOWEST_LP:
                x_lo = r.x_extreme(i, float(two_delta[i]), lo, hi, highest=False)
                lo, hi = max(x_lo, 0.0), x_hi
                if lo != lo or hi != hi:
                    break
                K[i, 0], K[i, 1] = lo, hi
                i -= 1
                if i < 0:
                    break
            else:
                break
        return K

    def compute_parameterization(self, sd_start: float, sd_end: float, return_data: bool = False):  # type: ignore[override]
        """toppra's forward pass (greedy: the largest controllable x at every stage), same safeguards,
        each stage's one-variable LP solved in a compiled loop (``_forward_pass``)."""
        K = self.compute_controllable_sets(sd_end, sd_end)
        if np.isnan(K).any():
            return (None, None, None, K) if return_data else (None, None, None)
        x_start = sd_start**2
        if x_start + SMALL < K[0, 0] or K[0, 1] + SMALL < x_start:
            return (None, None, None, K) if return_data else (None, None, None)
        r = self._rows
        us, xs = _forward_pass(r.A, r.B, r.C, r.u_lo, r.u_hi, r.x_lo, r.x_hi, K, self._two_delta, x_start)
        sd = np.sqrt(xs)
        return (us, sd, None, K) if return_data else (us, sd, None)
