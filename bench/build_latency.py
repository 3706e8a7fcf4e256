"""Knot placement and validation latency alone (issue 25 item 5), on the trajectories of
bench/plan_latency.py's full plans (arm6, 8 waypoints in 70 % of each range, seed 1).

The trajectories are planned once; then ``build_program`` (knot placement + the validated
program) runs on each of them ``--repeat`` times, interleaved by round (a drift of the host's
speed spreads over all paths), pinned to one core. Prints p50/p99 wall of the placement, of the
validation and of both, and the CPU time (this thread's) of both. Faster than plan_latency.py (no
reference plans), for comparing two trees back to back on a loaded host.

Run:  PYTHONPATH=$PWD python3 bench/build_latency.py [--paths 200] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.planner.build import build_program
from pvtflow.planner.knots import KnotOptions
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import load_cell_config


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[-1]})
    cell = load_cell_config(None)
    cp = CellPlanner(cell)
    cp.warm_up()
    assert cp.planner is not None
    lim = cp.limits
    rng = np.random.default_rng(args.seed)
    mid, half = 0.5 * (lim.upper + lim.lower), 0.5 * 0.7 * (lim.upper - lim.lower)
    trajs = []
    for _ in range(args.paths):
        out = cp.planner.plan(PlanInput(rng.uniform(mid - half, mid + half, (8, lim.dof))))
        if out.ok and out.trajectory is not None:
            trajs.append(out.trajectory)
    opts = KnotOptions(tolerance_qc=cp.tolerance_qc)
    for t in trajs[:20]:  # warm
        build_program(t, cp.axes, cell.name, opts)
    rows = np.zeros((args.repeat, len(trajs), 3))
    for r in range(args.repeat):
        for i, t in enumerate(trajs):
            c0 = time.thread_time()
            b = build_program(t, cp.axes, cell.name, opts)
            rows[r, i] = (b.timing["knots"], b.timing["validation"], time.thread_time() - c0)
    ms = rows.reshape(-1, 3) * 1e3
    knots, val, cpu = ms[:, 0], ms[:, 1], ms[:, 2]

    def pc(x: np.ndarray) -> str:
        return f"p50 {np.percentile(x, 50):.3f} p99 {np.percentile(x, 99):.3f}"

    print(f"command: python bench/build_latency.py --paths {args.paths} --repeat {args.repeat} --seed {args.seed}")
    print(
        f"{len(trajs)} trajectories x {args.repeat}: knots {pc(knots)}  validation {pc(val)}  "
        f"both {pc(knots + val)}  (wall ms); CPU both {pc(cpu)}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
