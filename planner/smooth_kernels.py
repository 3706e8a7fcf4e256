"""The compiled loops of the drive's window jerk: its peaks (``planner.knots.window_jerk``) and the
records nudged for it (``planner.knots.jerk_smooth``).

Its cubics are the drive's own (``axes.drive.interpolation.epos2_segment`` and ``hermite``), inlined:
this file is one of ``planner.kernel_cache.KERNEL_SOURCES``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import (
    LIMIT_RTOL,
    cubic_peak_acceleration,
    cubic_peak_speed,
    cubic_position_range,
    epos2_end,
    epos2_segment,
    hermite,
)

_F = NDArray[np.float64]
_I = NDArray[np.int64]

_PASSES = 4


@njit(cache=True)
def _acceleration_side(start: _F, duration: _F, c2: _F, c3: _F, t: float, left: bool) -> float:
    """A piecewise cubic's acceleration just before (``left``) or just after ``t``; 0 at rest
    before its first segment and after its last."""
    n = len(start)
    end = start[n - 1] + duration[n - 1]
    if (left and (t <= start[0] or t > end)) or (not left and (t < start[0] or t >= end)):
        return 0.0
    lo, hi = 0, n  # the last segment starting before t (left) or at or before t (right)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if start[mid] < t or (not left and start[mid] == t):
            lo = mid
        else:
            hi = mid
    tau = min(max(t - start[lo], 0.0), duration[lo])
    return 2.0 * c2[lo] + 6.0 * c3[lo] * tau


@njit(cache=True)
def window_jerk_peaks(start: _F, duration: _F, c2: _F, c3: _F, window: float) -> tuple[_F, _F]:
    """(t, |a(t + W) - a(t)| / W, the larger side) at every segment end and every end less W: the
    acceleration is linear in between, so the window jerk peaks at one of them."""
    n = len(start)
    times = np.empty(2 * (n + 1))
    for k in range(n):
        times[k] = start[k]
    times[n] = start[n - 1] + duration[n - 1]
    for k in range(n + 1):
        times[n + 1 + k] = times[k] - window
    jerk = np.empty(len(times))
    for i in range(len(times)):
        t = times[i]
        d_left = _acceleration_side(start, duration, c2, c3, t + window, True) - _acceleration_side(
            start, duration, c2, c3, t, True
        )
        d_right = _acceleration_side(start, duration, c2, c3, t + window, False) - _acceleration_side(
            start, duration, c2, c3, t, False
        )
        jerk[i] = max(abs(d_left), abs(d_right)) / window
    return times, jerk


@njit(cache=True)
def _fill_acceleration(
    rows: _I, f: float, k: int, start: _I, a_left: _F, a_right: _F, pad: int
) -> tuple[float, float, float, float]:
    """Write segment k's acceleration at its whole ms into the one-sided arrays (index t + pad);
    return its cubic's (c0, c1, c2, c3)."""
    p0, v0, p1, v1, T = epos2_segment(rows, 0, k, f)
    c0, c1, c2, c3 = hermite(p0, v0, p1, v1, T)
    s = start[k]
    n = int(T)
    for i in range(n):
        a_right[s + i + pad] = 2.0 * c2 + 6.0 * c3 * i
        a_left[s + i + 1 + pad] = 2.0 * c2 + 6.0 * c3 * (i + 1)
    return c0, c1, c2, c3


@njit(cache=True)
def _window_max(a_left: _F, a_right: _F, lo: int, hi: int, w: int) -> float:
    """max over array indices u in [lo, hi] of the window jerk |a(u + w) - a(u)| / w, both sides."""
    worst = 0.0
    n = len(a_left)
    for u in range(max(lo, 0), min(hi, n - w - 1) + 1):
        d = max(abs(a_left[u + w] - a_left[u]), abs(a_right[u + w] - a_right[u]))
        worst = max(worst, d)
    return worst / w


@njit(cache=True)
def _segment_ok(
    rows: _I,
    f: float,
    k: int,
    start: _I,
    dwell: int,
    plan: _F,
    tol: float,
    vmax: float,
    amax: float,
    lo: float,
    hi: float,
) -> bool:
    p0, v0, p1, v1, T = epos2_segment(rows, 0, k, f)
    c0, c1, c2, c3 = hermite(p0, v0, p1, v1, T)
    if cubic_peak_speed(c1, c2, c3, T) > vmax * (1.0 + LIMIT_RTOL):
        return False
    if cubic_peak_acceleration(c2, c3, T) > amax * (1.0 + LIMIT_RTOL):
        return False
    p_lo, p_hi = cubic_position_range(c0, c1, c2, c3, T)
    if p_lo < lo or p_hi > hi:
        return False
    j0 = start[k] - dwell
    for i in range(int(T) + 1):
        j = j0 + i
        if 0 <= j < len(plan):
            tau = float(i)
            if abs(c0 + tau * (c1 + tau * (c2 + tau * c3)) - plan[j]) > tol:
                return False
    return True


@njit(cache=True)
def smooth_records(
    records: _I,
    f: float,
    plan: _F,
    tol: float,
    vmax: float,
    amax: float,
    lo: float,
    hi: float,
    allowed: float,
    window: int,
) -> _I:
    """Records (a copy) whose interior records are nudged where the drive's window jerk exceeds
    ``allowed`` (qc/ms^3): see the module docstring. ``plan``: the axis's plan at every ms from the
    first segment after the dwell (qc); ``vmax``, ``amax`` in qc/ms, qc/ms^2."""
    rows = records.copy()
    n = epos2_end(rows, 0, len(rows))  # segments 0 .. n - 1
    start = np.zeros(n + 1, dtype=np.int64)
    for k in range(n):
        start[k + 1] = start[k] + rows[k, 2]
    end = start[n]
    pad = window + 1
    a_left = np.zeros(end + 2 * pad + 1)
    a_right = np.zeros(end + 2 * pad + 1)
    for k in range(n):
        _fill_acceleration(rows, f, k, start, a_left, a_right, pad)
    dwell = int(rows[0, 2])
    for _ in range(_PASSES):
        changed = False
        for j in range(1, n - 1):  # record j ends segment j and starts j + 1 (not the start, not the goal)
            lo_u, hi_u = start[j] - window + pad, start[j + 2] + pad
            here = _window_max(a_left, a_right, lo_u, hi_u, window)
            if here <= allowed:
                continue
            p_keep, v_keep = rows[j, 0], rows[j, 1]
            best, best_p, best_v = here * (1.0 - 1e-9), p_keep, v_keep
            for dp in (-1, 0, 1):
                for dv in (-2, -1, 0, 1, 2):
                    if dp == 0 and dv == 0:
                        continue
                    rows[j, 0], rows[j, 1] = p_keep + dp, v_keep + dv
                    if not (
                        _segment_ok(rows, f, j, start, dwell, plan, tol, vmax, amax, lo, hi)
                        and _segment_ok(rows, f, j + 1, start, dwell, plan, tol, vmax, amax, lo, hi)
                    ):
                        continue
                    _fill_acceleration(rows, f, j, start, a_left, a_right, pad)
                    _fill_acceleration(rows, f, j + 1, start, a_left, a_right, pad)
                    w = _window_max(a_left, a_right, lo_u, hi_u, window)
                    if w < best:
                        best, best_p, best_v = w, rows[j, 0], rows[j, 1]
            rows[j, 0], rows[j, 1] = best_p, best_v
            _fill_acceleration(rows, f, j, start, a_left, a_right, pad)
            _fill_acceleration(rows, f, j + 1, start, a_left, a_right, pad)
            changed = changed or best_p != p_keep or best_v != v_keep
        if not changed:
            break
    return rows
