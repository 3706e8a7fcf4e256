"""The jerk-limited program split at the path's rests (issue 39 item 2): is it faster per plan?

Where the path rests inside (a C1 waypoint, ``planner.jerk.warm.rests_of``) the motion is at rest
there, so the parts between two rests are independent programs, each ending at rest: solved apart
(in parallel threads: casadi releases the interpreter's lock while it solves) and joined exactly.
For N random arm6 paths of W waypoints (bench/pvt_quality.py's drawing, seeded; jerk F x amax/s,
joint limits only, as bench/jerk_vs_copp.py) this solves, without a deadline, with fatrop:

- the whole path on ``--intervals`` intervals (the product's program, its grid and start);
- each rest-to-rest section on its own grid of the intervals shared out by the section's share of
  TOPP-RA's time (rounded up to a multiple of ``--unit``), one after the other, then the sections in
  ``--threads`` threads at once (wall time of the whole set);
- the whole path on 192 intervals, the reference (1.001x copp-py's TOPP3 at 1000 stations).

Prints per path and summarised: the rests, fatrop's time for the whole and for each section, the
sections' wall time in threads, and each duration over the 192-interval one (the solver's own
duration, before the dense check's slow-down, the same for all).

Run:  python bench/jerk_sections.py [--paths 20] [--waypoints 8] [--factor 10] [--seed 1]
      [--intervals 96] [--unit 8] [--threads 2]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

from pvtflow.planner.jerk.nlp import program_bounds, program_parameters, program_rows, variable_scales
from pvtflow.planner.jerk.solve import cached_program, solve_in_time
from pvtflow.planner.jerk.warm import MIN_REST_TO_REST, WarmProfile, rests_of, warm_start
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import parameterize
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def solve(path, limits, constraints, jmax, profile, waypoints, rests, n):
    """fatrop on the program for ``n`` intervals between rests[0] and rests[-1]: (duration s, fatrop s, iterations)."""
    grid = profile.grid(waypoints, rests, n)
    rows = program_rows(path, grid, limits, constraints)
    rows.sd_max[np.searchsorted(grid, rests[1:-1])] = 0.0
    start = warm_start(profile, grid, rows, jmax)
    scale = variable_scales(start)
    per_variable = np.tile(scale, n + 1)[: len(start)]
    bounds = program_bounds(rows)
    args = {k: v / per_variable for k, v in bounds.items() if k in ("lbx", "ubx")}
    args |= {k: v for k, v in bounds.items() if k in ("lbg", "ubg")}
    args["p"] = np.concatenate((program_parameters(rows, limits, jmax), scale))
    args["x0"] = start / per_variable
    program = cached_program(n, limits.dof, False)
    began = time.perf_counter()
    sol, _status, _ = solve_in_time(program, args, scale, None)
    took = time.perf_counter() - began
    if sol is None:
        return math.nan, took, -1
    return float(np.sum(sol.h)), took, sol.iterations


def in_threads(count: int, jobs: list[tuple]) -> float:
    """Wall time (s) of ``solve`` on every job, ``count`` threads taking them in turn."""
    queue = list(range(len(jobs)))
    lock = threading.Lock()

    def worker() -> None:
        while True:
            with lock:
                if not queue:
                    return
                k = queue.pop(0)
            solve(*jobs[k])

    began = time.perf_counter()
    threads = [threading.Thread(target=worker) for _ in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return time.perf_counter() - began


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--intervals", type=int, default=96)
    ap.add_argument("--unit", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
    cp = CellPlanner(cell)
    planner = cp.planner
    limits = cp.limits
    constraints = planner.constraints
    jmax = args.factor * limits.acceleration
    rng = np.random.default_rng(args.seed)
    rows = []
    for i in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        res = cp.plan(PlanInput(wp, max_jerk=jmax), budget_ms=0)  # the floor: only its path is used
        path = res.plan.trajectory.path
        warm = parameterize(path, limits, constraints, planner.gridpoints)
        rests = rests_of(path)
        profile = WarmProfile.of(warm, rests)
        ws = path.waypoint_s
        whole = solve(path, limits, constraints, jmax, profile, ws, rests, args.intervals)
        ref = solve(path, limits, constraints, jmax, profile, ws, rests, 192)
        line = (
            f"path {i:2d}: {len(rests) - 2} stops, whole {args.intervals}: fatrop {1e3 * whole[1]:6.1f} ms "
            f"it {whole[2]:3d} dur/192 {whole[0] / ref[0]:.4f}"
        )
        if len(rests) > 2:
            tr = np.interp(rests, profile.s, profile.t)
            share = np.diff(tr) / tr[-1]
            sections = []
            for k in range(len(rests) - 1):
                inside = ws[(ws >= rests[k] - 1e-12) & (ws <= rests[k + 1] + 1e-12)]
                least = max(MIN_REST_TO_REST, len(inside) - 1)
                n = max(least, args.unit * math.ceil(share[k] * args.intervals / args.unit))
                sections.append((inside, rests[k : k + 2], n))
            for _, _, n in sections:  # built before timing
                cached_program(n, limits.dof, False)
            apart = [solve(path, limits, constraints, jmax, profile, w, r, n) for w, r, n in sections]
            wall = in_threads(args.threads, [(path, limits, constraints, jmax, profile, *sec) for sec in sections])
            joined = sum(a[0] for a in apart)
            sizes = "+".join(str(n) for _, _, n in sections)
            per = ", ".join(f"{1e3 * a[1]:.1f}" for a in apart)
            line += (
                f" | sections {sizes}: fatrop {per} ms (sum {1e3 * sum(a[1] for a in apart):.1f}), "
                f"{args.threads} threads wall {1e3 * wall:.1f} ms, dur/192 {joined / ref[0]:.4f}"
            )
            rows.append((whole[1], wall, max(a[1] for a in apart), whole[0] / ref[0], joined / ref[0]))
        print(line, flush=True)
    if rows:
        r = np.array(rows)
        print(
            f"{len(rows)} of {args.paths} paths rest inside. whole fatrop p50 {1e3 * np.median(r[:, 0]):.1f} ms, "
            f"sections in {args.threads} threads wall p50 {1e3 * np.median(r[:, 1]):.1f} ms, "
            f"longest section p50 {1e3 * np.median(r[:, 2]):.1f} ms; dur/192 whole p50 {np.median(r[:, 3]):.4f} "
            f"max {r[:, 3].max():.4f}, joined p50 {np.median(r[:, 4]):.4f} max {r[:, 4].max():.4f}"
        )
    print(
        f"command: python bench/jerk_sections.py --paths {args.paths} --waypoints {args.waypoints} --factor "
        f"{args.factor:g} --seed {args.seed} --intervals {args.intervals} --unit {args.unit} --threads {args.threads}"
    )


if __name__ == "__main__":
    main()
