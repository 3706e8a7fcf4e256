"""The fixed-period profiles' knots compiled with numba (``planner.knots.fixed_period``): the ratios
of their reconstructions and the exact integer search over their setpoints.

One record per period: the drive's reconstruction (``axes.drive.interpolation``'s ``linear``,
``cubic_pv``, ``cubic_p``) is judged window by window, and the setpoints are chosen by a shortest
path over their nudges, the least slow-down first, then the closest to the plan.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import (
    LIMIT_RTOL,
    Interpolation,
    central_velocity,
    cubic_peak_acceleration,
    cubic_peak_speed,
    hermite,
    linear_segment,
    linear_step_acceleration,
)
from pvtflow.planner.knots.check_kernels import horner, leaves
from pvtflow.planner.knots.quantize_kernels import EXCESS_WEIGHT, N_NUDGES, nudge_dp, nudge_dv
from pvtflow.planner.slowdown import slowdown

_F = NDArray[np.float64]
_I = NDArray[np.int64]


# The reconstructions a fixed-period drive applies to its setpoints (axes.drive.interpolation's
# ``linear``, ``cubic_pv``, ``cubic_p``). Each judges a segment on a window of consecutive points of
# the records padded with copies of their first and last point (velocity 0 there), so that the rest
# at both ends comes out of each segment's own rule: linear [R0, R0, R0, R1 .. RN, RN] (the velocity
# before the first segment is 0), cubic_pv [(R0, 0), R0 .. RN, (RN, 0)], cubic_p [R0, R0, R0, R1 ..
# RN, RN, RN] (the central velocities at both ends are 0).
# The kinds as ints for numba, from ``Interpolation.code``
LINEAR, CUBIC_PV, CUBIC_P = Interpolation.LINEAR.code, Interpolation.CUBIC_PV.code, Interpolation.CUBIC_P.code
_FP_PROBES = np.array([0.25, 0.5, 0.75])  # where inside a segment its deviation from the plan is judged


@njit(cache=True)
def _fp_layout(kind: int) -> tuple[int, int, int, int]:
    """(points per window, pad points before record 0, after the last record, where in the window
    the judged segment starts)."""
    if kind == LINEAR:
        return 3, 2, 1, 1
    if kind == CUBIC_PV:
        return 2, 1, 1, 0
    return 4, 2, 2, 1


@njit(cache=True)
def _count_nudge(e: int) -> int:
    """Nudge e of a setpoint without a velocity: 0, +1, -1, +2, -2 ... counts."""
    return (e + 1) // 2 if e % 2 else -(e // 2)


@njit(cache=True)
def _fp_judge(
    kind: int,
    q0: float,
    q1: float,
    q2: float,
    q3: float,
    u0: float,
    u1: float,
    T: float,
    k0: int,
    n_real: int,
    plan: _F,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
) -> tuple[float, float, float]:
    """One segment of a fixed-period reconstruction from its window of points (positions q, for
    cubic_pv velocities u in qc/ms): max |v| / 0x607F and max |a| / 0x60C5 (both inf where it
    leaves 0x607D), and its summed squared deviation from the plan at its end and probes if it runs
    from record k0 to record k0 + 1 of the n_real + 1 records (0 for the padding's segments)."""
    if kind == LINEAR:
        v_prev = linear_segment(q0, q1, T)[1]
        c0, c1 = linear_segment(q1, q2, T)
        c2 = c3 = 0.0
        acceleration = linear_step_acceleration(v_prev, c1, T)
        p1, v1 = q2, c1
    elif kind == CUBIC_PV:
        c0, c1, c2, c3 = hermite(q0, u0, q1, u1, T)
        acceleration = cubic_peak_acceleration(c2, c3, T)
        p1, v1 = q1, u1
    else:
        v1 = central_velocity(q1, q3, T)
        c0, c1, c2, c3 = hermite(q1, central_velocity(q0, q2, T), q2, v1, T)
        acceleration = cubic_peak_acceleration(c2, c3, T)
        p1 = q2
    if kind != LINEAR and leaves(c0, c1, c2, c3, T, p1, v1, pos_lo, pos_hi):
        return np.inf, np.inf, 0.0  # a linear segment stays between its ends, which are inside
    dev = 0.0
    if 0 <= k0 < n_real:
        last = len(plan) - 1
        t0 = k0 * int(T)
        dev = (p1 - plan[min(t0 + int(T), last)]) ** 2
        for x in _FP_PROBES:
            tau = np.floor(T * x)
            dev += (horner(c0, c1, c2, c3, tau) - plan[min(t0 + int(tau), last)]) ** 2
    return cubic_peak_speed(c1, c2, c3, T) * rv_per, acceleration * ra_per, dev


@njit(cache=True)
def fixed_period_ratios(
    kind: int,
    p: _F,
    v: _F,
    plan: _F,
    period: int,
    f: float,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
) -> tuple[_F, _F]:
    """Per segment of the reconstruction (``kind``) of the records at positions ``p`` and velocity
    units ``v`` (floats: the plan's exact samples as well as integers), max |v| / 0x607F and max
    |a| / 0x60C5."""
    W, pad_l, pad_r, _ = _fp_layout(kind)
    n = len(p) - 1
    L = pad_l + n + 1 + pad_r
    T = float(period)
    q, u = np.zeros(4), np.zeros(4)
    rv, ra = np.empty(L - W + 1), np.empty(L - W + 1)
    for i in range(W - 1, L):
        for d in range(W):
            j = i - W + 1 + d - pad_l
            q[d] = p[min(max(j, 0), n)]
            u[d] = v[j] * f if 0 <= j <= n else 0.0
        rv[i - W + 1], ra[i - W + 1], _ = _fp_judge(
            kind, q[0], q[1], q[2], q[3], u[0], u[1], T, -1, n, plan, rv_per, ra_per, pos_lo, pos_hi
        )
    return rv, ra


@njit(cache=True)
def _fp_window(cp: _I, cv: _I, nc: _I, i: int, s: int, W: int, f: float, q: _F, u: _F) -> None:
    """The window of points i - W + 1 .. i - 1 for the state ``s`` (their choices, the newest the
    lowest digit of a mixed radix), into q (positions) and u (velocities, qc/ms)."""
    for d in range(1, W):
        c = s % nc[i - d]
        s //= nc[i - d]
        q[W - 1 - d], u[W - 1 - d] = cp[i - d, c], cv[i - d, c] * f


@njit(cache=True)
def track_fixed_period(
    kind: int,
    P: _I,
    V: _I,
    plan: _F,
    period: int,
    f: float,
    rv_per: float,
    ra_per: float,
    pos_lo: float,
    pos_hi: float,
    v_units: float,
    reach: int,
) -> tuple[_I, _I, float]:
    """The integer setpoints of a fixed-period axis whose reconstruction (``kind``) stays inside the
    limits, from their rounding ``P``, ``V``: the rounding itself where it is inside already, else
    the best combination of the candidates of every record between the first and the last, found
    exactly by a Viterbi pass over the reconstruction's windows (the state: the choices of a
    window's first points). Candidates: cubic_pv, the EPOS2 nudges (a count, two velocity units);
    a position alone, a count, and up to ``reach`` counts within ``reach`` points of a segment the
    rounding puts over a limit (where the plan's acceleration jumps between two records, a cubic
    through its samples overshoots: the records have to leave the plan there). The least slow-down
    the segments call for first (a bottleneck path), then, among the combinations that keep every
    segment under max(that, 1), the least summed excess over 1, then the closest to the plan.
    Returns the records' positions and velocities, and the slow-down they call for (1: none)."""
    W, pad_l, pad_r, at = _fp_layout(kind)
    n = len(P) - 1
    L = pad_l + n + 1 + pad_r
    T = float(period)
    rv, ra = fixed_period_ratios(kind, P * 1.0, V * 1.0, plan, period, f, rv_per, ra_per, pos_lo, pos_hi)
    plain = 1.0
    near = np.zeros(L, dtype=np.int64)  # per point: how far it may move off its rounding
    for w in range(len(rv)):
        need = slowdown(rv[w], ra[w])
        if not need <= 1.0 + LIMIT_RTOL:
            plain = max(plain, need)
            for j in range(max(w - reach, 0), min(w + W - 1 + reach, L - 1) + 1):
                near[j] = reach
    if plain == 1.0:
        return P.copy(), V.copy(), 1.0
    C = N_NUDGES if kind == CUBIC_PV else 2 * max(reach, 1) + 1
    cp, cv = np.empty((L, C), dtype=np.int64), np.zeros((L, C), dtype=np.int64)
    nc = np.ones(L, dtype=np.int64)
    for i in range(L):
        cp[i, 0] = P[min(max(i - pad_l, 0), n)]
        if pad_l <= i <= pad_l + n:
            cv[i, 0] = V[i - pad_l]
    for i in range(pad_l + 1, pad_l + n):  # the ends stay where the plan starts and stops
        m = 1
        for e in range(1, N_NUDGES if kind == CUBIC_PV else 2 * max(near[i], 1) + 1):
            dp, dv = (nudge_dp(e), nudge_dv(e)) if kind == CUBIC_PV else (_count_nudge(e), 0)
            p, v = cp[i, 0] + dp, cv[i, 0] + dv
            if pos_lo <= p <= pos_hi and abs(v) <= v_units:
                cp[i, m], cv[i, m] = p, v
                m += 1
        nc[i] = m
    # the verdicts of every (previous state, choice) of every point, laid end to end
    offset = np.zeros(L + 1, dtype=np.int64)
    for i in range(L):
        states = 1
        if i >= W - 1:
            for d in range(1, W):
                states *= nc[i - d]
        offset[i + 1] = offset[i] + states * nc[i]
    R = np.empty(offset[L])
    D = np.empty(offset[L])
    q, u = np.zeros(4), np.zeros(4)
    # pass 1: every segment's verdict, and the least slow-down (a bottleneck path)
    B = np.zeros(1)  # the first W - 1 points: the padding and record 0, one candidate each
    for i in range(W - 1, L):
        kept = 1  # the weight of the oldest digit of the previous state: the part the next state keeps
        for d in range(1, W - 1):
            kept *= nc[i - d]
        B_next = np.full(kept * nc[i], np.inf)
        k0 = i - W + 1 + at - pad_l
        for s in range(len(B)):
            _fp_window(cp, cv, nc, i, s, W, f, q, u)
            for c in range(nc[i]):
                q[W - 1], u[W - 1] = cp[i, c], cv[i, c] * f
                j = offset[i] + s * nc[i] + c
                r_v, r_a, D[j] = _fp_judge(
                    kind, q[0], q[1], q[2], q[3], u[0], u[1], T, k0, n, plan, rv_per, ra_per, pos_lo, pos_hi
                )
                R[j] = slowdown(r_v, r_a)
                s_next = (s % kept) * nc[i] + c
                B_next[s_next] = min(B_next[s_next], max(B[s], R[j]))
        B = B_next
    best = B[0]  # the last W - 1 points are the last record and the padding: one candidate each
    # pass 2: under max(best, 1), the least excess, then the closest to the plan (a shortest path)
    cap = max(best, 1.0 + LIMIT_RTOL)
    G = np.zeros(1)
    back = np.zeros(offset[L], dtype=np.int64)  # per point and next state: the previous state
    for i in range(W - 1, L):
        kept = 1
        for d in range(1, W - 1):
            kept *= nc[i - d]
        G_next = np.full(kept * nc[i], np.inf)
        for s in range(len(G)):
            if G[s] == np.inf:
                continue
            for c in range(nc[i]):
                j = offset[i] + s * nc[i] + c
                if not R[j] <= cap:
                    continue
                cost = G[s] + EXCESS_WEIGHT * max(R[j] - 1.0, 0.0) + D[j]
                s_next = (s % kept) * nc[i] + c
                if cost < G_next[s_next]:
                    G_next[s_next] = cost
                    back[offset[i] + s_next] = s
        G = G_next
    P_out, V_out = P.copy(), V.copy()
    s = 0
    for i in range(L - 1, W - 2, -1):
        c = s % nc[i]
        if pad_l < i < pad_l + n:
            P_out[i - pad_l], V_out[i - pad_l] = cp[i, c], cv[i, c]
        s = back[offset[i] + s]
    return P_out, V_out, max(best, 1.0)
