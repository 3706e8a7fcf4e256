"""toppra's TOPP-RA algorithm with its per-stage bookkeeping done once up front (``LeanTOPPRA``)."""

from __future__ import annotations

import math

import numpy as np
import toppra.algorithm as algo
import toppra.constraint as constraint
from numpy.typing import NDArray
from toppra.algorithm.algorithm import ParameterizationData
from toppra.constants import SMALL
from toppra.parametrizer import ParametrizeSpline
from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

from pvtflow.planner.path import JointPath
from pvtflow.planner.topp.passes import HIGHEST_LP, LOWEST_LP, backward_pass, forward_pass
from pvtflow.planner.topp.rows import StageRows


class Computed(constraint.LinearConstraint):
    """A constraint's parameters on one grid, computed once: the solver wrapper and the rest check
    of LeanTOPPRA both read them."""

    def __init__(self, source: constraint.Constraint, params: tuple) -> None:
        super().__init__()
        self.identical = source.identical
        self.params = params

    def compute_constraint_params(self, path: JointPath, gridpoints: NDArray[np.float64]):  # type: ignore[override]
        return self.params


class LeanTOPPRA(algo.TOPPRA):
    """toppra's TOPPRA, with the per-stage bookkeeping of its two passes done once up front.

    Same algorithm, same LPs, same results: the backward pass (controllable sets) is one compiled
    loop (``backward_pass``) that solves each stage's 2-D LP as toppra's seidel solver does
    (``seidel_lp2d``: its operations in its order, its warm starts; the same controllable sets,
    bit for bit, as the Cython solver on 400 arm6 and gantry3 solves of 20 to 300 gridpoints,
    tests/planner/test_timing.py), without building toppra's solver wrapper (a Python loop over
    every stage's rows) or calling it stage by stage, which is where most of the time of a
    coarse-grid solve goes. The forward pass fixes x at every stage, so its LP has one variable: it is solved
    in one compiled loop by the rule toppra's seidel wrapper applies to it (``forward_pass``; the
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
        # toppra's seidel solver's, compiled (``seidel_lp2d``), on the rows stacked once
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
        rows = self._rows = StageRows.stack(self._params, len(self.gridpoints))
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
            computed = [Computed(c, p) for c, p in zip(self.constraints, self._params, strict=True)]
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
            i, lo, hi, stop, x_hi = backward_pass(
                stage_rows, boxes, self._x_top, *self._u_top, self._rest, two_delta, K, i, lo, hi, given, x_hi,
                self._active_up, self._active_down,
            )  # fmt: skip
            given = False
            if stop == HIGHEST_LP:
                x_hi, given = r.x_extreme(i, float(two_delta[i]), lo, hi, highest=True), True
            elif stop == LOWEST_LP:
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
        each stage's one-variable LP solved in a compiled loop (``forward_pass``)."""
        K = self.compute_controllable_sets(sd_end, sd_end)
        if np.isnan(K).any():
            return (None, None, None, K) if return_data else (None, None, None)
        x_start = sd_start**2
        if x_start + SMALL < K[0, 0] or K[0, 1] + SMALL < x_start:
            return (None, None, None, K) if return_data else (None, None, None)
        r = self._rows
        us, xs = forward_pass(r.A, r.B, r.C, r.u_lo, r.u_hi, r.x_lo, r.x_hi, K, self._two_delta, x_start)
        sd = np.sqrt(xs)
        return (us, sd, None, K) if return_data else (us, sd, None)
