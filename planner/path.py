"""Geometric paths through joint waypoints: where the axes go, not yet when.

The path is a piecewise cubic through the waypoints, parameterised by the cumulative chord length
in joint space (s in [0, L]): the not-a-knot cubic spline (C2), except where the spline would swing
past a position limit between two waypoints that are both inside. There that joint's slopes at
the piece's ends are clamped so that the piece's Bezier control points lie inside the limits, and
the pieces next to a clamped slope become cubic Hermites through the same waypoints (C1 there: the
second derivative may jump at such a waypoint). A cubic lies within the hull of its control
points, so waypoints inside the limits always give a path inside them; the exact extrema of every
piece are checked all the same, as a safety net (docs/planning.md).
"""

from __future__ import annotations

from enum import Enum

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline
from scipy.linalg.lapack import dgtsv
from toppra.interpolator import AbstractGeometricPath

from pvtflow.axes.drive.interpolation import cubic_position_range, hermite_coefficients
from pvtflow.planner.limits import JointLimits

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
    finite = np.isfinite(w)
    if not finite.all():
        i, j = np.argwhere(~finite)[0]
        raise PlanError(
            PlanResult.INVALID_INPUT,
            f"waypoint {i}, joint {limits.names[j]}: {w[i, j]} is not a finite number",
            waypoint=int(i),
            joint=limits.names[j],
        )
    outside = np.argwhere((w < limits.lower - POSITION_TOLERANCE) | (w > limits.upper + POSITION_TOLERANCE))
    if len(outside):  # the first waypoint with a joint outside, its first such joint
        i, j = (int(v) for v in outside[0])
        q = w[i]
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
def spline_piece(x: NDArray[np.float64], anchor: float, s: float, i: int) -> tuple[int, float]:
    """The path's piece that holds ``anchor`` (``i``: a hint for it; at a waypoint, the piece that
    starts there; clipped to the end pieces) and the offset of s into it (scipy's PPoly layout:
    breakpoints ``x``). The anchor is s itself, or the start of the grid interval s lies in: the
    second derivative may jump at a waypoint, and every sample of one grid interval (its end
    included) belongs to the interval's own piece."""
    i = interval(x, anchor, i, len(x) - 2)
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
    x: NDArray[np.float64], c: NDArray[np.float64], anchor: NDArray[np.float64], s: NDArray[np.float64], order: int
) -> NDArray[np.float64]:
    """The path's ``order``-th derivative (0, 1, 2) at every s, (len(s), dof), in one pass, on the
    piece that holds the sample's anchor (``spline_piece``)."""
    out = np.empty((len(s), c.shape[2]))
    i = 0
    for k in range(len(s)):
        i, h = spline_piece(x, anchor[k], s[k], i)
        for j in range(c.shape[2]):
            q, q_s, q_ss = spline_at(c, i, h, j)
            out[k, j] = q if order == 0 else (q_s if order == 1 else q_ss)
    return out


@njit(cache=True)
def _spline_states(
    x: NDArray[np.float64], c: NDArray[np.float64], anchor: NDArray[np.float64], s: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``_spline_values`` of orders 0, 1 and 2 in one pass."""
    q, q_s, q_ss = np.empty((len(s), c.shape[2])), np.empty((len(s), c.shape[2])), np.empty((len(s), c.shape[2]))
    i = 0
    for k in range(len(s)):
        i, h = spline_piece(x, anchor[k], s[k], i)
        for j in range(c.shape[2]):
            q[k, j], q_s[k, j], q_ss[k, j] = spline_at(c, i, h, j)
    return q, q_s, q_ss


@njit(cache=True)
def _piece_ranges(x: NDArray[np.float64], c: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact (min, max) of every piece and joint, each (pieces, dof) (``cubic_position_range``)."""
    n, dof = c.shape[1], c.shape[2]
    lo, hi = np.empty((n, dof)), np.empty((n, dof))
    for i in range(n):
        for j in range(dof):
            lo[i, j], hi[i, j] = cubic_position_range(c[3, i, j], c[2, i, j], c[1, i, j], c[0, i, j], x[i + 1] - x[i])
    return lo, hi


def _outside(
    x: NDArray[np.float64], c: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
    """Which pieces (pieces, dof) leave [lower, upper] (beyond the shared tolerance), and the ranges."""
    lo, hi = _piece_ranges(x, c)
    out = (lo < lower - (POSITION_TOLERANCE + 1e-12 * np.abs(lo))) | (
        hi > upper + POSITION_TOLERANCE + 1e-12 * np.abs(hi)
    )
    return out, lo, hi


def _hermite_pieces(
    s: NDArray[np.float64], w: NDArray[np.float64], m: NDArray[np.float64], k: NDArray[np.intp], j: NDArray[np.intp]
) -> NDArray[np.float64]:
    """The Hermite cubics of pieces k, joints j (through w and slopes m): rows of ``c``, highest power first."""
    c0, c1, c2, c3 = hermite_coefficients(w[k, j], m[k, j], w[k + 1, j], m[k + 1, j], s[k + 1] - s[k])
    return np.stack((c3, c2, c1, c0))


def not_a_knot(s: NDArray[np.float64], w: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """scipy's not-a-knot ``CubicSpline(s, w)``: its coefficients ``c`` and its slope at the last
    waypoint, bit for bit (the same arithmetic and LAPACK's tridiagonal solver, as scipy 1.17 does
    them) without scipy's input checks and its PPoly, which cost four times the solve. Below 4
    waypoints scipy's special cases: scipy itself."""
    if len(s) < 4:
        spline = CubicSpline(s, w, bc_type="not-a-knot")
        return np.array(spline.c), spline(s[-1], 1)
    lower, main, upper, b, slope = _not_a_knot_system(s, w)
    _, _, _, m, info = dgtsv(lower, main, upper, b, 1, 1, 1, 1)
    if info != 0:
        raise np.linalg.LinAlgError("singular matrix")
    return _not_a_knot_pieces(s, w, slope, np.ascontiguousarray(m))


@njit(cache=True)
def _not_a_knot_system(
    s: NDArray[np.float64], w: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The not-a-knot spline's tridiagonal system for its slopes (lower, main and upper diagonal,
    right-hand sides), as scipy builds it, and the chords' slopes."""
    n, dof = w.shape
    dx = s[1:] - s[:-1]
    slope = np.empty((n - 1, dof))
    for i in range(n - 1):
        for j in range(dof):
            slope[i, j] = (w[i + 1, j] - w[i, j]) / dx[i]
    lower, main, upper = np.zeros(n - 1), np.zeros(n), np.zeros(n - 1)
    b = np.empty((n, dof))
    for i in range(1, n - 1):
        main[i] = 2 * (dx[i - 1] + dx[i])
        upper[i] = dx[i - 1]
        lower[i - 1] = dx[i]
        for j in range(dof):
            b[i, j] = 3 * (dx[i] * slope[i - 1, j] + dx[i - 1] * slope[i, j])
    main[0] = dx[1]
    upper[0] = d = s[2] - s[0]
    for j in range(dof):
        b[0, j] = ((dx[0] + 2 * d) * dx[1] * slope[0, j] + (dx[0] * dx[0]) * slope[1, j]) / d
    main[n - 1] = dx[n - 3]
    lower[n - 2] = d = s[n - 1] - s[n - 3]
    for j in range(dof):
        b[n - 1, j] = (
            (dx[n - 2] * dx[n - 2]) * slope[n - 3, j] + (2 * d + dx[n - 2]) * dx[n - 3] * slope[n - 2, j]
        ) / d
    return lower, main, upper, b, slope


@njit(cache=True)
def _not_a_knot_pieces(
    s: NDArray[np.float64], w: NDArray[np.float64], slope: NDArray[np.float64], m: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The spline's coefficients from its slopes ``m`` at the waypoints, and its slope at the last
    waypoint, in scipy's order of evaluation."""
    n, dof = w.shape
    c = np.empty((4, n - 1, dof))
    for i in range(n - 1):
        dx = s[i + 1] - s[i]
        for j in range(dof):
            t = (m[i, j] + m[i + 1, j] - 2 * slope[i, j]) / dx
            c[0, i, j] = t / dx
            c[1, i, j] = (slope[i, j] - m[i, j]) / dx - t
            c[2, i, j] = m[i, j]
            c[3, i, j] = w[i, j]
    h = s[n - 1] - s[n - 2]  # the last piece's slope at its end, in scipy's order of evaluation
    end = np.empty(dof)
    for j in range(dof):
        end[j] = c[2, n - 2, j] + c[1, n - 2, j] * h * 2.0 + c[0, n - 2, j] * (h * h) * 3.0
    return c, end


def within_limits_pieces(
    s: NDArray[np.float64], w: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The path's cubic pieces through waypoints ``w`` at ``s``: ``c[k, piece, joint]`` (highest power
    first), and which slopes (N, dof) were clamped to keep it inside [lower, upper].

    Start from the not-a-knot cubic spline. While a piece of joint j leaves the limits, j's slopes at
    both its ends are clamped into the range that keeps the piece's Bezier control points
    p0 + m0 h / 3 and p1 - m1 h / 3 inside the limits, and the pieces on either side of a changed
    slope become the cubic Hermites through their waypoints with the new slopes. Every such range
    holds 0 (the waypoints are inside), so a slope clamped again only moves towards 0 and stays in
    every range it was clamped into: a piece whose two slopes have been clamped for it stays inside
    for good, and each round clamps at least one more piece (one whose control points are all
    inside does not leave), so at most N - 1 rounds change anything. Pieces no clamp touched keep
    the spline's own coefficients, bit for bit.
    """
    n = len(w)
    c, end_slope = not_a_knot(s, w)
    clamped = np.zeros(w.shape, dtype=bool)
    out, _, _ = _outside(s, c, lower, upper)
    if not out.any():  # the spline itself (most paths): nothing to clamp
        return np.ascontiguousarray(c), clamped
    slopes = np.vstack((c[2], end_slope[None, :]))
    h = np.diff(s)
    p = np.clip(w, lower, upper)  # on the limit at worst: every slope range holds 0
    for rounds in range(2 * (n - 1)):
        if rounds:
            out, _, _ = _outside(s, c, lower, upper)
            if not out.any():
                break
        piece, joint = np.nonzero(out)
        hk = h[piece]
        # piece k's start slope keeps p_k + m h / 3 inside, its end slope p_k+1 - m h / 3
        ends = np.concatenate((piece, piece + 1))
        joints = np.concatenate((joint, joint))
        low = np.concatenate(((lower[joint] - p[piece, joint]) / hk, (p[piece + 1, joint] - upper[joint]) / hk))
        high = np.concatenate(((upper[joint] - p[piece, joint]) / hk, (p[piece + 1, joint] - lower[joint]) / hk))
        lo_bound, hi_bound = np.full(w.shape, -np.inf), np.full(w.shape, np.inf)
        np.maximum.at(lo_bound, (ends, joints), 3.0 * low)
        np.minimum.at(hi_bound, (ends, joints), 3.0 * high)
        new = np.clip(slopes, lo_bound, hi_bound)
        changed = new != slopes
        slopes = new
        clamped |= changed
        k, j = np.nonzero(changed[:-1] | changed[1:])  # the pieces on either side of a changed slope
        c[:, k, j] = _hermite_pieces(s, w, slopes, k, j)
    return np.ascontiguousarray(c), clamped


class JointPath(AbstractGeometricPath):
    """A piecewise cubic through (N, dof) waypoints, inside the position limits between them,
    s = cumulative chord length: the spline, C1 where it had to be clamped (``within_limits_pieces``).

    A toppra geometric path (constraints and the algorithm take it directly), plus what the planner
    needs: the waypoints' path parameters, the pieces for the compiled loops, evaluation on a
    chosen piece (the second derivative may jump at a waypoint) and an exact position-limit check.
    """

    def __init__(self, waypoints: ArrayLike, limits: JointLimits) -> None:
        super().__init__()
        w = check_waypoints(waypoints, limits)
        ss = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))))
        self.points: NDArray[np.float64] = w
        self.waypoint_s: NDArray[np.float64] = ss
        c, clamped = within_limits_pieces(ss, w, limits.lower, limits.upper)
        self._pieces = (ss, c)
        # the slopes (N, dof) that were clamped to keep the path inside the limits
        self.clamped: NDArray[np.bool_] = clamped
        # the inner waypoints next to a rebuilt (Hermite) piece: where the second derivative may jump
        rebuilt = (clamped[:-1] | clamped[1:]).any(axis=1)
        self.kinks: NDArray[np.float64] = ss[1:-1][rebuilt[:-1] | rebuilt[1:]]
        if clamped.any():  # otherwise the spline itself, which within_limits_pieces found inside
            self.check_within(limits)

    @property
    def pieces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The path's pieces as the compiled loops take them (scipy's PPoly layout): breakpoints
        (the waypoints' s), and ``c[k, piece, joint]``, highest power first."""
        return self._pieces

    def __call__(self, path_positions: ArrayLike, order: int = 0) -> NDArray[np.float64]:
        """toppra's evaluation (q, q_s or q_ss at s; (dof,) for a scalar s, (n, dof) for n of them),
        in one compiled pass (a plan evaluates its path a dozen times on hundreds of points). At a
        waypoint, the piece that starts there."""
        s = np.asarray(path_positions, dtype=float)
        flat = np.atleast_1d(s).ravel()
        out = self._values(flat, flat, order)
        return out[0] if s.ndim == 0 else out.reshape(*s.shape, out.shape[1])

    def on_piece_of(self, anchor: ArrayLike, s: ArrayLike, order: int) -> NDArray[np.float64]:
        """The ``order``-th derivative at every s on the piece that holds its anchor, (n, dof): with
        the grid interval's start as the anchor, all of an interval's samples on its own piece, its
        end included (q_ss of the piece that ends at a waypoint, not of the one that starts there)."""
        s_arr = np.asarray(s, dtype=float).ravel()
        a_arr = np.broadcast_to(np.asarray(anchor, dtype=float).ravel(), s_arr.shape)
        return self._values(np.ascontiguousarray(a_arr), s_arr, order)

    def states_on_piece_of(
        self, anchor: NDArray[np.float64], s: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``on_piece_of`` of orders 0, 1 and 2 at once, (n, dof) each (``anchor`` and ``s`` of the
        same length)."""
        s = np.ascontiguousarray(s, dtype=float).ravel()
        return _spline_states(*self._pieces, np.ascontiguousarray(anchor, dtype=float).ravel(), s)

    def _values(self, anchor: NDArray[np.float64], s: NDArray[np.float64], order: int) -> NDArray[np.float64]:
        if order not in (0, 1, 2):
            raise ValueError(f"Invalid order {order}")
        return _spline_values(*self._pieces, anchor, s, order)

    @property
    def dof(self) -> int:
        return int(self.points.shape[1])

    @property
    def path_interval(self) -> NDArray[np.float64]:
        return np.array([self.waypoint_s[0], self.waypoint_s[-1]])

    @property
    def waypoints(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.waypoint_s, self.points

    @property
    def length(self) -> float:
        return float(self.waypoint_s[-1])

    def check_within(self, limits: JointLimits) -> None:
        """Exact extrema of every piece against the position limits: the safety net under
        ``within_limits_pieces`` (which keeps every piece inside; this never fires on waypoints
        inside the limits)."""
        out, lo, hi = _outside(*self._pieces, limits.lower, limits.upper)
        if out.any():
            k, j = (int(v) for v in np.argwhere(out)[0])
            q = float(lo[k, j] if lo[k, j] < limits.lower[j] else hi[k, j])
            raise PlanError(
                PlanResult.PATH_OUT_OF_LIMITS,
                f"the path between waypoints {k} and {k + 1} takes joint {limits.names[j]} to "
                f"{q:.6g}, outside [{limits.lower[j]:.6g}, {limits.upper[j]:.6g}]",
                segment=k,
                joint=limits.names[j],
                value=q,
            )
