"""Scratch: capture the screened program's solver args on arm6 8-waypoint paths (joint limits only)."""
import os, pickle, sys, time
from dataclasses import replace
from pathlib import Path
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, "bench")
import numpy as np
from pvt_quality import random_waypoints
import pvtflow.planner.jerk as jerk
from pvtflow.planner.jerk.solve import PROGRAMS
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import parameterize
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

torque = "--torque" in sys.argv
cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
if not torque:
    cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
cp = CellPlanner(cell)
planner, limits = cp.planner, cp.limits
jmax = 10 * limits.acceleration
rng = np.random.default_rng(1)
captured = []
orig = jerk.solve_in_time
def spy(program, args, scale, deadline, meanwhile=None):
    captured.append(dict(n=program.n, dof=program.dof, torque=program.torque, args={k: np.asarray(v) for k, v in args.items()}, scale=scale))
    return orig(program, args, scale, deadline, meanwhile)
jerk.solve_in_time = spy
for i in range(int(sys.argv[1])):
    wp = random_waypoints(cell, rng, 8)
    path = cp.plan(PlanInput(wp, max_jerk=jmax), budget_ms=0).plan.trajectory.path
    warm = parameterize(path, limits, planner.constraints, planner.gridpoints)
    for n in (48, 96):
        jerk.jerk_limited(path, limits, planner.constraints, jmax, warm, n, time.perf_counter() + 60)
pickle.dump(captured, open(f"/tmp/x39_cap{'_t' if torque else ''}.pkl", "wb"))
print(len(captured), [(c["n"], c["dof"], c["torque"]) for c in captured[:4]])
