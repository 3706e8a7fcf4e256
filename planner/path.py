"""Geometric paths through joint waypoints: where the axes go, not yet when.

The path is toppra's cubic spline through the waypoints, parameterised by the cumulative chord
length in joint space (s in [0, L]). A spline can swing past a position limit between two
waypoints that are both inside; that is checked exactly on every spline piece, not sampled.
"""

from __future__ import annotations

from enum import Enum
from functools import cached_property

import numpy as np
import toppra
from numba import njit
from numpy.typing import ArrayLike, NDArray

from planner.limits import JointLimits

# Two waypoints closer than this (joint units, Euclidean) are the same point.
MIN_WAYPOINT_DISTANCE = 1e-6
# Position limits are exact: a waypoint may sit on one, not past it by more than this.
POSITION_TOLERANCE = 1e-9


class PlanResult(Enum):
    """Outcome of planning; every member but OK names what was wrong with the input."""

    OK = "ok"
    INVALID_INPUT = "invalid_input"  # shape, joint count, NaN/inf
    REPEATED_WAYPOINT = "repeated_waypoint"  # consecutive waypoints coincide
    WAYPOINT_OUT_OF_LIMITS = "waypoint_out_of_limits"  # a waypoint outside the position limits
    PATH_OUT_OF_LIMITS = "path_out_of_limits"  # the path leaves the limits between waypoints
    INFEASIBLE = "infeasible"  # no parameterization satisfies the constraints


class PlanError(ValueError):
    """A planning input that cannot be planned; ``result`` says why, ``details`` where."""

    def __init__(self, result: PlanResult, message: str, **details: object) -> None:
        self.result = result
        self.message = message
        self.details = details
        super().__init__(message)


def check_waypoints(waypoints: ArrayLike, limits: JointLimits) -> NDArray[np.float64]:
    """The waypoints as an (N, dof) float array, or a PlanError saying what is wrong with them."""
    try:
        w = np.array(waypoints, dtype=float)
    except (TypeError, ValueError):
        raise PlanError(PlanResult.INVALID_INPUT, "waypoints must be a list of lists of numbers") from None
    if w.ndim != 2:
        raise PlanError(
            PlanResult.INVALID_INPUT, f"waypoints must be a 2-D array (N, {limits.dof}), got shape {w.shape}"
        )
    if w.shape[1] != limits.dof:
        raise PlanError(
            PlanResult.INVALID_INPUT,
            f"each waypoint needs {limits.dof} joint values ({', '.join(limits.names)}), got {w.shape[1]}",
        )
    if w.shape[0] < 2:
        raise PlanError(PlanResult.INVALID_INPUT, f"a path needs at least 2 waypoints, got {w.shape[0]}")
    bad = np.argwhere(~np.isfinite(w))
    if len(bad):
        i, j = bad[0]
        raise PlanError(
            PlanResult.INVALID_INPUT,
            f"waypoint {i}, joint {limits.names[j]}: {w[i, j]} is not a finite number",
            waypoint=int(i),
            joint=limits.names[j],
        )
    for i, q in enumerate(w):
        below = q < limits.lower - POSITION_TOLERANCE
        above = q > limits.upper + POSITION_TOLERANCE
        if below.any() or above.any():
            j = int(np.flatnonzero(below | above)[0])
            raise PlanError(
                PlanResult.WAYPOINT_OUT_OF_LIMITS,
                f"waypoint {i}, joint {limits.names[j]}: {q[j]:.6g} is outside "
                f"[{limits.lower[j]:.6g}, {limits.upper[j]:.6g}]",
                waypoint=i,
                joint=limits.names[j],
                value=float(q[j]),
            )
    steps = np.linalg.norm(np.diff(w, axis=0), axis=1)
    repeated = np.flatnonzero(steps < MIN_WAYPOINT_DISTANCE)
    if len(repeated):
        i = int(repeated[0])
        raise PlanError(PlanResult.REPEATED_WAYPOINT, f"waypoints {i} and {i + 1} are the same point", waypoint=i + 1)
    return w


@njit(cache=True)
def interval(a: NDArray[np.float64], v: float, i: int, hi: int) -> int:
    """The last i <= hi with a[i] <= v (0 if none), walking on from the hint ``i``: the times and
    path parameters of one sampling pass only grow, so each step is one comparison, not a search."""
    if a[i] > v:
        return min(max(np.searchsorted(a, v, side="right") - 1, 0), hi)
    while i < hi and a[i + 1] <= v:
        i += 1
    return i


@njit(cache=True)
def spline_piece(x: NDArray[np.float64], s: float, i: int) -> tuple[int, float]:
    """The path's spline piece at s (``i``: a hint for it) and the offset into it (scipy's PPoly
    layout: breakpoints ``x``; clipped to the end pieces)."""
    i = interval(x, s, i, len(x) - 2)
    return i, s - x[i]


@njit(cache=True)
def spline_at(c: NDArray[np.float64], i: int, h: float, j: int) -> tuple[float, float, float]:
    """Joint j of the path on piece i at offset h: q, q_s, q_ss (``c[k, piece, joint]``, highest
    power first)."""
    q = ((c[0, i, j] * h + c[1, i, j]) * h + c[2, i, j]) * h + c[3, i, j]
    q_s = (3.0 * c[0, i, j] * h + 2.0 * c[1, i, j]) * h + c[2, i, j]
    q_ss = 6.0 * c[0, i, j] * h + 2.0 * c[1, i, j]
    return q, q_s, q_ss


@njit(cache=True)
def _spline_values(
    x: NDArray[np.float64], c: NDArray[np.float64], s: NDArray[np.float64], order: int
) -> NDArray[np.float64]:
    """The spline's ``order``-th derivative (0, 1, 2) at every s, (len(s), dof), in one pass."""
    out = np.empty((len(s), c.shape[2]))
    i = 0
    for k in range(len(s)):
        i, h = spline_piece(x, s[k], i)
        for j in range(c.shape[2]):
            q, q_s, q_ss = spline_at(c, i, h, j)
            out[k, j] = q if order == 0 else (q_s if order == 1 else q_ss)
    return out


class JointPath(toppra.SplineInterpolator):
    """A cubic spline through (N, dof) waypoints, s = cumulative chord length.

    Subclassing toppra's SplineInterpolator keeps it a toppra geometric path (constraints and the
    algorithm take it directly) while adding what the planner needs: the waypoints' path
    parameters and an exact position-limit check.
    """

    def __init__(self, waypoints: ArrayLike, limits: JointLimits) -> None:
        w = check_waypoints(waypoints, limits)
        ss = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))))
        super().__init__(ss, w, bc_type="not-a-knot")
        self.points: NDArray[np.float64] = w
        self.waypoint_s: NDArray[np.float64] = ss
        self._check_within(limits)

    @cached_property
    def pieces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The spline's pieces as the compiled loops take them (scipy's PPoly layout): breakpoints,
        and ``c[k, piece, joint]``, highest power first."""
        return self.cspl.x, np.ascontiguousarray(self.cspl.c)

    def __call__(self, path_positions: ArrayLike, order: int = 0) -> NDArray[np.float64]:
        """toppra's evaluation (q, q_s or q_ss at s; (dof,) for a scalar s, (n, dof) for n of them),
        from the same spline pieces in one compiled pass: a plan evaluates its path a dozen times on
        hundreds of points, and scipy's per-call overhead was a tenth of the planning time."""
        if order not in (0, 1, 2):
            raise ValueError(f"Invalid order {order}")
        s = np.asarray(path_positions, dtype=float)
        out = _spline_values(*self.pieces, np.atleast_1d(s).ravel(), order)
        return out[0] if s.ndim == 0 else out.reshape(*s.shape, out.shape[1])

    @property
    def length(self) -> float:
        return float(self.waypoint_s[-1])

    def _check_within(self, limits: JointLimits) -> None:
        """Exact extrema of every spline piece against the position limits."""
        spline = self.cspl  # scipy CubicSpline: c[k, piece, joint], highest power first
        c3, c2, c1 = spline.c[0], spline.c[1], spline.c[2]
        h = np.diff(spline.x)[:, None]
        # stationary points of each piece: 3 c3 t^2 + 2 c2 t + c1 = 0
        a, b = 3.0 * c3, 2.0 * c2
        with np.errstate(divide="ignore", invalid="ignore"):
            disc = b * b - 4.0 * a * c1
            sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
            quad = np.abs(a) > 1e-14
            roots = (np.where(quad, (-b - sq) / (2.0 * a), -c1 / b), np.where(quad, (-b + sq) / (2.0 * a), np.nan))
        for t in roots:
            inside = np.isfinite(t) & (t > 0.0) & (t < h)
            if not inside.any():
                continue
            piece, joint = np.nonzero(inside)
            tt = t[piece, joint]
            q = spline(spline.x[piece] + tt)[np.arange(len(piece)), joint]
            tol = POSITION_TOLERANCE + 1e-12 * np.abs(q)
            out = (q < limits.lower[joint] - tol) | (q > limits.upper[joint] + tol)
            if out.any():
                k = int(np.flatnonzero(out)[0])
                j = int(joint[k])
                raise PlanError(
                    PlanResult.PATH_OUT_OF_LIMITS,
                    f"the path between waypoints {piece[k]} and {piece[k] + 1} takes joint {limits.names[j]} to "
                    f"{q[k]:.6g}, outside [{limits.lower[j]:.6g}, {limits.upper[j]:.6g}]; add a waypoint there "
                    "or move the neighbours away from the limit",
                    segment=int(piece[k]),
                    joint=limits.names[j],
                    value=float(q[k]),
                )
