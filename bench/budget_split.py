"""Where a jerk-limited plan's budget goes (issue 39 item 2): the parts of a cell plan timed apart.

For N random arm6 paths (bench/pvt_quality.py's drawing, max_jerk = F x each joint's acceleration
limit per second), two plans of each path through ``CellPlanner.plan``:

- the S-curve floor (``budget_ms`` 0: no solver has time): ``floor`` its timing (the S-curve and its
  dense check, ``timing["jerk"]``), ``floor knots`` its knot placement and validation;
- the solver's answer on ``--intervals`` (no deadline): ``topp`` TOPP-RA, ``solve`` the jerk-limited
  timing (fatrop and the dense check), ``check`` the dense check and slow-down of the solver's answer
  alone (what follows a solve that finishes at the deadline, before its knots), ``knots`` knot
  placement and validation of that motion; and
  from fatrop's own statistics its iterations and the share of its wall time spent evaluating the
  program's functions (what casadi's generated C code could speed up; the rest is fatrop's own
  linear algebra).

Prints p50 / p99 / max of each (ms). The reserve a budget keeps back from the solve
(``service.cell_planner.knots_reserve_ms``) must cover the floor and its knots where the solve
comes late, the answer's knots where it does not.

Run:  python bench/budget_split.py [--paths 20] [--intervals 48] [--factor 10] [--waypoints 8] [--seed 1]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

_EVALUATIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_hess_l", "nlp_jac_g")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--intervals", type=int, default=48)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    from pvtflow.planner.jerk.solve import PROGRAMS  # casadi: loaded by the warm-up

    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    rng = np.random.default_rng(args.seed)
    jerk = args.factor * cp.limits.acceleration
    parts: dict[str, list[float]] = {
        k: [] for k in ("floor", "floor knots", "topp", "solve", "check", "knots", "fatrop", "fatrop evaluations")
    }
    import time

    import pvtflow.planner.jerk as jerk_module

    checked = jerk_module._checked
    checks: list[float] = []

    def timed_check(*a, **k):  # type: ignore[no-untyped-def]
        began = time.perf_counter()
        try:
            return checked(*a, **k)
        finally:
            checks.append(time.perf_counter() - began)

    jerk_module._checked = timed_check  # jerk_limited looks it up at the call
    iterations: list[int] = []
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        floor = cp.plan(PlanInput(wp, max_jerk=jerk), None, None, 0.0)
        parts["floor"].append(floor.timing.get("jerk", np.nan))
        parts["floor knots"].append(floor.timing.get("knots", np.nan))
        checks.clear()
        best = cp.plan(PlanInput(wp, max_jerk=jerk, jerk_intervals=args.intervals))
        parts["check"].append(checks[-1] if checks else np.nan)
        for key, name in (("topp", "topp"), ("solve", "jerk"), ("knots", "knots")):
            parts[key].append(best.timing.get(name, np.nan))
        program = next(PROGRAMS.ready(*s) for s in PROGRAMS.shapes() if s[0] == args.intervals)
        stats = program.solver("fatrop").stats()
        parts["fatrop"].append(program.fatrop_s[-1])
        parts["fatrop evaluations"].append(sum(float(stats.get(f"t_wall_{e}", 0.0)) for e in _EVALUATIONS))
        iterations.append(int(stats.get("iter_count", 0)))
    print(
        f"arm6, {args.paths} paths of {args.waypoints} waypoints, max_jerk {args.factor:g} x amax/s, "
        f"{args.intervals} intervals; load average {os.getloadavg()[0]:.1f}"
    )
    for key, values in parts.items():
        v = 1000.0 * np.array(values)
        p50, p99 = np.nanpercentile(v, 50), np.nanpercentile(v, 99)
        print(f"  {key:20s} ms: p50 {p50:6.1f}  p99 {p99:6.1f}  max {np.nanmax(v):6.1f}")
    share = np.array(parts["fatrop evaluations"]) / np.array(parts["fatrop"])
    print(
        f"  fatrop iterations p50 {np.median(iterations):.0f} max {max(iterations)}; "
        f"evaluations' share of its time p50 {np.median(share):.2f}"
    )
    print(
        f"  command: python bench/budget_split.py --paths {args.paths} --intervals {args.intervals} "
        f"--factor {args.factor:g} --waypoints {args.waypoints} --seed {args.seed}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
