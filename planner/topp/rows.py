"""Every stage's constraint rows of a TOPP-RA problem, stacked once, and the closed-form facts read from them.

toppra's solver wrapper builds each stage's rows in a Python loop at every solve; here all stages' rows of all
constraints are one (n, m) array each, so the passes (``planner.topp.passes``) read them in compiled loops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.optimize import linprog

# the solver wrapper's box on u and x at every stage (toppra's seidel VAR_MIN / VAR_MAX)
VAR_MAX = 1e8


def times(F: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """F v at every stage: F the same at every stage (2-D) or one per stage (3-D)."""
    return v @ F.T if F.ndim == 2 else np.einsum("ikj,ij->ik", F, v)


@njit(cache=True)
def stage_rows(
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
class StageRows:
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
    def stack(cls, params: list[tuple], n: int) -> StageRows:
        x_lo, x_hi = np.full(n, -VAR_MAX), np.full(n, VAR_MAX)
        u_lo, u_hi = np.full(n, -VAR_MAX), np.full(n, VAR_MAX)
        m = sum(p[3].shape[-2] for p in params if p[0] is not None)
        A, B, C = np.empty((n, m)), np.empty((n, m)), np.empty((n, m))
        col = 0
        for a, b, c, F, h, ubound, xbound in params:
            if a is not None:
                k = F.shape[-2]
                if F.ndim == 2 and np.ndim(h) == 1:  # pvtflow's constraints: one F for every stage
                    stage_rows(F, a, b, c, h, A, B, C, col)
                else:
                    A[:, col : col + k], B[:, col : col + k] = times(F, a), times(F, b)
                    C[:, col : col + k] = times(F, c) - h
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
        return u_range(self.A, self.B, self.C, self.u_lo, self.u_hi, self.x_lo, self.x_hi, x)


@njit(cache=True)
def nan_min(a: float, b: float) -> float:
    """numpy's minimum: NaN if either is."""
    return a if a != a or a < b else b


@njit(cache=True)
def nan_max(a: float, b: float) -> float:
    """numpy's maximum: NaN if either is."""
    return a if a != a or a > b else b


@njit(cache=True)
def u_range(
    A: NDArray[np.float64],
    B: NDArray[np.float64],
    C: NDArray[np.float64],
    u_lo: NDArray[np.float64],
    u_hi: NDArray[np.float64],
    x_lo: NDArray[np.float64],
    x_hi: NDArray[np.float64],
    x: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``StageRows.u_range_at`` in one pass over the rows: each row's bound -(B x + C) / A on u
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
                top = nan_min(top, -r / a)
            elif a < 0.0:
                bottom = nan_max(bottom, -r / a)
            elif a == 0.0 and r > 0.0:
                broken = True
        hi[i] = nan_min(u_hi[i], top)
        lo[i] = np.inf if broken or x[i] < x_lo[i] or x[i] > x_hi[i] else nan_max(u_lo[i], bottom)
    return lo, hi
