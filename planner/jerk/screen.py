"""The joints whose rows a stage of the program holds within a deadline: the few the start ranks
highest there, checked after the solve.

fatrop's time per iteration grows with the inequality rows per stage (arm6, 96 intervals, alternated on
10 paths: 36 rows, every joint's, 1.7 ms per iteration; 18 rows 1.05 ms; 12 rows 0.8 ms; bench/RESULTS.md
"Issue 39 item 2 at `budget_ms: 50`: sections at the rests, fewer rows per stage"), and on a stage of
the path few joints bind: the joint nearest its velocity limit, the one nearest its acceleration limit,
the one nearest its jerk limit. So within a deadline each stage holds the rows of ``ROW_JOINTS`` joints
(one more with torque rows): per stage the highest ranked by the start's velocity, acceleration, jerk
(and torque) each over the stage's largest of its kind (the leader of each kind ranks 1), the ranks the
largest within ``NEIGHBOURS`` stages on either side (a binding joint moves along the path as the solve
speeds up). The box on s' at the gridpoints keeps every joint's velocity (a bound, not a row), and the
TCP speed's rows are the path's, not a joint's.

After the solve every joint's rows are evaluated at their samples (``largest_row``): where a joint
left out exceeds its limit there the answer is no optimum of the whole program (``optimal`` False);
the dense check slows it down uniformly until every limit holds, as it does any answer.
"""

from __future__ import annotations

import dataclasses
import functools

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.jerk.nlp import CONTROL, FRACTIONS, STATE, Rows, stage_function
from pvtflow.planner.limits import JointLimits

# rows per stage for this many joints, one more with torque rows (arm6, joint limits: 3 lost the optimum on
# 2 paths of 22, 4 on none; with the cell's torque and TCP rows 4 lost it on 1 of 20, 5 on none)
ROW_JOINTS = 4
NEIGHBOURS = 2  # the ranks over this many stages on either side (0 or 1 lost it on more paths with 3 joints)
# a row left out that exceeds its limit by more than this at its samples: the answer is no optimum
ROW_TOL = 1e-6


def screened(rows: Rows, joints: NDArray[np.intp]) -> Rows:
    """``rows`` with each stage's joint columns cut to ``joints`` (n, k); the s' boxes stay whole."""

    def take(m: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.take_along_axis(m, joints, axis=1)

    torque = None if rows.torque is None else tuple(take(m) for m in rows.torque)
    return dataclasses.replace(
        rows, q1=take(rows.q1), q2=take(rows.q2), q3=take(rows.q3), e1=take(rows.e1), e2=take(rows.e2), torque=torque
    )


def row_joints(
    rows: Rows, start: NDArray[np.float64], limits: JointLimits, max_jerk: NDArray[np.float64], k: int = ROW_JOINTS
) -> NDArray[np.intp]:
    """The ``k`` joints whose rows each stage holds (n, k), ascending: ranked by the start's
    (``warm.warm_start``) velocity, acceleration and jerk at both ends of the stage."""
    width = len(STATE) + len(CONTROL)
    stages = np.append(start, np.zeros(len(CONTROL))).reshape(-1, width)
    sd, a, j = stages[:, 0, None], stages[:, 1, None], stages[:-1, 3, None]
    s0, s1, a0, a1 = sd[:-1], sd[1:], a[:-1], a[1:]
    velocity = np.maximum(np.abs(rows.q1 * s0), np.abs(rows.e1 * s1)) / limits.velocity
    acceleration = np.maximum(np.abs(rows.q2 * s0**2 + rows.q1 * a0), np.abs(rows.e2 * s1**2 + rows.e1 * a1))
    jerk0 = rows.q3 * s0**3 + 3.0 * rows.q2 * s0 * a0 + rows.q1 * j
    jerk1 = rows.q3 * s1**3 + 3.0 * rows.e2 * s1 * a1 + rows.e1 * j
    jerk = np.maximum(np.abs(jerk0), np.abs(jerk1)) / max_jerk
    kinds = [velocity, acceleration / limits.acceleration, jerk]
    if rows.torque is not None:  # at the starts: the share of the effort about gravity's (lo, hi: the effort's ends)
        ta, tb, lo, hi = rows.torque
        kinds.append(np.abs(ta * a0 + tb * s0**2 - 0.5 * (lo + hi)) / (0.5 * (hi - lo)))
    rank = np.maximum.reduce([r / np.maximum(np.max(r, axis=1, keepdims=True), 1e-300) for r in kinds])
    padded = np.pad(rank, ((NEIGHBOURS, NEIGHBOURS), (0, 0)))
    rank = np.maximum.reduce([padded[i : i + len(rank)] for i in range(2 * NEIGHBOURS + 1)])
    return np.sort(np.argsort(-rank, axis=1, kind="stable")[:, :k], axis=1)


@functools.lru_cache(maxsize=8)
def _stages(n: int, dof: int, torque: bool) -> ca.Function:
    """The whole program's stage function mapped over n stages: built once per shape (2-3 ms of casadi
    each time, after a solve within a deadline, where every ms is the answer's: bench/RESULTS.md)."""
    return stage_function(dof, torque).map(n)


def largest_row(
    rows: Rows,
    sd: NDArray[np.float64],
    sdd: NDArray[np.float64],
    h: NDArray[np.float64],
    j: NDArray[np.float64],
    limits: JointLimits,
    max_jerk: NDArray[np.float64],
) -> float:
    """The largest |row| of every joint (1: at its limit) at the samples the program holds its rows at,
    for the solution (s', s'' at the gridpoints, each interval's time and jerk): the program's own
    stage rows (``nlp.stage_function``), the middles following from the solution as its equalities do."""
    n, dof = rows.q1.shape
    stage = _stages(n, dof, rows.torque is not None)
    s0, a0 = sd[:-1], sdd[:-1]
    middles_sigma, middles_sd = [], []
    for f in FRACTIONS:
        tau = f * h
        middles_sigma.append(tau * (s0 + tau * (0.5 * a0 + tau * j / 6.0)))
        middles_sd.append(s0 + tau * (a0 + 0.5 * j * tau))
    inv = [np.tile(1.0 / lim, (n, 1)).T for lim in (limits.velocity, limits.acceleration, max_jerk)]
    ta, tb = (rows.torque[0].T, rows.torque[1].T) if rows.torque is not None else (np.zeros((dof, n)),) * 2
    per = (rows.q1, rows.q2, rows.q3, rows.e1, rows.e2)
    row = [np.atleast_2d(v) for v in (s0, a0, h, j, *middles_sigma, *middles_sd, rows.D)]
    values = np.asarray(stage(*row, *(m.T for m in per), *inv, ta, tb)[2])
    ratio = np.abs(values)
    if rows.torque is not None:  # the torque rows (after the acceleration's): lo <= value <= hi, not [-1, 1]
        _, _, lo, hi = rows.torque
        ratio[dof : 2 * dof] = np.abs(values[dof : 2 * dof] - 0.5 * (lo + hi).T) / (0.5 * (hi - lo).T)
    return float(np.max(ratio, initial=0.0))
