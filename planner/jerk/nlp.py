"""The jerk-limited timing's nonlinear program (casadi): its variables, rows and objective, and
their numbers on one grid (the rows' coefficients, the bounds, the parameters, the scales).

- a grid s_0 < ... < s_N along the path that contains every waypoint, so that each interval
  lies in one cubic piece of the path spline (q_sss constant on it);
- on interval k the path parameter is a cubic in time: constant s''' = j_k for a time h_k,
  from the state (s', s'') = (sd_k, a_k) at s_k; the state at s_(k+1) follows from it (the
  gap-closing rows) and the distance it covers is exactly s_(k+1) - s_k (one equality per
  interval). Acceleration is continuous, jerk piecewise constant: what a drive's cubic
  segments reproduce best;
- inside the interval the path is a cubic in sigma = s - s_k, so q_s, q_ss, q_sss there are
  exact polynomials in sigma, and every joint velocity, acceleration and jerk sample is an
  exact polynomial in the interval's variables: the rows hold at their samples exactly, not
  through a linearisation;
- rows: joint velocity at the gridpoints (a box on sd_k, merged with the TCP speed bound) and
  in the middle of every interval; joint acceleration at the start and the middle; joint
  jerk at the start, the middle and the end (jerk jumps at gridpoints); joint torque (the
  same RNEA rows as TOPP-RA's collocation) at the gridpoints; TCP speed at the gridpoints and,
  with the frame's speed factor of the interval's midpoint in s, in the middle;
- objective: the duration, sum of h_k.

The program is built once per shape (intervals, joints, torque rows) and kept with its
solvers (``planner.jerk.solve``); a path's numbers are its parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np
import toppra.constraint as constraint
from numpy.typing import NDArray

from pvtflow.planner.jerk.trajectory import interval_coefficients
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath
from pvtflow.planner.timing import (
    IntervalJointAccelerationConstraint,
    IntervalJointVelocityConstraint,
    RneaJointTorqueConstraint,
    TcpAngularSpeedConstraint,
    TcpSpeedConstraint,
)

# bounds on a speed |G(s) q_s| s' <= limit (the joint velocity, the TCP's linear and angular speed)
_SPEED_CONSTRAINTS = (IntervalJointVelocityConstraint, TcpSpeedConstraint, TcpAngularSpeedConstraint)


@dataclass(frozen=True)
class Rows:
    """What the program's rows are made of on one grid: numbers only, (n, dof) unless said."""

    D: NDArray[np.float64]  # (n,) interval lengths in s
    q1: NDArray[np.float64]  # q_s at the interval starts
    q2: NDArray[np.float64]  # q_ss at the interval starts
    q3: NDArray[np.float64]  # q_sss on the intervals
    e1: NDArray[np.float64]  # q_s at the interval ends (on the interval's own piece)
    e2: NDArray[np.float64]  # q_ss at the interval ends (on the interval's own piece)
    sd_max: NDArray[np.float64]  # (n + 1,) bound on s' at the gridpoints (joint and TCP speed; 0: a stop)
    sd_max_mid: NDArray[np.float64]  # (n,) bound on s' in the middle of the intervals (TCP speed; inf)
    torque: tuple[NDArray[np.float64], ...] | None  # a, b, lo, hi: lo <= a s'' + b s'^2 <= hi at the starts


# variables per stage: the state (s', s'') at the gridpoint, then the interval's controls: its time,
# its jerk s''', and sigma and s' at fixed fractions of its time (lifted: the rows there are then
# low-degree polynomials of few variables, which halves the work of the Hessian and the Jacobian)
FRACTIONS = (0.5,)  # where in time the joint velocity and acceleration rows are held (bench/RESULTS.md)
_MIDDLE_INDEX = 0  # the fraction that is the middle (jerk and TCP speed rows there)
STATE = ("sd", "a")
CONTROL = ("h", "j", *(f"sigma_{i}" for i in range(len(FRACTIONS))), *(f"sd_{i}" for i in range(len(FRACTIONS))))
_EQUALITIES = 3 + 2 * len(FRACTIONS)  # per stage: the next state (2), the distance, sigma and s' at the fractions
_JERK_ROWS = 3  # per joint: start, middle, end
PER_STAGE = ("q1", "q2", "q3", "e1", "e2", "ta", "tb")  # the path's numbers per stage, dof each (``Rows``)


def stage_function(dof: int, torque: bool) -> ca.Function:
    """The rows of one interval: (its variables and numbers) -> the state at its end, then the
    distance and lifted residuals and its inequality rows (normalised to [-1, 1] but torque's)."""
    m = len(FRACTIONS)
    sd, a, h, j = (ca.SX.sym(n) for n in (*STATE, *CONTROL[:2]))
    sgs = [ca.SX.sym(f"sigma_{i}") for i in range(m)]
    sds = [ca.SX.sym(f"sd_{i}") for i in range(m)]
    D = ca.SX.sym("D")
    q1, q2, q3, e1, e2, ta, tb = (ca.SX.sym(n, dof) for n in ("q1", "q2", "q3", "e1", "e2", "ta", "tb"))
    inv_v, inv_a, inv_j = (ca.SX.sym(n, dof) for n in ("inv_v", "inv_a", "inv_j"))

    def at(tau: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        """sigma, s', s'' at time tau into the interval."""
        return tau * (sd + tau * (0.5 * a + tau * j / 6.0)), sd + tau * (a + 0.5 * j * tau), a + j * tau

    def jerk(q_s: ca.SX, q_ss: ca.SX, s_d: ca.SX, s_dd: ca.SX) -> ca.SX:
        return (q3 * s_d**3 + 3.0 * q_ss * (s_d * s_dd) + q_s * j) * inv_j

    sg1, sd1, a1 = at(h)
    rows = [(q2 * sd**2 + q1 * a) * inv_a]
    if torque:
        rows.append(ta * a + tb * sd**2)
    residual = [(sg1 - D) / D]
    jerk_mid = ca.SX.zeros(dof)
    for i, f in enumerate(FRACTIONS):
        sg_h, sd_h, a_f = at(f * h)
        residual += [sgs[i] - sg_h, sds[i] - sd_h]
        q_s, q_ss = q1 + sgs[i] * (q2 + 0.5 * sgs[i] * q3), q2 + sgs[i] * q3  # the path there, exactly
        rows += [q_s * sds[i] * inv_v, (q_ss * sds[i] ** 2 + q_s * a_f) * inv_a]
        if i == _MIDDLE_INDEX:
            jerk_mid = jerk(q_s, q_ss, sds[i], a_f)
    rows += [jerk(q1, q2, sd, a), jerk_mid, jerk(e1, e2, sd1, a1)]  # the end: sigma = D once the distance holds
    inputs = [sd, a, h, j, *sgs, *sds, D, q1, q2, q3, e1, e2, inv_v, inv_a, inv_j, ta, tb]
    return ca.Function("stage", inputs, [ca.vertcat(sd1, a1), ca.vertcat(*residual), ca.vertcat(*rows)])


def stage_rows(
    stage: ca.Function,
    x: ca.SX,
    u: ca.SX,
    x_next: ca.SX,
    D: ca.SX,
    per_stage: Sequence[ca.SX],
    inv: ca.SX,
    scale: ca.SX,
) -> ca.SX:
    """The program's rows of one stage (``stage``: ``stage_function``) in its scaled variables: the
    gap to the next state, the distance and lifted residuals, then the inequality rows. ``per_stage``:
    its q1, q2, q3, e1, e2, ta, tb (dof each), ``inv``: its inverse velocity, acceleration and jerk limits."""
    dof = per_stage[0].shape[0]
    # the variables are the program's own divided by a typical magnitude of each (``variable_scales``)
    x_scale, u_scale = scale[: len(STATE)], scale[len(STATE) :]
    m = len(FRACTIONS)
    sigma_scale, sd_scale = u_scale[2], u_scale[2 + m]
    residual_scale = ca.vertcat(1.0, *([sigma_scale, sd_scale] * m))
    q1, q2, q3, e1, e2, ta, tb = per_stage
    xs, us = x * x_scale, u * u_scale
    controls = (us[i] for i in range(len(CONTROL)))
    limits = (inv[:dof], inv[dof : 2 * dof], inv[2 * dof :])
    x1, residual, rows = stage(xs[0], xs[1], *controls, D, q1, q2, q3, e1, e2, *limits, ta, tb)
    return ca.vertcat(x_next - x1 / x_scale, residual / residual_scale, rows)


def build_nlp(n: int, dof: int, torque: bool) -> tuple[dict[str, ca.SX], list[bool]]:
    """The program for n intervals and dof joints (x, p, f, g) and which of its rows are equalities."""
    stage = stage_function(dof, torque)
    D = ca.SX.sym("D", n)
    per_stage = [ca.SX.sym(name, n, dof) for name in PER_STAGE]
    # the limits per stage: a screened program (``planner.jerk.screen``) holds other joints' rows on each
    inv = ca.SX.sym("inv", n, 3 * dof)
    scale = ca.SX.sym("scale", len(STATE) + len(CONTROL))
    x = [ca.SX.sym(f"x{k}", len(STATE)) for k in range(n + 1)]
    u = [ca.SX.sym(f"u{k}", len(CONTROL)) for k in range(n)]
    w: list[ca.SX] = []
    g: list[ca.SX] = []
    equality: list[bool] = []
    for k in range(n):
        rows = stage_rows(stage, x[k], u[k], x[k + 1], D[k], [mat[k, :].T for mat in per_stage], inv[k, :].T, scale)
        w += [x[k], u[k]]
        g.append(rows)
        equality += [True] * _EQUALITIES + [False] * (rows.shape[0] - _EQUALITIES)
    w.append(x[n])
    p = ca.vertcat(D, *(ca.vec(mat) for mat in per_stage), ca.vec(inv), scale)
    objective = ca.sum1(ca.vertcat(*(uk[0] for uk in u)))
    return {"x": ca.vertcat(*w), "p": p, "f": objective, "g": ca.vertcat(*g)}, equality


def program_rows(
    path: JointPath, grid: NDArray[np.float64], limits: JointLimits, constraints: Sequence[constraint.Constraint]
) -> Rows:
    """The numbers of the program's rows on ``grid``, from the cell's toppra constraints."""
    n = len(grid) - 1
    _, q1, q2, q3 = interval_coefficients(path, grid)
    D = np.diff(grid)
    mid = 0.5 * (grid[:-1] + grid[1:])
    sd_max = np.full(n + 1, np.inf)
    sd_max_mid = np.full(n, np.inf)
    torque = None
    for c in constraints:
        if isinstance(c, _SPEED_CONSTRAINTS):
            with np.errstate(divide="ignore"):
                sd_max = np.minimum(sd_max, np.min(c.limit / np.abs(c.speed_factors(path, grid)), axis=1))
                if not isinstance(c, IntervalJointVelocityConstraint):
                    sd_max_mid = np.minimum(sd_max_mid, np.min(c.limit / np.abs(c.speed_factors(path, mid)), axis=1))
        elif isinstance(c, RneaJointTorqueConstraint):
            a, b, cc, _F, _g, _ub, _xb = c.compute_constraint_params(path, grid[:-1])
            torque = (a / c.effort, b / c.effort, -1.0 - cc / c.effort, 1.0 - cc / c.effort)
        elif not isinstance(c, IntervalJointAccelerationConstraint):
            raise ValueError(f"the jerk-limited timing cannot hold a {type(c).__name__}")
    e1 = q1 + D[:, None] * (q2 + 0.5 * D[:, None] * q3)
    e2 = q2 + D[:, None] * q3
    return Rows(D, q1, q2, q3, e1, e2, sd_max, sd_max_mid, torque)


def program_bounds(rows: Rows) -> dict[str, NDArray[np.float64]]:
    """lbx, ubx, lbg, ubg of the program for ``rows``: rest at both ends and at every stop, speed
    boxes, row bounds."""
    n, dof = rows.q1.shape  # the program's intervals and joints
    width = len(STATE) + len(CONTROL)
    lbx, ubx = np.full((n + 1, width), -np.inf), np.full((n + 1, width), np.inf)
    lbx[:, 0], ubx[:, 0] = 0.0, rows.sd_max
    # no interval is crossed faster than at a quarter of the highest speed allowed anywhere: keeps the
    # solver away from h -> 0, where the distance row loses its gradient (a trap of local infeasibility)
    finite = rows.sd_max[np.isfinite(rows.sd_max) & (rows.sd_max > 0.0)]
    lbx[:-1, 2] = 0.25 * rows.D / (np.max(finite) if len(finite) else 1e6)
    first_sd = len(STATE) + 2 + len(FRACTIONS)  # the column of the first lifted s'
    lbx[:-1, first_sd : first_sd + len(FRACTIONS)] = 0.0
    ubx[:-1, first_sd + _MIDDLE_INDEX] = rows.sd_max_mid
    # at rest with zero acceleration at both ends and at every stop on the way (a stop with s'' != 0
    # would run backwards along the path on one side of it)
    rest = rows.sd_max == 0.0
    rest[[0, n]] = True
    lbx[rest, :2] = ubx[rest, :2] = 0.0
    one = np.ones((n, dof))
    lo, hi = [np.zeros((n, _EQUALITIES)), -one], [np.zeros((n, _EQUALITIES)), one]
    if rows.torque is not None:
        lo.append(rows.torque[2])
        hi.append(rows.torque[3])
    rest_rows = 2 * len(FRACTIONS) + _JERK_ROWS
    lo += [-one] * rest_rows
    hi += [one] * rest_rows
    cut = len(CONTROL)  # the last stage has a state only
    return {
        "lbx": lbx.ravel()[:-cut],
        "ubx": ubx.ravel()[:-cut],
        "lbg": np.hstack(lo).ravel(),
        "ubg": np.hstack(hi).ravel(),
    }


def program_parameters(
    rows: Rows, limits: JointLimits, max_jerk: NDArray[np.float64], joints: NDArray[np.intp] | None = None
) -> NDArray[np.float64]:
    """The program's parameters for ``rows``; ``joints`` (n, k): the joints whose rows each stage
    holds where they are screened (``planner.jerk.screen``), None: every joint."""
    zero = np.zeros_like(rows.q1)
    ta, tb = (rows.torque[0], rows.torque[1]) if rows.torque is not None else (zero, zero)
    per_stage = (rows.q1, rows.q2, rows.q3, rows.e1, rows.e2, ta, tb)
    inv = np.concatenate((1.0 / limits.velocity, 1.0 / limits.acceleration, 1.0 / max_jerk))
    if joints is None:
        joints = np.broadcast_to(np.arange(limits.dof), (len(rows.D), limits.dof))
    dof = limits.dof
    per_joint = np.concatenate((inv[joints], inv[joints + dof], inv[joints + 2 * dof]), axis=1)
    return np.concatenate((rows.D, *(m.ravel("F") for m in per_stage), per_joint.ravel("F")))


def variable_scales(start: NDArray[np.float64]) -> NDArray[np.float64]:
    """A typical magnitude of each of a stage's variables (the 90th percentile of its |start| over
    the stages, 1 where that is 0): fatrop, unlike ipopt, does not scale a program itself, and the
    jerk s''' is orders of magnitude larger than the times h."""
    width = len(STATE) + len(CONTROL)
    stages = np.append(start, np.zeros(len(CONTROL))).reshape(-1, width)[:-1]
    typical = np.percentile(np.abs(stages), 90, axis=0)
    return np.where(typical > 0.0, typical, 1.0)
