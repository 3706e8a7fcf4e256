"""Jerk-limited plans within a budget (issue 25): wall time against the budget, how many answers
were optimal, what the others cost in duration.

For N random arm6 paths (bench/pvt_quality.py's drawing), max_jerk = F x each joint's acceleration
limit per second: the whole cell plan (TOPP-RA, jerk-limited timing, knots, validation) with
``budget_ms``. Prints wall time p50 / p99 / max (and the thread's CPU time, and the process's: a
solve thread left running past the deadline counts there), the optimal /
not-optimal / timeout counts, and for every not-optimal answer its duration over the same path's
plan without a deadline (and over TOPP-RA's lower bound).

Run:  python bench/plan_budget.py [--paths 200] [--budget-ms 50] [--factor 10] [--waypoints 8] [--seed 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import TIMEOUT, CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=200)
    ap.add_argument("--budget-ms", type=float, default=50.0)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    rng = np.random.default_rng(args.seed)
    jerk = args.factor * cp.limits.acceleration
    wall, cpu, process, late_cost, late_bound = [], [], [], [], []
    counts = {"optimal": 0, "not optimal": 0, TIMEOUT: 0, "other": 0}
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        cpu0 = time.process_time()
        res = cp.plan(PlanInput(wp, max_jerk=jerk), None, None, args.budget_ms)
        process.append(time.process_time() - cpu0)  # every thread's: a solve left running counts too
        if res.code == TIMEOUT or res.ok:
            wall.append(res.timing.get("total", np.nan))
            cpu.append(res.timing.get("cpu", np.nan))
        if res.code == TIMEOUT:
            counts[TIMEOUT] += 1
            continue
        if not res.ok:
            counts["other"] += 1
            continue
        if res.optimal:
            counts["optimal"] += 1
            continue
        counts["not optimal"] += 1
        best = cp.plan(PlanInput(wp, max_jerk=jerk))  # the same path without a deadline
        assert res.gap is not None and best.gap is not None
        late_cost.append(res.gap["duration_s"] / best.gap["duration_s"])
        late_bound.append(res.gap["duration_s"] / res.gap["lower_bound_s"])
    w, c = 1000.0 * np.array(wall), 1000.0 * np.array(cpu)
    print(
        f"arm6, {args.paths} paths of {args.waypoints} waypoints, max_jerk {args.factor:g} x amax/s, "
        f"budget {args.budget_ms:g} ms"
    )
    print(f"  wall ms: p50 {np.nanpercentile(w, 50):.1f}  p99 {np.nanpercentile(w, 99):.1f}  max {np.nanmax(w):.1f}")
    print(f"  cpu ms:  p50 {np.nanpercentile(c, 50):.1f}  p99 {np.nanpercentile(c, 99):.1f}  max {np.nanmax(c):.1f}")
    pc = 1000.0 * np.array(process)
    print(f"  process cpu ms (all threads): p50 {np.percentile(pc, 50):.1f}  p99 {np.percentile(pc, 99):.1f}")
    print("  " + ", ".join(f"{k}: {v}" for k, v in counts.items()))
    if late_cost:
        lc, lb = np.array(late_cost), np.array(late_bound)
        print(
            f"  not optimal: duration / the optimal plan's p50 {np.median(lc):.2f} max {lc.max():.2f}; "
            f"/ TOPP-RA's p50 {np.median(lb):.2f} max {lb.max():.2f}"
        )
    print(
        f"  command: python bench/plan_budget.py --paths {args.paths} --budget-ms {args.budget_ms:g} "
        f"--factor {args.factor:g} --waypoints {args.waypoints} --seed {args.seed}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
