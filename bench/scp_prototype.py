"""A sequential LP on TOPP-RA's grid for the jerk-limited timing: how fast, how short? (issue 39 item 2)

A PROTOTYPE to decide direction (1) of issue 39 item 2 by measurement, not a planner: it answers an
s-domain profile (x = s'^2 and u = s'' at stations, x linear in s between them through the
trapezoid x_(i+1) - x_i = (u_i + u_(i+1)) D_i), not a JerkTrajectory the knots could take.

Variables x_i, u_i at N + 1 stations (``WarmProfile.grid``: every waypoint, even in TOPP-RA's time,
rests at the ends and the C1 waypoints). Rows: x_i <= sd_max_i^2 (joint and TCP speed), joint
acceleration q_s u + q_ss x at every station, joint jerk sqrt(x) (q_s u' + 3 q_ss u + q_sss x) with
u' = (u_(i+1) - u_i) / D_i at both ends of every interval, its sqrt(x) taken from the previous
iterate (the first: TOPP-RA's, which bounds every jerk-limited profile from above), a trust region
x <= 1.5 xbar + 1e-3 max(xbar). Objective: max sum D_i x_i / sqrt(xbar_i) (the duration's
gradient's direction, capped near rest). scipy's HiGHS (dual simplex), no new dependency.

Prints per station count: LP wall per iteration, total; the profile's duration (sum 2 D / (v_i + v_(i+1)))
after K iterations over pvtflow's 192-interval no-deadline answer on the same path; the profile's worst
joint jerk at its stations over the limit (sqrt(x) exact, before any slow-down) and the duration after
the uniform slow-down k = cbrt(that) which would hold it there.

``--solver clarabel``: the same LPs with Clarabel (pip ``clarabel``, interior point; bench-only here).

Run:  python bench/scp_prototype.py [--paths 10] [--stations 96,192] [--iterations 6] [--solver highs|clarabel]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

import pvtflow.planner.jerk as jerk_module
from pvtflow.planner.jerk.nlp import program_rows
from pvtflow.planner.jerk.warm import WarmProfile, rests_of
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

LP_ONLY: list[float] = []  # linprog's own wall (HiGHS and scipy's wrapper), per LP


SOLVER = "highs"


class _Answer:
    def __init__(self, status: int, x: np.ndarray) -> None:
        self.status, self.x = status, x


def _clarabel(w, A_ub, b_ub, eq, bounds):  # type: ignore[no-untyped-def]
    """The same LP with Clarabel (interior point): bounds as rows, fixed variables as equalities."""
    import clarabel

    nv = len(w)
    eye = sp.identity(nv, format="csr")
    lo, hi = bounds[:, 0], bounds[:, 1]
    fixed = lo == hi
    up = np.isfinite(hi) & ~fixed
    down = np.isfinite(lo) & ~fixed
    A = sp.vstack((eq, eye[fixed], A_ub, eye[up], -eye[down])).tocsc()
    b = np.concatenate((np.zeros(eq.shape[0]), lo[fixed], b_ub, hi[up], -lo[down]))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    cones = [
        clarabel.ZeroConeT(eq.shape[0] + int(fixed.sum())),
        clarabel.NonnegativeConeT(A.shape[0] - eq.shape[0] - int(fixed.sum())),
    ]
    sol = clarabel.DefaultSolver(sp.csc_matrix((nv, nv)), w, A, b, cones, settings).solve()
    ok = str(sol.status) in ("Solved", "AlmostSolved")
    return _Answer(0 if ok else 2, np.asarray(sol.x))


def scp(path, limits, constraints, jmax, warm, n: int, iterations: int):  # type: ignore[no-untyped-def]
    """[(duration, worst jerk ratio, LP wall s)] per iteration on an n-interval grid."""
    rests = rests_of(path)
    profile = WarmProfile.of(warm, rests)
    grid = profile.grid(path.waypoint_s, rests, n)
    rows = program_rows(path, grid, limits, constraints)
    rows.sd_max[np.searchsorted(grid, rests[1:-1])] = 0.0
    dof = limits.dof
    D = rows.D
    amax, vmax2 = limits.acceleration, rows.sd_max**2
    q1 = np.vstack((rows.q1, rows.e1[-1]))  # q_s at the stations (the last from the last interval's end)
    q2 = np.vstack((rows.q2, rows.e2[-1]))
    nv = 2 * (n + 1)  # x_0..x_N, u_0..u_N
    ix, iu = np.arange(n + 1), n + 1 + np.arange(n + 1)
    # equalities: x_(i+1) - x_i - D_i (u_i + u_(i+1)) = 0
    r = np.arange(n)
    eq = sp.csr_matrix(
        (
            np.concatenate((np.ones(n), -np.ones(n), -D, -D)),
            (np.tile(r, 4), np.concatenate((ix[1:], ix[:-1], iu[:-1], iu[1:]))),
        ),
        shape=(n, nv),
    )
    # acceleration at the stations, every joint: q_s u + q_ss x in [-amax, amax]
    st = np.arange(n + 1)
    acc_rows = []
    for k in range(dof):
        acc_rows.append(
            sp.csr_matrix(
                (np.concatenate((q2[:, k], q1[:, k])), (np.tile(st, 2), np.concatenate((ix, iu)))), shape=(n + 1, nv)
            )
        )
    A_acc = sp.vstack(acc_rows)
    b_acc = np.repeat(amax, n + 1)
    rest = rows.sd_max == 0.0
    rest[[0, n]] = True
    xbar = np.minimum(np.interp(grid, profile.s, profile.x), vmax2)
    out = []
    for _ in range(iterations):
        began = time.perf_counter()
        v = np.sqrt(np.maximum(xbar, 0.0))
        jr = []  # jerk at both ends of every interval: sqrt(xbar) (q_s (u1 - u0)/D + 3 q_ss u + q_sss x)
        jb = []
        for end, (c1, c2, c3) in enumerate(((rows.q1, rows.q2, rows.q3), (rows.e1, rows.e2, rows.q3))):
            at = r + end
            for k in range(dof):
                vals = np.concatenate((-c1[:, k] / D, c1[:, k] / D, 3.0 * c2[:, k], c3[:, k]))
                cols = np.concatenate((iu[:-1], iu[1:], iu[at], ix[at]))
                jr.append(sp.csr_matrix((vals, (np.tile(r, 4), cols)), shape=(n, nv)))
                jb.append(jmax[k] / np.maximum(v[at], 1e-9))
        A_j = sp.vstack(jr)
        b_j = np.concatenate(jb)
        A_ub = sp.vstack((A_acc, -A_acc, A_j, -A_j)).tocsr()
        b_ub = np.concatenate((b_acc, b_acc, b_j, b_j))
        cap = 1e-3 * max(np.max(xbar), 1e-12)
        lo_x = np.zeros(n + 1)  # a lower trust bound made the first LPs infeasible (rests need x << TOPP-RA)
        hi_x = np.minimum(vmax2, xbar + 0.5 * xbar + cap)
        lo_x[rest] = hi_x[rest] = 0.0
        bounds = np.vstack(
            (np.column_stack((lo_x, hi_x)), np.column_stack((np.full(n + 1, -np.inf), np.full(n + 1, np.inf))))
        )
        bounds[iu[rest]] = 0.0
        w = np.zeros(nv)
        Dst = np.zeros(n + 1)
        Dst[:-1] += 0.5 * D
        Dst[1:] += 0.5 * D
        w[ix] = -Dst / np.maximum(v, 0.05 * np.max(v))
        lp_began = time.perf_counter()
        if SOLVER == "clarabel":
            res = _clarabel(w, A_ub, b_ub, eq, bounds)
        else:
            res = linprog(w, A_ub=A_ub, b_ub=b_ub, A_eq=eq, b_eq=np.zeros(n), bounds=bounds, method="highs-ds")
        wall = time.perf_counter() - began
        LP_ONLY.append(time.perf_counter() - lp_began)
        if res.status != 0:
            out.append((np.nan, np.nan, wall))
            break
        x, u = np.maximum(res.x[ix], 0.0), res.x[iu]
        vs = np.sqrt(x)
        duration = float(np.sum(2.0 * D / np.maximum(vs[:-1] + vs[1:], 1e-12)))
        du = np.diff(u) / D
        worst = 0.0
        for c1, c2, c3, at in ((rows.q1, rows.q2, rows.q3, r), (rows.e1, rows.e2, rows.q3, r + 1)):
            jerk = vs[at, None] * (c1 * du[:, None] + 3.0 * c2 * u[at, None] + c3 * x[at, None])
            worst = max(worst, float(np.max(np.abs(jerk) / jmax)))
        out.append((duration, worst, wall))
        xbar = x
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10)
    ap.add_argument("--stations", default="96,192")
    ap.add_argument("--iterations", type=int, default=6)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--solver", choices=("highs", "clarabel"), default="highs")
    args = ap.parse_args()
    global SOLVER
    SOLVER = args.solver
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    jmax = args.factor * cp.limits.acceleration
    captured: list[tuple] = []
    solve = jerk_module.jerk_limited

    def capture(*a, **k):  # type: ignore[no-untyped-def]
        traj = solve(*a, **k)
        captured.append((a, traj))
        return traj

    jerk_module.jerk_limited = capture  # planner.plan imports it at the call
    rng = np.random.default_rng(args.seed)
    sizes = [int(s) for s in args.stations.split(",")]
    table: dict[int, list] = {n: [] for n in sizes}
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, 8)
        captured.clear()
        cp.plan(PlanInput(wp, max_jerk=jmax))
        (path, limits, constraints, jm, warm, *_), ref = captured[0]
        for n in sizes:
            its = scp(path, limits, constraints, jm, warm, n, args.iterations)
            table[n].append((ref.duration, its))
    print(
        f"arm6, {args.paths} paths of 8 waypoints, jerk {args.factor:g} x amax/s, joint limits only; "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"  {SOLVER} alone per LP (all sizes): p50 {1000 * np.median(LP_ONLY):.1f} ms,"
        f" max {1000 * np.max(LP_ONLY):.1f} ms"
    )
    for n, runs in table.items():
        print(f"  {n} intervals:")
        for it in range(args.iterations):
            ratio, slowed, worst, walls = [], [], [], []
            for ref, its in runs:
                if it < len(its) and np.isfinite(its[it][0]):
                    d, w, _ = its[it]
                    ratio.append(d / ref)
                    worst.append(w)
                    slowed.append(d * max(1.0, np.cbrt(w)) / ref)
                    walls.append(1000.0 * sum(x[2] for x in its[: it + 1]))
            if not ratio:
                continue
            print(
                f"    after {it + 1}: {len(ratio)}/{len(runs)} answered;"
                f" duration / pvtflow-192 p50 {np.median(ratio):.4f}"
                f" max {np.max(ratio):.4f}; worst jerk at stations p50 {np.median(worst):.3f} max {np.max(worst):.3f};"
                f" slowed to hold it p50 {np.median(slowed):.4f} max {np.max(slowed):.4f};"
                f" LP wall so far p50 {np.median(walls):.1f} max {np.max(walls):.1f} ms"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
