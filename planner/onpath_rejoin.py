"""Back to the planned timing within the jerk limit where no S-curve in path speed can (issue 37, override 1.0).

Why no S-curve can: along a program's path (s = the plan's time) the joints' jerk is q'''(s) s'^3 + 3 q''(s) s' s''
+ q'(s) s'''. A jerk-limited time-optimal plan decelerates at its jerk limit from its cruise to rest (gantry3's move
in bench/onpath_service.py: q''' = J for all of its last 0.2 s, the acceleration 0 -> 0.89 x 0x60C5 -> 0, no
stretch at constant deceleration). An S-curve in s that reaches s' = 1 inside that stretch adds its s'' and s'''
terms to q''' = J (1.36-2.06 x the limit on the 10-ms window, bench/RESULTS.md), and late in the motion no S-curve
from the running speed ends before the stretch begins. So the planned timing can only be joined there on the plan's
own curve to rest, as a time-optimal braking from a lower speed meets the one from a higher speed, both at the jerk
limit: the rest of the path is re-timed, not its speed scaled, and joins the plan delayed by whole grid steps.

How: for a path along one line in joint space (a joint move, the gantry's straight moves), every joint is
q_j = q_j(s0) + c_j (u - u(s0)) of one reference joint's position u (the joint with the largest travel against its
jerk limit), so the joints' limits are bounds on u's derivatives (the share of 0x60C5 and of the jerk limit asked,
0x607F). A linear program on u(t), jerk constant on each ``STEP_S``, from the running state (u, u', u'') to the
delayed plan's state where it joins: the fewest grid steps of delay for which it joins at all (by bisection, joining
``MIN_TAIL_S`` before the plan's end: any later join holds with the same delay), then the soonest join with that
delay (bisection), the least summed jerk. The path positions are s(t) = u^-1(u(t)) until the join, the plan's after,
so the tool stays on the path. Other paths: NoRejoinError (the caller's fallback: the highest scale whose S-curve
holds). Pure: numbers in, numbers out.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.optimize import linprog

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.onpath_stop import REST_SD, _s_at, _sd_at
from pvtflow.planner.trajectory import Trajectory

STEP_S = 0.004  # the program's step: the drives judge jerk over 10 ms windows (planner.knots.window_jerk)
LINE_TOLERANCE = 1e-3  # a joint's largest distance from the line, of its travel: farther, the path is not a line
MAX_DELAY_STEPS = 400  # the most grid steps of delay looked at past the lag at the change
MIN_TAIL_S = 0.02  # the latest join, before the plan's end: planned records left to join


class NoRejoinError(ValueError):
    """No re-timing of the rest of the path joins the planned timing within the limits (or the path is no line)."""


def reference_of(
    planned: Trajectory, s0: float, max_jerk: NDArray[np.float64]
) -> tuple[int, NDArray[np.float64], float]:
    """(the reference joint: the largest travel against its jerk limit, every joint's travel per unit of its own, the
    sign of its travel). NoRejoinError where the rest of the path is not one line in joint space."""
    t = np.linspace(s0, planned.duration, 400)
    q = planned.position(t)
    travel = q[-1] - q[0]
    r = int(np.argmax(np.abs(travel) / np.asarray(max_jerk, dtype=float)))
    if abs(travel[r]) < 1e-12:
        raise NoRejoinError("the rest of the path does not move")
    c = travel / travel[r]
    off = q - q[0] - np.outer(q[:, r] - q[0, r], c)
    if np.any(np.abs(off) > LINE_TOLERANCE * np.maximum(np.abs(travel), 1e-9)):
        raise NoRejoinError("the rest of the path is not one line in joint space")
    sign = 1.0 if travel[r] > 0 else -1.0
    if np.any(np.diff(sign * q[:, r]) < -LINE_TOLERANCE * abs(travel[r])):
        raise NoRejoinError("the reference joint does not move one way along the rest of the path")
    return r, c, sign


def _program(
    start: tuple[float, float, float],
    n: int,
    end: tuple[float, float, float],
    vmax: float,
    amax: float,
    jmax: float,
    smooth: bool = False,
) -> NDArray[np.float64] | None:
    """(u, u', u'') at every step (row 0: ``start``, row ``n``: ``end``) with |u'''| <= ``jmax`` (constant on each
    step), |u''| <= ``amax``, 0 <= u' <= ``vmax``; the least jerk summed over the steps (``smooth``; else any: whether
    there is one); None: none."""
    h = STEP_S
    # the variables: p, v, a at steps 1..n (index k - 1), the jerk on steps 0..n-1, |jerk| (smooth); x_k+1 = F x_k + g j
    ip, iv, ia, ij, ie = 0, n, 2 * n, 3 * n, 4 * n
    f = ((1.0, h, h * h / 2.0), (0.0, 1.0, h), (0.0, 0.0, 1.0))
    g = (h**3 / 6.0, h * h / 2.0, h)
    rows: list[int] = []
    cols: list[int] = []
    vals: list[float] = []
    rhs: list[float] = []
    for k in range(n):
        for m, base in enumerate((ip, iv, ia)):
            r = 3 * k + m
            rows += [r, r]
            cols += [base + k, ij + k]
            vals += [1.0, -g[m]]
            if k == 0:
                rhs.append(sum(f[m][i] * start[i] for i in range(3)))
                continue
            rhs.append(0.0)
            for i, b in enumerate((ip, iv, ia)):
                if f[m][i] != 0.0:
                    rows.append(r)
                    cols.append(b + k - 1)
                    vals.append(-f[m][i])
    size = 5 * n if smooth else 4 * n
    a_eq = sp.csr_matrix((vals, (rows, cols)), shape=(3 * n, size))
    bounds = [(None, None)] * n + [(0.0, vmax)] * n + [(-amax, amax)] * n + [(-jmax, jmax)] * n
    bounds[ip + n - 1] = (end[0], end[0])
    bounds[iv + n - 1] = (end[1], end[1])
    bounds[ia + n - 1] = (end[2], end[2])
    cost = np.zeros(size)
    a_ub = b_ub = None
    if smooth:  # |jerk_k| <= e_k, the e_k summed
        k = np.arange(n)
        a_ub = sp.csr_matrix(
            (
                np.concatenate((np.ones(n), -np.ones(n), -np.ones(n), -np.ones(n))),
                (np.concatenate((k, k, n + k, n + k)), np.concatenate((ij + k, ie + k, ij + k, ie + k))),
            ),
            shape=(2 * n, size),
        )
        b_ub = np.zeros(2 * n)
        bounds += [(0.0, None)] * n
        cost[ie:] = 1.0
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=np.asarray(rhs), bounds=bounds, method="highs")
    if res.status != 0:
        return None
    x = res.x
    return np.column_stack(
        (
            np.concatenate(([start[0]], x[ip : ip + n])),
            np.concatenate(([start[1]], x[iv : iv + n])),
            np.concatenate(([start[2]], x[ia : ia + n])),
        )
    )


def _least(feasible: Callable[[int], bool], lo: int, hi: int, hi_holds: bool = False) -> int | None:
    """The least integer in [lo, hi] at which ``feasible`` (false below it, true from it on) holds, None: none;
    from ``lo`` upwards in doubling steps, then bisection (``hi_holds``: known to hold at ``hi``, bisection only)."""
    step, below = 1, lo - 1
    k = hi if hi_holds else lo
    while not feasible(k):
        below = k
        if k >= hi:
            return None
        k = min(hi, k + step)
        step *= 2
    while k - below > 1:
        mid = (below + k) // 2
        if feasible(mid):
            k = mid
        else:
            below = mid
    return k


def rejoin_plan(
    planned: Trajectory,
    running: Trajectory,
    t0_s: float,
    limits: JointLimits,
    max_jerk: NDArray[np.float64],
    grid_s: float,
    share: float,
    jerk_share: float,
    in_time: Callable[[], bool] | None = None,
    phase_s: float = 0.0,
) -> tuple[Trajectory, float, float]:
    """The rest of ``running`` from ``t0_s`` re-timed to join ``planned`` delayed by the fewest whole grid steps (plus
    ``phase_s``: a resume's rest, which need not be a grid time), as early as that delay allows, within ``share`` of
    0x60C5, ``jerk_share`` of ``max_jerk`` (joint units/s^3) and 0x607F until it joins; (the whole motion, program
    time; the plan's s where it joins; the delay, s). NoRejoinError where none joins it ``MIN_TAIL_S`` before its end,
    or where ``in_time`` (asked before each linear program) says the change's records would come too late (on the
    wall clock the drives run on meanwhile)."""
    jmax_j = np.asarray(max_jerk, dtype=float)
    t0 = float(np.clip(t0_s, 0.0, running.duration))
    s0, sd0 = _s_at(running, t0), _sd_at(running, t0)
    i = int(np.clip(np.searchsorted(running.breakpoints, t0, side="right") - 1, 0, len(running.sdd) - 1))
    sdd0 = float(running.sdd[i])
    if sd0 < REST_SD or t0 >= running.duration - 1e-9:  # at rest (a braking's end, to rounding): a resume's start
        sd0, sdd0 = 0.0, 0.0
    ref, c, sign = reference_of(planned, s0, jmax_j)
    end = planned.duration

    def state(s: float) -> tuple[float, float, float]:  # the reference joint on the plan at s (s' = 1)
        t = np.array([s])
        return tuple(float(sign * f(t)[0, ref]) for f in (planned.position, planned.velocity, planned.acceleration))

    p0, q1, q2 = state(s0)
    start = (p0, q1 * sd0, q2 * sd0 * sd0 + q1 * sdd0)
    moving = np.abs(c) > 1e-12
    vmax = float(np.min(np.asarray(limits.velocity, dtype=float)[moving] / np.abs(c[moving])))
    amax = share * float(np.min(np.asarray(limits.acceleration, dtype=float)[moving] / np.abs(c[moving])))
    jmax = jerk_share * float(np.min(jmax_j[moving] / np.abs(c[moving])))
    last = end - MIN_TAIL_S  # the latest join: planned records left to run after it

    def steps_to(s_join: float, delay: float) -> int:  # the program's steps from t0 to where it joins at s_join
        return math.floor((s_join + delay - t0) / STEP_S + 1e-9)

    def joins(delay_steps: int, n: int, smooth: bool = False) -> NDArray[np.float64] | None:
        delay = delay_steps * grid_s + phase_s
        s_join = t0 + n * STEP_S - delay
        if n < 2 or s_join <= s0 or s_join > last + 1e-9:
            return None
        if in_time is not None and not in_time():
            raise NoRejoinError("the drives would need the change's records before it is made")
        return _program(start, n, state(s_join), vmax, amax, jmax, smooth)

    lag = max(0, math.ceil((t0 - s0 - phase_s) / grid_s - 1e-9))  # delayed by at least the lag it has now
    delay_steps = _least(
        lambda k: joins(k, steps_to(last, k * grid_s + phase_s)) is not None, lag, lag + MAX_DELAY_STEPS
    )
    if delay_steps is None:
        raise NoRejoinError("no re-timing of the rest of the path joins the planned timing within the limits")
    delay = delay_steps * grid_s + phase_s
    first = steps_to(s0, delay) + 1
    n = _least(lambda k: joins(delay_steps, k) is not None, first, steps_to(last, delay), hi_holds=True)
    out = joins(delay_steps, n, smooth=True) if n is not None else None
    if out is None:
        raise NoRejoinError("no re-timing of the rest of the path joins the planned timing within the limits")
    s_join = t0 + n * STEP_S - delay
    # the path positions s(t) = u^-1(u(t)) until the join (u along the rest of the plan, densely), the plan's after
    s_dense = np.linspace(s0, s_join, max(2, math.ceil((s_join - s0) / 5e-5) + 1))
    u_dense = np.maximum.accumulate(sign * planned.position(s_dense)[:, ref])
    s_new = np.interp(out[1:n, 0], u_dense, s_dense)
    u1 = sign * planned.velocity(s_new)[:, ref]
    grid_new = np.concatenate(([s0], s_new, [s_join]))
    sd_new = np.concatenate(([sd0], out[1:n, 1] / np.maximum(u1, 1e-12), [1.0]))
    t_new = t0 + STEP_S * np.arange(n + 1)
    keep = np.concatenate(([True], np.diff(grid_new) > 1e-12))
    keep[-1] = True
    grid_new, sd_new, t_new = grid_new[keep], sd_new[keep], t_new[keep]
    before = running.gridpoints < s0 - 1e-12
    after = planned.gridpoints > s_join + 1e-9
    grid = np.concatenate((running.gridpoints[before], grid_new, planned.gridpoints[after]))
    sd = np.concatenate((running.sd[before], sd_new, np.ones(int(after.sum()))))
    times = np.concatenate((running.breakpoints[before], t_new, planned.gridpoints[after] + delay))
    dt = np.diff(times)
    if np.any(dt <= 0.0) or np.any(np.diff(grid) <= 0.0):
        raise NoRejoinError("the re-timing does not move forward along the path")
    sdd = 2.0 * (np.diff(grid) - sd[:-1] * dt) / (dt * dt)
    return Trajectory(running.path, grid, sd, sdd, times, running.joint_names), s_join, delay
