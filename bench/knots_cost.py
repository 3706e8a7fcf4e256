"""What knot placement costs, by the length of the motion: CPU time of ``place_knots`` on the arm6
cell for paths drawn in a centred fraction of each joint range (short, acceleration-bound moves
and long ones), with the placements and slow-down rounds it took.

For each range: ``--paths`` random paths of ``--waypoints`` waypoints, planned with the cell's
constraints; each placement is timed ``--repeat`` times (best CPU time kept: the VM's speed
drifts). Prints per range the median motion length, the knot placement p50/p90 (ms), its cost per
second of motion, records, and how often a path needed more than one round (slow-down).
``--stages``: also where the time goes, per range: the CPU time per path of each step of the
placement (timers wrapped around ``planner.knots``' step functions; nested steps are inside their
callers' figures).

Run:  python bench/knots_cost.py [--paths 25] [--waypoints 8] [--repeat 3] [--seed 5] [--stages]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import pvtflow.planner.knots
from pvtflow.planner.knots import check, epos2, fixed_period, place_knots, quantize, refine, samples
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

RANGES = (0.2, 0.5, 0.8)
STAGES = (
    "sample_trajectory",
    "switch_flat_knots",
    "refine",
    "fit_knots",
    "lsq_fit",
    "quantize_checked",
    "split_segments",
    "axis_records",
    "fixed_period_axis",
)
# every module of the package that calls a step holds its own name for it
MODULES = (pvtflow.planner.knots, check, epos2, fixed_period, quantize, refine, samples)


def time_stages() -> dict[str, float]:
    """Wrap the knot placement's steps with CPU timers; returns the running totals (s) by step."""
    spent = dict.fromkeys(STAGES, 0.0)
    for name in STAGES:
        step = next(getattr(m, name) for m in MODULES if hasattr(m, name))

        def timed(*a, _step=step, _name=name, **k):  # type: ignore[no-untyped-def]
            start = time.process_time()
            try:
                return _step(*a, **k)
            finally:
                spent[_name] += time.process_time() - start

        for m in MODULES:
            if getattr(m, name, None) is step:
                setattr(m, name, timed)
    return spent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=25)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--stages", action="store_true", help="also the CPU time of each step of the placement")
    args = ap.parse_args()
    spent = time_stages() if args.stages else None

    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cell_planner = CellPlanner(cell)
    planner, axes = cell_planner.planner, list(cell_planner.axes)
    assert planner is not None, cell_planner.setup_error
    cell_planner.warm_up()  # numba's compiled loops: loaded (or compiled) before anything is timed
    lim = cell.joint_limits()
    mid, half = (lim.lower + lim.upper) / 2.0, (lim.upper - lim.lower) / 2.0
    rng = np.random.default_rng(args.seed)
    print(
        f"command: python bench/knots_cost.py --paths {args.paths} --waypoints {args.waypoints} "
        f"--repeat {args.repeat} --seed {args.seed}{' --stages' if args.stages else ''}"
    )
    print("range  motion p50  knots p50  knots p90  ms per s of motion  records/axis p50  paths with >1 round")
    stage_rows = []
    for frac in RANGES:
        if spent is not None:
            for name in spent:
                spent[name] = 0.0
        cpu, length, records, rounds = [], [], [], []
        while len(cpu) < args.paths:
            wp = mid - frac * half + 2.0 * frac * half * rng.random((args.waypoints, lim.dof))
            out = planner.plan(PlanInput(wp))
            if not out.ok or out.trajectory is None:
                continue  # the spline leaves the limits: draw again
            best = np.inf
            for _ in range(args.repeat):
                start = time.process_time()
                result = place_knots(out.trajectory, axes)
                best = min(best, time.process_time() - start)
            cpu.append(best * 1000.0)
            length.append(result.duration_ms / 1000.0)
            records.append(np.mean([len(a.records) for a in result.axes]))
            rounds.append(result.rounds)
        c, s = np.array(cpu), np.array(length)
        print(
            f"{frac:4.0%}   {np.median(s):7.2f} s  {np.median(c):7.1f} ms  {np.percentile(c, 90):7.1f} ms"
            f"  {np.median(c / s):12.2f}        {np.median(records):10.0f}        "
            f"{sum(r > 1 for r in rounds)}/{len(rounds)}"
        )
        if spent is not None:
            per_path = 1000.0 / (args.paths * args.repeat)
            stage_rows.append(
                f"{frac:4.0%}   " + ", ".join(f"{n.strip('_')} {t * per_path:.2f}" for n, t in spent.items())
            )
    if stage_rows:
        print("CPU ms per path by step (planner.knots.<module>.<step>):")
        print("\n".join(stage_rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
