"""Judging one knot segment's cubic, compiled with numba: step 4's check (``planner.knots.check``)
and the judgements every other step's kernels share (a cubic's value, its deviation at a few
probes, whether it leaves 0x607D).

Knot placement judges hundreds of short cubics many times over: each judgement is a handful of
flops, whose cost in numpy would be the fixed price of the calls, not the arithmetic. These loops
hold no formula of their own: the cubic and its extrema are ``axes.drive.interpolation``'s (``hermite``,
``cubic_peak_speed``, ...), inlined, so this file is one of ``planner.kernel_cache.KERNEL_SOURCES``.

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
    cubic_position_range,
    hermite,
)

_F = NDArray[np.float64]
_I = NDArray[np.int64]


@njit(cache=True)
def horner(c0: float, c1: float, c2: float, c3: float, tau: float) -> float:
    return c0 + tau * (c1 + tau * (c2 + tau * c3))


@njit(cache=True, fastmath={"nnan", "ninf", "nsz", "reassoc"})
def max_of(err: _F, n: int) -> float:
    """max(0, err[:n]) for values >= 0, none NaN (|deviations|): a maximum is exact in any order, so
    this one loop may take it in SIMD lanes (``reassoc``); the deviations themselves are computed
    without fast-math, each as the plain loop would."""
    w = 0.0
    for i in range(n):
        w = max(w, err[i])
    return w


@njit(cache=True)
def whole_ms(knots: _I) -> _F:
    """0.0, 1.0, ... up to the longest gap of ``knots``: a segment's sample times as a table. A
    float converted from an int64 in the loop keeps it scalar (AVX2 has no such conversion); a
    load does not, and the values are the same."""
    longest = 1
    for k in range(len(knots) - 1):
        longest = max(longest, knots[k + 1] - knots[k])
    return np.arange(longest + 1).astype(np.float64)


@njit(cache=True)
def probe_deviation(c0: float, c1: float, c2: float, c3: float, T: float, k0: int, plan: _F, probes: _F) -> float:
    """Worst |cubic - plan| at the whole ms ``floor(T * x)`` of a segment that starts at plan index
    ``k0`` (a cheap judgement: a few probes, not every ms)."""
    worst = 0.0
    last = len(plan) - 1
    for x in probes:
        tau = np.floor(T * x)
        worst = max(worst, abs(horner(c0, c1, c2, c3, tau) - plan[min(k0 + int(tau), last)]))
    return worst


@njit(cache=True)
def leaves(c0: float, c1: float, c2: float, c3: float, T: float, p1: float, v1: float, lo: float, hi: float) -> bool:
    """Whether a segment's cubic (from c0 to p1, end velocity v1) leaves [lo, hi] (0x607D): solved
    exactly only where the cheap bound (within T (|V0| + |V1|) 4/27 of its ends) reaches a limit."""
    reach = T * (abs(c1) + abs(v1)) * (4.0 / 27.0)
    if min(c0, p1) - reach >= lo and max(c0, p1) + reach <= hi:
        return False
    p_lo, p_hi = cubic_position_range(c0, c1, c2, c3, T)
    return p_lo < lo or p_hi > hi


@njit(cache=True)
def prev_segment(prev_knots: _I, j: int, k0: int, k1: int) -> tuple[int, bool]:
    """Advance ``j`` to the previous knots' segment starting at k0; whether it is k0 .. k1."""
    while j < len(prev_knots) - 2 and prev_knots[j] < k0:
        j += 1
    return j, len(prev_knots) >= 2 and prev_knots[j] == k0 and prev_knots[j + 1] == k1


@njit(cache=True)
def check_segments(
    knots: _I,
    P: _I,
    V: _I,
    stride: int,
    f: _F,
    rv_per: _F,
    ra_per: _F,
    pos_lo: _F,
    pos_hi: _F,
    plan: _F,
    prev_knots: _I,
    prev_P: _I,
    prev_V: _I,
    prev_dev: _F,
    prev_rv: _F,
    prev_ra: _F,
    prev_out: NDArray[np.bool_],
) -> tuple[_F, _F, _F, NDArray[np.bool_]]:
    """Per knot segment, the quantized records' cubic judged exactly: worst |cubic - plan| at every
    ms (an axis's last segment also at its goal), max |v| / 0x607F, max |a| / 0x60C5, and whether
    it leaves 0x607D. A segment whose two records equal the previous check's keeps its verdict."""
    nseg = len(knots) - 1
    dev, rv, ra = np.zeros(nseg), np.zeros(nseg), np.zeros(nseg)
    out = np.zeros(nseg, dtype=np.bool_)
    tau = whole_ms(knots)
    err = np.empty(len(tau))
    j = 0
    for k in range(nseg):
        k0, k1 = knots[k], knots[k + 1]
        a = k0 // stride
        if k1 // stride != a:
            continue
        j, same = prev_segment(prev_knots, j, k0, k1)
        if same and prev_P[j] == P[k] and prev_P[j + 1] == P[k + 1] and prev_V[j] == V[k] and prev_V[j + 1] == V[k + 1]:
            dev[k], rv[k], ra[k], out[k] = prev_dev[j], prev_rv[j], prev_ra[j], prev_out[j]
            continue
        T = float(k1 - k0)
        p0, p1 = float(P[k]), float(P[k + 1])
        v1 = V[k + 1] * f[a]
        c0, c1, c2, c3 = hermite(p0, V[k] * f[a], p1, v1, T)
        rv[k] = cubic_peak_speed(c1, c2, c3, T) * rv_per[a]
        ra[k] = cubic_peak_acceleration(c2, c3, T) * ra_per[a]
        out[k] = leaves(c0, c1, c2, c3, T, p1, v1, pos_lo[a], pos_hi[a])
        n = k1 - k0
        for t in range(n):
            err[t] = abs(horner(c0, c1, c2, c3, tau[t]) - plan[k0 + t])
        worst = max_of(err, n)
        if k == nseg - 1 or knots[k + 2] // stride != a:  # the axis's goal sample belongs to its last segment
            worst = max(worst, abs(horner(c0, c1, c2, c3, T) - plan[k1]))
        dev[k] = worst
    return dev, rv, ra, out
