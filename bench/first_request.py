"""The first jerk-limited plans after a start: does any lose its deadline to something not warmed?

Each run is a fresh interpreter that starts as ``pvtflow serve`` starts its planner (``CellPlanner``,
``warm_up``, ``freeze_startup_objects``), then plans the same 8-waypoint arm6 paths (80 % of every
range, max_jerk 10 x each joint's acceleration limit per second) at ``--budget-ms``, one after the
other: per request its code (ok / timeout), wall time and the thread's CPU time, and which solver
answered. Then the casadi programs and solvers the requests built (none: the warm-up built them).

Run:  python bench/first_request.py [--runs 5] [--requests 4] [--budget-ms 50]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
import numpy as np
from pvtflow.planner.jerk import solve
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import load_cell_config
from pvtflow.axes.canbus.collector import freeze_startup_objects

requests, budget = int(sys.argv[1]), float(sys.argv[2])
planner = CellPlanner(load_cell_config(None))
t0 = time.perf_counter()
planner.warm_up()
freeze_startup_objects()
warm_s = time.perf_counter() - t0
cache = getattr(solve, "PROGRAMS", None)  # None: a tree before it (its programs are not counted)
built = lambda: {} if cache is None else {str(s): sorted(cache.ready(*s).solvers) for s in cache.shapes()}
before = built()
lim = planner.limits
rng = np.random.default_rng(1)
rows = []
for _ in range(requests):
    w = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))
    t = time.perf_counter()
    r = planner.plan(PlanInput(w, max_jerk=10.0 * lim.acceleration), budget_ms=budget)
    wall = (time.perf_counter() - t) * 1e3
    solver = r.plan.details.get("solver") if r.plan is not None else None
    rows.append([r.code, wall, r.timing.get("cpu", float("nan")) * 1e3, solver])
print(json.dumps({"warm_s": warm_s, "rows": rows, "built": built() != before}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--requests", type=int, default=4)
    ap.add_argument("--budget-ms", type=float, default=50.0)
    args = ap.parse_args()
    firsts, others, timeouts, builds, warm = [], [], 0, 0, []
    for run in range(args.runs):
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(args.requests), str(args.budget_ms)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        )
        seen = json.loads(out.stdout.strip().splitlines()[-1])
        warm.append(seen["warm_s"])
        builds += seen["built"]
        for k, (code, wall, cpu, solver) in enumerate(seen["rows"]):
            timeouts += code == "timeout"
            (firsts if k == 0 else others).append(wall)
            print(f"run {run} request {k}: {code:8s} wall {wall:6.1f} ms  cpu {cpu:6.1f} ms  {solver}")
    f, o = np.array(firsts), np.array(others)
    print(
        f"{args.runs} starts, budget {args.budget_ms:g} ms: first request wall max {f.max():.1f} ms (median "
        f"{np.median(f):.1f}); later requests wall median {np.median(o):.1f} max {o.max():.1f} ms; "
        f"{timeouts} timeout(s); runs where a request built a casadi program or solver: {builds}; "
        f"warm-up {np.median(warm):.2f} s (median)"
    )
    options = f"--runs {args.runs} --requests {args.requests} --budget-ms {args.budget_ms:g}"
    print(f"command: python bench/first_request.py {options}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
