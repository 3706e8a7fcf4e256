"""The jerk-limited program with fewer rows per stage (issue 39 item 2): fatrop's time and the answer.

Within a deadline each stage of the program holds the rows of ``planner.jerk.screen.ROW_JOINTS``
joints (ranked by the start), every joint's rows checked after the solve. For N random arm6 paths
of W waypoints (bench/pvt_quality.py's drawing, seeded; jerk F x amax/s, joint limits only, as
bench/jerk_vs_copp.py), on ``--intervals`` intervals, alternated on every path: the whole program
(``ROW_JOINTS`` = every joint) and the screened one with every count of ``--row-joints``, all with a
deadline far off (the solver finishes; the floor is computed beside it, as within any deadline).
Prints fatrop's time (p50, max) and per iteration, the checked duration over the whole program's
(p50, max), the answers the check marked not optimal, and the durations over the whole program's
on 192 intervals (1.001x copp-py's TOPP3 at 1000 stations, bench/RESULTS.md).

Run:  python bench/jerk_rows.py [--paths 20] [--waypoints 8] [--factor 10] [--seed 1]
      [--intervals 96] [--row-joints 3,4]
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

import pvtflow.planner.jerk as jerk
from pvtflow.planner.jerk.solve import PROGRAMS
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import parameterize
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--intervals", type=int, default=96)
    ap.add_argument("--row-joints", default="3,4")
    args = ap.parse_args()
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
    cp = CellPlanner(cell)
    planner, limits = cp.planner, cp.limits
    jmax = args.factor * limits.acceleration
    counts = [int(k) for k in args.row_joints.split(",")]
    names = ["whole", *(f"{k} joints" for k in counts)]
    fatrop: dict[str, list[float]] = {m: [] for m in names}
    per_iteration: dict[str, list[float]] = {m: [] for m in names}
    ratio: dict[str, list[float]] = {m: [] for m in names}
    to192: dict[str, list[float]] = {m: [] for m in names}
    not_optimal = dict.fromkeys(names, 0)
    rng = np.random.default_rng(args.seed)
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        path = cp.plan(PlanInput(wp, max_jerk=jmax), budget_ms=0).plan.trajectory.path  # the floor: its path only
        warm = parameterize(path, limits, planner.constraints, planner.gridpoints)
        ref = jerk.jerk_limited(path, limits, planner.constraints, jmax, warm, 192).duration
        whole = None
        for name, k in zip(names, [limits.dof, *counts], strict=True):
            jerk.ROW_JOINTS = k
            deadline = time.perf_counter() + 60.0  # all alike: the floor computed while fatrop solves
            PROGRAMS.get(args.intervals, k, False)  # built before it is timed
            traj = jerk.jerk_limited(path, limits, planner.constraints, jmax, warm, args.intervals, deadline)
            whole = traj.duration if whole is None else whole
            took = PROGRAMS.ready(args.intervals, k, False).fatrop_s[-1]
            fatrop[name].append(took)
            per_iteration[name].append(took / max(traj.iterations, 1))
            ratio[name].append(traj.duration / whole)
            to192[name].append(traj.duration / ref)
            not_optimal[name] += int(not traj.optimal)
    print(f"arm6, {args.paths} paths of {args.waypoints} waypoints (seed {args.seed}), jerk {args.factor:g} x amax/s")
    for name in names:
        f, r, q = 1e3 * np.array(fatrop[name]), np.array(ratio[name]), np.array(to192[name])
        print(
            f"{args.intervals} intervals, {name:<9}: fatrop p50 {np.median(f):6.1f} max {f.max():6.1f} ms, "
            f"per iteration {1e3 * np.median(per_iteration[name]):.2f} ms; duration / whole p50 {np.median(r):.4f} "
            f"max {r.max():.4f}, / whole at 192 p50 {np.median(q):.4f} max {q.max():.4f}; "
            f"not optimal {not_optimal[name]}"
        )
    print(
        f"command: python bench/jerk_rows.py --paths {args.paths} --waypoints {args.waypoints} "
        f"--factor {args.factor:g} --seed {args.seed} --intervals {args.intervals} --row-joints {args.row_joints}"
    )


if __name__ == "__main__":
    main()
