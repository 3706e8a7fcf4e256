"""The jerk-limited program's functions compiled (planner/jerk/compiled.py) against casadi's interpreted ones.

For N random arm6 paths of W waypoints (bench/pvt_quality.py's drawing, seeded; jerk F x amax/s, joint limits
only, or the cell's torque and TCP speed rows with ``--cell-rows``), the screened program a deadline solves
on each of ``--intervals``: its arguments taken from a plan with a deadline far off, then fatrop on the
interpreted program and on the compiled one, alternated, ``--repeat`` times each. Prints the library's
build (generate + gcc, into a fresh cache folder) and load times, fatrop's time per solve (p50, p90, max)
and per iteration, its evaluations' share (casadi's statistics), and whether the answers are the same to
the last bit.

Run:  python bench/jerk_compiled.py [--paths 20] [--waypoints 8] [--factor 10] [--seed 1]
      [--intervals 48,96] [--repeat 2] [--cell-rows]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

import pvtflow.planner.jerk as jerk
from pvtflow.planner.jerk.nlp import build_nlp
from pvtflow.planner.jerk.solve import Program, Solution, _solve_now
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import parameterize
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def captured_args(args: argparse.Namespace) -> dict[tuple[int, int, bool], list[tuple[dict[str, Any], Any]]]:
    """The screened programs' arguments by shape, from plans with a deadline far off."""
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    if not args.cell_rows:
        cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
    cp = CellPlanner(cell)
    planner, limits = cp.planner, cp.limits
    jmax = args.factor * limits.acceleration
    found: dict[tuple[int, int, bool], list[tuple[dict[str, Any], Any]]] = {}
    solve_in_time = jerk.solve_in_time

    def spy(program: Program, solver_args: dict[str, Any], scale: Any, *rest: Any) -> Any:
        found.setdefault((program.n, program.dof, program.torque), []).append((solver_args, scale))
        return solve_in_time(program, solver_args, scale, *rest)

    jerk.solve_in_time = spy
    rng = np.random.default_rng(args.seed)
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        path = cp.plan(PlanInput(wp, max_jerk=jmax), budget_ms=0).plan.trajectory.path  # the floor: its path only
        warm = parameterize(path, limits, planner.constraints, planner.gridpoints)
        for n in args.intervals:
            jerk.jerk_limited(path, limits, planner.constraints, jmax, warm, n, time.perf_counter() + 60.0)
    jerk.solve_in_time = solve_in_time
    return {shape: cases for shape, cases in found.items() if shape[0] in args.intervals}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--intervals", type=lambda s: [int(n) for n in s.split(",")], default=[48, 96])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cell-rows", action="store_true", help="the cell's torque and TCP speed rows too")
    args = ap.parse_args()
    cases_by_shape = captured_args(args)
    with tempfile.TemporaryDirectory() as cache:
        os.environ["PVTFLOW_CACHE_DIR"] = cache  # a fresh cache: the build timed from nothing
        for shape, cases in sorted(cases_by_shape.items()):
            interpreted = Program(*shape, *build_nlp(*shape))
            fast = Program(*shape, *build_nlp(*shape))
            began = time.perf_counter()
            assert fast.use_compiled(), "the C compiler failed"
            built = time.perf_counter() - began
            began = time.perf_counter()
            again = Program(*shape, *build_nlp(*shape))
            assert again.use_compiled(build=False)
            loaded = time.perf_counter() - began
            times: dict[str, list[tuple[float, int, float]]] = {"interpreted": [], "compiled": []}
            same = 0
            for program in (interpreted, fast):  # a solver's first solve sets up its memory: not timed
                _solve_now(program, cases[0][0], cases[0][1], float("inf"))
            for _ in range(args.repeat):
                for solver_args, scale in cases:
                    answers: list[Solution] = []
                    for name, program in (("interpreted", interpreted), ("compiled", fast)):
                        sol = _solve_now(program, solver_args, scale, float("inf"))[0]
                        assert sol is not None
                        stats = program.solver("fatrop").stats()
                        evals = sum(v for k, v in stats.items() if k.startswith("t_wall_nlp"))
                        times[name].append((program.fatrop_s[-1], sol.iterations, evals))
                        answers.append(sol)
                    a, b = answers
                    same += all(np.array_equal(x, y) for x, y in ((a.sd, b.sd), (a.sdd, b.sdd), (a.h, b.h), (a.j, b.j)))
            n, dof, torque = shape
            ratio = np.array([c[0] for c in times["compiled"]]) / np.array([c[0] for c in times["interpreted"]])
            print(
                f"{n} intervals, rows of {dof} joints{' with torque' if torque else ''}, {len(cases)} paths: "
                f"library built in {built:.2f} s (generate + gcc), loaded from the cache in {loaded * 1e3:.0f} ms "
                f"(with the interpreted program's build); answers the same to the last bit: {same} of {len(ratio)}"
            )
            for name, rows in times.items():
                t = np.array(rows)
                p50, p90 = np.median(t[:, 0]) * 1e3, np.percentile(t[:, 0], 90) * 1e3
                print(
                    f"  fatrop {name:11s} p50 {p50:6.1f}  p90 {p90:6.1f}"
                    f"  max {np.max(t[:, 0]) * 1e3:6.1f} ms, per iteration {np.median(t[:, 0] / t[:, 1]) * 1e3:.3f} ms,"
                    f" evaluations p50 {np.median(t[:, 2]) * 1e3:5.1f} ms, iterations p50 {np.median(t[:, 1]):.0f}"
                )
            print(f"  compiled / interpreted per solve: p50 {np.median(ratio):.2f}, p90 {np.percentile(ratio, 90):.2f}")
    print(f"load average {os.getloadavg()[0]:.1f}")
    print("command: python bench/jerk_compiled.py " + " ".join(sys.argv[1:]))


if __name__ == "__main__":
    main()
