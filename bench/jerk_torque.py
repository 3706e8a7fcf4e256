"""Joint torque in jerk-limited plans, everywhere in time: the worst |tau| / effort of the final
trajectory, with Pinocchio's RNEA at 20 samples per grid interval (one-sided at both ends, as
tests/planner/test_plan.py checks TOPP-RA's) and every 1 ms.

1. The binding arm6 path of tests/planner/test_plan.py (effort cut to 25/34/25 % on joints 1-3),
   and the same path with every effort cut to 30 %: without a deadline, and with ``budget_ms`` 0
   (the S-curve floor) and 60 (ipopt alone, stopped at its deadline, in a process whose fatrop history is short).
2. ``--paths`` random arm6 paths of 2-8 waypoints (seed ``--seed``) with every effort at 30 %:
   the worst ratio of the jerk-limited answer (solver and floor) and of TOPP-RA's, for comparison.
3. The torque check's cost on 8-waypoint arm6 paths at the cell's own efforts
   (``planner.jerk._torque_slowdown``, where the tree has it): median and max per plan.

max_jerk = 10 x each joint's acceleration limit per second. Run it on two trees to compare.

Run:  python bench/jerk_torque.py [--paths 20] [--seed 2] [--cost-paths 8]
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

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
BINDING = np.array([[0.0, -1.0, 1.2, 0, 0, 0], [1.5, 0.8, -0.6, 0, 0, 0]])


def with_effort(factor: np.ndarray | float) -> JointLimits:
    lim = LIMITS
    return JointLimits(lim.names, lim.lower, lim.upper, lim.velocity, lim.acceleration, lim.effort * factor)


def torque_ratios(traj, effort: np.ndarray) -> tuple[float, float]:
    """Worst |tau| / effort at 20 samples per grid interval, and every 1 ms."""
    out = []
    for t in (traj.check_times(19), np.linspace(0.0, traj.duration, int(traj.duration * 1000) + 1)):
        tau = ARM.model.inverse_dynamics_rows(traj.position(t), traj.velocity(t), traj.acceleration(t))
        out.append(float(np.max(np.abs(tau) / effort)))
    return out[0], out[1]


def binding_path() -> None:
    print("1. the binding path of tests/planner/test_plan.py")
    print("effort              budget_ms  solver  optimal  torque_scale  duration_s  worst@20/interval  worst@1ms")
    for name, factor in (("25/34/25 % (test)", np.array([0.25, 0.34, 0.25, 1, 1, 1])), ("30 %", 0.3)):
        lim = with_effort(factor)
        planner = Planner(lim, ARM.model, torque_limits=True)
        planner.plan(PlanInput(BINDING, max_jerk=10.0 * lim.acceleration))  # casadi loaded, program built
        for budget in (None, 0.0, 60.0):
            out = planner.plan(PlanInput(BINDING, max_jerk=10.0 * lim.acceleration, budget_ms=budget))
            tr = out.trajectory
            r20, r1 = torque_ratios(tr, lim.effort)
            d = out.details
            print(
                f"{name:19s} {budget!s:>9s}  {d['solver']:6s}  {d['optimal']!s:7s}  "
                f"{d.get('torque_scale', float('nan')):12.6f}  {tr.duration:10.4f}  {r20:17.6f}  {r1:9.6f}"
            )


def random_paths(count: int, seed: int) -> None:
    print(f"\n2. {count} random arm6 paths of 2-8 waypoints (seed {seed}), every effort at 30 %")
    lim = with_effort(0.3)
    planner = Planner(lim, ARM.model, torque_limits=True)
    rng = np.random.default_rng(seed)
    rows: dict[str, list[float]] = {"TOPP-RA": [], "jerk, solver": [], "jerk, floor": []}
    slowed = {"jerk, solver": [], "jerk, floor": []}
    for _ in range(count):
        wp = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((int(rng.integers(2, 9)), lim.dof)))
        topp = planner.plan(PlanInput(wp))
        rows["TOPP-RA"].append(max(torque_ratios(topp.trajectory, lim.effort)))
        for key, budget in (("jerk, solver", None), ("jerk, floor", 0.0)):
            out = planner.plan(PlanInput(wp, max_jerk=10.0 * lim.acceleration, budget_ms=budget))
            rows[key].append(max(torque_ratios(out.trajectory, lim.effort)))
            slowed[key].append(float(out.details.get("torque_scale", float("nan"))))
    print("timing        worst ratio: p50      max    paths > 1+1e-6   torque_scale p50   max   not optimal")
    for key, r in rows.items():
        a = np.array(r)
        line = f"{key:13s} {np.median(a):18.6f} {a.max():8.6f} {int(np.sum(a > 1 + 1e-6)):10d}"
        if key in slowed:
            s = np.array(slowed[key])
            line += f"   {np.median(s):16.4f} {s.max():7.4f}"
            if key == "jerk, solver":
                line += f"   {int(np.sum(s > 1.001))} (torque slowed > 0.1 %)"
        print(line)


def check_cost(count: int) -> None:
    import pvtflow.planner.jerk as jerk

    if not hasattr(jerk, "_torque_slowdown"):
        print("\n3. this tree has no torque check in the jerk-limited timing")
        return
    print(f"\n3. the torque check's cost, {count} random 8-waypoint arm6 paths at the cell's efforts (seed 1)")
    lim = LIMITS
    planner = Planner(lim, ARM.model, torque_limits=True)
    constraints = planner.constraints
    rng = np.random.default_rng(1)
    cost: dict[str, list[float]] = {"solver": [], "floor": []}
    for _ in range(count):
        wp = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))
        for key, budget in (("solver", None), ("floor", 0.0)):
            tr = planner.plan(PlanInput(wp, max_jerk=10.0 * lim.acceleration, budget_ms=budget)).trajectory
            best = np.inf
            for _ in range(5):
                t0 = time.perf_counter()
                jerk._torque_slowdown(tr, constraints)
                best = min(best, time.perf_counter() - t0)
            cost[key].append(best * 1000.0)
    for key, c in cost.items():
        print(f"{key:6s}: median {np.median(c):.2f} ms, max {np.max(c):.2f} ms per plan (best of 5)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--cost-paths", type=int, default=8)
    args = ap.parse_args()
    binding_path()
    random_paths(args.paths, args.seed)
    check_cost(args.cost_paths)
    print("\ncommand: python bench/jerk_torque.py" + "".join(f" {a}" for a in sys.argv[1:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
