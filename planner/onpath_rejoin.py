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
so the tool stays on the path.

Any other path (several waypoints, a tool line through IK, a sequence's blends): the path speed s(t) itself, jerk
constant on each step, from the running (s, s', s'') to the delayed plan's (s_join, 1, 0). The joints' limits are not
linear in it there (the jerk's q''' s'^3 + 3 q'' s' s''), so each linear program has them linearised around the last
solution (sequential linear programs, a trust region on s', the most room under the limits asked so that the
linearisation's error stays inside them) and is repeated until the true ratios hold; the path's q'' and q''' are
taken over the drives' 10-ms jerk window, as they judge them (the records' cubics make q''' a sum of pulses). The
delay is looked for on 8-ms steps from the lag an S-curve in s' would add, the solution checked on 4-ms steps. The
caller judges the records (0x607F, 0x60C5, the window jerk within 1.2 x) as for any change. Pure: numbers in,
numbers out.
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
    """No re-timing of the rest of the path joins the planned timing within the limits."""


class NotALineError(NoRejoinError):
    """The rest of the path is not one line in joint space, along which one joint moves one way (``reference_of``)."""


def reference_of(
    planned: Trajectory, s0: float, max_jerk: NDArray[np.float64]
) -> tuple[int, NDArray[np.float64], float]:
    """(the reference joint: the largest travel against its jerk limit, every joint's travel per unit of its own, the
    sign of its travel). NotALineError where the rest of the path is not one line in joint space."""
    t = np.linspace(s0, planned.duration, 400)
    q = planned.position(t)
    travel = q[-1] - q[0]
    r = int(np.argmax(np.abs(travel) / np.asarray(max_jerk, dtype=float)))
    if abs(travel[r]) < 1e-12:
        raise NoRejoinError("the rest of the path does not move")
    c = travel / travel[r]
    off = q - q[0] - np.outer(q[:, r] - q[0, r], c)
    if np.any(np.abs(off) > LINE_TOLERANCE * np.maximum(np.abs(travel), 1e-9)):
        raise NotALineError("the rest of the path is not one line in joint space")
    sign = 1.0 if travel[r] > 0 else -1.0
    if np.any(np.diff(sign * q[:, r]) < -LINE_TOLERANCE * abs(travel[r])):
        raise NotALineError("the reference joint does not move one way along the rest of the path")
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
    # the variables: p, v, a at steps 1..n (index k - 1), the jerk on steps 0..n-1, |jerk| (smooth)
    ip, iv, ia, ij, ie = 0, n, 2 * n, 3 * n, 4 * n
    size = 5 * n if smooth else 4 * n
    a_eq, b_eq = _dynamics(start, n, size, STEP_S)
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
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=bounds, method="highs")
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


# --- any path: the path speed s(t), the joints' limits linearised around an iterate (sequential linear programs) ---
WINDOW_S = 0.005  # half the drives' 10-ms jerk window: the path's derivatives are taken over it (planner.knots)
SLP_ITERATIONS = 4  # linear programs per join tried, at most
SLP_GIVE_UP = 0.05  # a least excess over the linearised limits (of them) this large from the second program: no join
SLP_NEAR_GIVE_UP = 0.2  # a least excess this large in the first program from a neighbouring join's solution: no join
SLP_FAR = 1.15  # a true ratio to the limits this large from the second program: no join (it would not converge)
SLP_ACCEPT = 1.02  # the true (not linearised) ratio to the limits asked of a solution at its steps
COARSE_STEPS = 2  # a join is looked for on steps of this many STEP_S (each program a third the size), then checked
JOIN_BACK_S = (
    0.032  # the sooner join tried with the least delay: the plan's own last segment or two (30-60 ms on gantry3)
)
GUESS_SHARE = 1.3  # the first delay tried past the lag: this many times the S-curve's (``_ramp_lag_s``)
FINE_TRIES = 3  # delays tried in turn where the coarse solution does not hold at every STEP_S
MOST_DELAY_S = 0.5  # the most delay looked at on any path, past the lag: this, or the rest's plan time ...
MOST_DELAY_REST = 3.0  # ... times this where longer
SLP_MARGIN = 0.15  # the most room under the limits the programs look for (the linearisation errs by some)


class PathCoefficients:
    """The path's derivatives in s where a re-timing needs them: q' exactly, q'' and q''' over the drives' jerk
    window (central differences of q' over +-``WINDOW_S``). The program's path is the records' cubics: q'' jumps at
    every knot and q''' is a sum of pulses there, which the drives judge over a 10-ms window, not pointwise."""

    def __init__(self, planned: Trajectory) -> None:
        self.path = planned.path
        self.end = float(planned.gridpoints[-1])

    def __call__(self, s: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        h = WINDOW_S
        lo, hi = np.clip(s - h, 0.0, self.end), np.clip(s + h, 0.0, self.end)
        d1 = self.path(np.clip(s, 0.0, self.end), 1)
        d1_lo, d1_hi = self.path(lo, 1), self.path(hi, 1)
        d2 = (d1_hi - d1_lo) / np.maximum(hi - lo, 1e-9)[:, None]
        d3 = (d1_hi - 2.0 * d1 + d1_lo) / (h * h)
        return d1, d2, d3


def path_ratios(
    coef: PathCoefficients, x: NDArray[np.float64], jerk: NDArray[np.float64], lim: NDArray[np.float64]
) -> float:
    """The joints' largest |velocity|, |acceleration|, |jerk| (on both steps at every point) of ``lim`` (3, dof)
    along s(t): ``x`` (n + 1, 3) the states (s, s', s'') at every step, ``jerk`` (n,) s''' on each; the jerk at
    every step but the last (the join: the plan's jerk from there on, ``_path_program``)."""
    d1, d2, d3 = coef(x[:, 0])
    v, a = x[:, 1:2], x[:, 2:3]
    vel = np.abs(d1 * v) / lim[0]
    acc = np.abs(d2 * v * v + d1 * a) / lim[1]
    base = d3 * v**3 + 3.0 * d2 * v * a
    w_before = np.concatenate(([jerk[0]], jerk))[:, None]
    w_after = np.concatenate((jerk, [jerk[-1]]))[:, None]
    jrk = np.maximum(np.abs(base + d1 * w_before), np.abs(base + d1 * w_after))[:-1] / lim[2]
    return float(max(vel.max(), acc.max(), jrk.max()))


def _integrate(start: tuple[float, float, float], jerk: NDArray[np.float64], h: float) -> NDArray[np.float64]:
    """(s, s', s'') at every step (of ``h``) from ``start`` with s''' = ``jerk`` on each."""
    out = np.empty((len(jerk) + 1, 3))
    out[0] = start
    for k, w in enumerate(jerk):
        p, v, a = out[k]
        out[k + 1] = (p + v * h + a * h * h / 2.0 + w * h**3 / 6.0, v + a * h + w * h * h / 2.0, a + w * h)
    return out


def _guess(start: tuple[float, float, float], n: int, end: tuple[float, float, float], h: float) -> NDArray[np.float64]:
    """(s, s', s'') at every step of the quintic in t from ``start`` to ``end`` over ``n`` steps: a first iterate."""
    T = n * h
    a0, a1, a2 = start[0], start[1], start[2] / 2.0
    m = np.array([[T**3, T**4, T**5], [3 * T**2, 4 * T**3, 5 * T**4], [6 * T, 12 * T**2, 20 * T**3]])
    rhs = np.array([end[0] - (a0 + a1 * T + a2 * T * T), end[1] - (a1 + 2 * a2 * T), end[2] - 2 * a2])
    a3, a4, a5 = np.linalg.solve(m, rhs)
    t = h * np.arange(n + 1)
    s = a0 + t * (a1 + t * (a2 + t * (a3 + t * (a4 + t * a5))))
    v = a1 + t * (2 * a2 + t * (3 * a3 + t * (4 * a4 + t * 5 * a5)))
    a = 2 * a2 + t * (6 * a3 + t * (12 * a4 + t * 20 * a5))
    return np.column_stack((s, np.maximum(v, 0.0), a))


def _resampled(prev: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """A solution over another number of steps as the iterate for ``n`` steps (its profile stretched in time)."""
    m = len(prev) - 1
    u, k = np.linspace(0.0, 1.0, n + 1), np.linspace(0.0, 1.0, m + 1)
    return np.column_stack([np.interp(u, k, prev[:, i]) for i in range(3)])


def _dynamics(
    start: tuple[float, float, float], n: int, nvar: int, h: float
) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
    """x_k+1 = F x_k + g j_k (k = 0..n-1), x_0 = ``start``: the variables p, v, a at steps 1..n, then j on 0..n-1."""
    ip, iv, ia, ij = 0, n, 2 * n, 3 * n
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
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * n, nvar)), np.asarray(rhs)


class _Rows:
    """Rows |sum(c * x) + const| <= L (1 + slack) of a linear program, both signs, gathered as sparse triplets."""

    def __init__(self, slack: int) -> None:
        self.slack = slack
        self.rows: list[NDArray[np.int64]] = []
        self.cols: list[NDArray[np.int64]] = []
        self.vals: list[NDArray[np.float64]] = []
        self.b: list[NDArray[np.float64]] = []
        self.count = 0

    def add(self, terms: list[tuple[NDArray[np.int64], NDArray[np.float64]]], const: NDArray[np.float64], L: float):
        m = len(const)
        for sign in (1.0, -1.0):
            idx = self.count + np.arange(m)
            for var, c in terms:
                self.rows.append(idx)
                self.cols.append(np.broadcast_to(var, (m,)))
                self.vals.append(sign * np.broadcast_to(c, (m,)))
            self.rows.append(idx)
            self.cols.append(np.full(m, self.slack))
            self.vals.append(np.full(m, -L))
            self.b.append(L - sign * const)
            self.count += m

    def matrix(self, nvar: int) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
        a = sp.csr_matrix(
            (np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
            shape=(self.count, nvar),
        )
        return a, np.concatenate(self.b)


def _path_program(
    coef: PathCoefficients,
    start: tuple[float, float, float],
    n: int,
    end: tuple[float, float, float],
    lim: NDArray[np.float64],
    iterate: NDArray[np.float64],
    h: float,
    in_time: Callable[[], bool] | None,
    near: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """s(t) over ``n`` steps from ``start`` to ``end`` (s, s', s'') with s''' constant on each step whose joints hold
    ``lim`` (3, dof: |velocity|, |acceleration|, |jerk|) at every step: linear programs with the joints' limits
    linearised around ``iterate`` (the coefficients at its s, the products of s' and s'' at its values, s' within a
    trust region of it) and one slack on all of them (the least), each from the last one's solution until the true
    ratios hold; (the states at every step, the jerk on each), None: none found (``near``: ``iterate`` is the solution
    of a neighbouring join, so that the first program's slack already tells: more than ``SLP_NEAR_GIVE_UP``, none)."""
    dof = lim.shape[1]
    ip, iv, ia, ij, isg = 0, n, 2 * n, 3 * n, 4 * n
    nvar = 4 * n + 1
    a_eq, b_eq = _dynamics(start, n, nvar, h)
    x_bar = iterate
    radius = 0.3
    k = np.arange(1, n)  # the points whose states are variables; the ends' are fixed
    for it in range(SLP_ITERATIONS):
        if in_time is not None and not in_time():
            raise NoRejoinError("the drives would need the change's records before it is made")
        d1, d2, d3 = coef(x_bar[:, 0])
        vb, ab = x_bar[:, 1], x_bar[:, 2]
        rows = _Rows(isg)
        for j in range(dof):
            vl, al, jl = (float(x) for x in lim[:, j])
            c1, c2, c3 = d1[k, j], d2[k, j], d3[k, j]
            fast = np.abs(c1) * (vb[k] + radius) > vl  # elsewhere the trust region holds 0x607F
            if fast.any():
                rows.add([(iv + k[fast] - 1, c1[fast])], np.zeros(int(fast.sum())), vl)
            rows.add([(iv + k - 1, 2.0 * c2 * vb[k]), (ia + k - 1, c1)], -c2 * vb[k] ** 2, al)
            if not np.isfinite(jl):
                continue
            # d3 v^3 + 3 d2 v a + d1 j around (vb, ab), on the step before the point and the one after
            jv = 3.0 * c3 * vb[k] ** 2 + 3.0 * c2 * ab[k]
            ja = 3.0 * c2 * vb[k]
            jc = -2.0 * c3 * vb[k] ** 3 - 3.0 * c2 * vb[k] * ab[k]
            for w in (ij + k - 1, ij + k):
                rows.add([(iv + k - 1, jv), (ia + k - 1, ja), (w, c1)], jc, jl)
            # the start's own state: its step's jerk (the join's is the plan's from there: its jerk jumps to the plan's)
            const = d3[0, j] * vb[0] ** 3 + 3.0 * d2[0, j] * vb[0] * ab[0]
            rows.add([(np.array([ij]), np.array([d1[0, j]]))], np.array([const]), jl)
        a_ub, b_ub = rows.matrix(nvar)
        bounds: list[tuple[float | None, float | None]] = [(None, None)] * n
        bounds += [(max(0.0, float(v) - radius), float(v) + radius) for v in vb[1 : n + 1]]
        bounds += [(None, None)] * (2 * n) + [(-SLP_MARGIN, None)] + [(0.0, None)] * (nvar - 4 * n - 1)
        bounds[ip + n - 1] = (end[0], end[0])
        bounds[iv + n - 1] = (end[1], end[1])
        bounds[ia + n - 1] = (end[2], end[2])
        cost = np.zeros(nvar)
        cost[isg] = 1.0
        res = linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=bounds, method="highs")
        if res.status != 0:
            return None
        jerk = res.x[ij : ij + n]
        states = _integrate(start, jerk, h)
        ratio = path_ratios(coef, states, jerk, lim)
        if ratio <= SLP_ACCEPT:
            return states, jerk
        if (it >= 1 or (near and res.x[isg] > SLP_NEAR_GIVE_UP)) and (res.x[isg] > SLP_GIVE_UP or ratio > SLP_FAR):
            return None
        x_bar = states
        radius *= 0.6
    return None


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
    return _bisect(feasible, below, k)


def _least_from(feasible: Callable[[int], bool], guess: int, lo: int, hi: int) -> int | None:
    """``_least`` from a ``guess``: downwards from it in doubling steps where it holds, upwards where not, then
    bisection (a good guess: a few tries)."""
    k = min(max(guess, lo), hi)
    step = 1
    if feasible(k):
        top = k
        while top > lo:
            k = max(lo, top - step)
            if not feasible(k):
                break
            top, step = k, step * 2
        else:
            return top
        below = k
    else:
        below = k
        while True:
            if below >= hi:
                return None
            k = min(hi, below + step)
            if feasible(k):
                break
            below, step = k, step * 2
        top = k
    return _bisect(feasible, below, top)


def _bisect(feasible: Callable[[int], bool], below: int, top: int) -> int:
    """The least integer in (``below``, ``top``] at which ``feasible`` holds, known to hold at ``top``."""
    while top - below > 1:
        mid = (below + top) // 2
        if feasible(mid):
            top = mid
        else:
            below = mid
    return top


def _ramp_lag_s(v0: float, a0: float, amax: float, jmax: float) -> float:
    """The lag an S-curve in path speed adds from s' = ``v0`` (s'' = ``a0``) up to s' = 1 within |s''| <= ``amax``
    and |s'''| <= ``jmax`` (the joints' limits over |q'| where it starts, the path's bend not counted): where the
    delay is first looked for (gantry3's bent path: 13 of the 20 grid steps it needs, arm6's 4.5 of 5)."""
    h, v, a, lost = 1e-3, v0, a0, 0.0
    for _ in range(2000):
        if v >= 1.0:
            break
        a = min(amax, a + jmax * h) if 1.0 - v > a * a / (2.0 * jmax) else max(0.0, a - jmax * h)
        v += max(a, 1e-3) * h
        lost += (1.0 - min(v, 1.0)) * h
    return lost


def _rejoin_along_path(
    planned: Trajectory,
    start: tuple[float, float, float],
    t0: float,
    lim: NDArray[np.float64],
    grid_s: float,
    phase_s: float,
    in_time: Callable[[], bool] | None,
) -> tuple[NDArray[np.float64], int, float]:
    """``rejoin_plan`` on any path: the path speed s(t) from ``start`` (s, s', s'' at ``t0``) to the plan's (s_join,
    1, 0) by ``_path_program`` on steps of ``COARSE_STEPS`` x ``STEP_S``: the fewest grid steps of delay, joined
    ``MIN_TAIL_S`` before the plan's end, looked for from ``_ramp_lag_s``, then joined ``JOIN_BACK_S`` sooner where
    that holds with the same delay (one try, not the soonest: each is a few linear programs, made while the drives'
    lock is held, and the motion's end is the same); the solution checked at every ``STEP_S``
    (its jerk constant on each, ``path_ratios``), re-solved on them where it does not hold, one grid step later where
    that fails too; (the states at every ``STEP_S``, their steps, the delay)."""
    coef = PathCoefficients(planned)
    s0 = start[0]
    last = float(planned.gridpoints[-1]) - MIN_TAIL_S
    big = COARSE_STEPS * STEP_S
    found: dict[tuple[int, int], NDArray[np.float64]] = {}
    warm: list[NDArray[np.float64]] = []

    def steps_to(s_join: float, delay: float) -> int:
        return math.floor((s_join + delay - t0) / big + 1e-9)

    def joins(delay_steps: int, n: int) -> bool:
        if (delay_steps, n) in found:
            return True
        delay = delay_steps * grid_s + phase_s
        s_join = t0 + n * big - delay
        if n < 2 or s_join <= s0 or s_join > last + 1e-9:
            return False
        end = (s_join, 1.0, 0.0)
        first = _resampled(warm[-1], n) if warm else _guess(start, n, end, big)
        first[0], first[-1] = start, end
        out = _path_program(coef, start, n, end, lim, first, big, in_time, near=bool(warm))
        if out is None:
            return False
        warm.append(out[0])
        found[(delay_steps, n)] = out[1]
        return True

    def fine(delay_steps: int, n: int) -> NDArray[np.float64] | None:
        jerk = np.repeat(found[(delay_steps, n)], COARSE_STEPS)
        states = _integrate(start, jerk, STEP_S)
        if path_ratios(coef, states, jerk, lim) <= SLP_ACCEPT:
            return states
        out = _path_program(coef, start, len(jerk), tuple(states[-1]), lim, states, STEP_S, in_time)
        return None if out is None else out[0]

    lag = max(0, math.ceil((t0 - s0 - phase_s) / grid_s - 1e-9))  # delayed by at least the lag it has now
    # the most delay looked at: a join later than braking to rest and starting again would take is no join worth it
    most = min(MAX_DELAY_STEPS, math.ceil(max(MOST_DELAY_S, MOST_DELAY_REST * (last - s0)) / grid_s))
    d1 = np.abs(coef(np.array([s0]))[0][0])
    moving = d1 > 1e-9 * max(float(d1.max()), 1e-30)
    amax, jmax = (float(np.min(lim[i][moving] / d1[moving])) for i in (1, 2))
    guess = lag + round(GUESS_SHARE * _ramp_lag_s(start[1], start[2], amax, jmax) / grid_s)
    least = lag
    for _ in range(FINE_TRIES):
        delay_steps = _least_from(
            lambda k: joins(k, steps_to(last, k * grid_s + phase_s)), max(guess, least), least, lag + most
        )
        if delay_steps is None:
            break
        delay = delay_steps * grid_s + phase_s
        n = steps_to(last, delay)
        back = n - round(JOIN_BACK_S / big)  # the plan's own records for its last segments: one try
        if joins(delay_steps, back) and (x := fine(delay_steps, back)) is not None:
            return x, back * COARSE_STEPS, delay
        x = fine(delay_steps, n)
        if x is not None:
            return x, n * COARSE_STEPS, delay
        least = delay_steps + 1
    raise NoRejoinError("no re-timing of the rest of the path joins the planned timing within the limits")


def _rejoin_on_line(
    planned: Trajectory,
    t0: float,
    s0: float,
    sd0: float,
    sdd0: float,
    ref: int,
    c: NDArray[np.float64],
    sign: float,
    limits: JointLimits,
    jmax_j: NDArray[np.float64],
    grid_s: float,
    share: float,
    jerk_share: float,
    in_time: Callable[[], bool] | None,
    phase_s: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, float]:
    """``rejoin_plan`` on a line in joint space: the linear program on the reference joint ``ref`` (``reference_of``);
    (s, s', t at every step, the plan's s where it joins, the delay)."""
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
    u1 = max(q1, 1e-12)  # u' on the plan where it starts: the S-curve's path speed in its units
    ramp = _ramp_lag_s(start[1] / u1, start[2] / u1, amax / u1, jmax / u1)
    delay_steps = _least_from(
        lambda k: joins(k, steps_to(last, k * grid_s + phase_s)) is not None,
        lag + round(GUESS_SHARE * ramp / grid_s),
        lag,
        lag + MAX_DELAY_STEPS,
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
    return grid_new, sd_new, t_new, s_join, delay


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
    try:
        ref, c, sign = reference_of(planned, s0, jmax_j)
    except NotALineError:  # any other path: its path speed
        lim = np.vstack(
            (
                np.asarray(limits.velocity, dtype=float),
                share * np.asarray(limits.acceleration, dtype=float),
                jerk_share * jmax_j,
            )
        )
        x, n, delay = _rejoin_along_path(planned, (s0, sd0, sdd0), t0, lim, grid_s, phase_s, in_time)
        grid_new, sd_new, t_new = x[:, 0], x[:, 1], t0 + STEP_S * np.arange(n + 1)
        s_join = float(grid_new[-1])
    else:
        grid_new, sd_new, t_new, s_join, delay = _rejoin_on_line(
            planned, t0, s0, sd0, sdd0, ref, c, sign, limits, jmax_j, grid_s, share, jerk_share, in_time, phase_s
        )
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
