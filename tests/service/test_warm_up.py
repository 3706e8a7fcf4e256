"""After a service's warm-up, no request compiles: every planner kernel a plan calls was loaded with
the types it is called with. On a new machine a kernel compiled mid-request costs seconds (a fresh
clone's first straight tool line took 3.9 s against its 200 ms budget), so a new numba type seen
only after the warm-up is a bug, whatever the cache on this machine holds.

The check runs in a child interpreter: this one has planned every kind of motion by now."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]

# One child, one warm-up, both checks: the numba kernels' signatures and the casadi programs built, each
# taken right after the warm-up; the jerk-limited requests within deadlines first (what they build is
# compared before any plan without a deadline), then every other kind of plan.
CHILD = r"""
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from pvtflow.planner.jerk import solve
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import load_cell_config

def signatures():
    seen = {}
    for name, module in list(sys.modules.items()):
        if not (name.startswith("pvtflow.planner") or name.startswith("pvtflow.axes")):
            continue
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher):
                seen[f"{value.py_func.__module__}.{value.py_func.__qualname__}"] = sorted(map(str, value.signatures))
    return seen

def built():
    return {str(shape): sorted(solve.PROGRAMS.ready(*shape).solvers) for shape in solve.PROGRAMS.shapes()}

planner = CellPlanner(load_cell_config(None))
planner.warm_up()
kernels = signatures()
before = built()
times = {str(s): [len(solve.PROGRAMS.ready(*s).iteration_s), len(solve.PROGRAMS.ready(*s).fatrop_s)]
         for s in solve.PROGRAMS.shapes()}
lo, hi = planner.limits.lower, planner.limits.upper
rng = np.random.default_rng(5)
jerk = 10.0 * planner.limits.acceleration
answers = []
for count, budget in ((8, 200.0), (8, 50.0), (8, 100.0), (60, 50.0), (3, None)):
    waypoints = lo + (0.15 + 0.7 * rng.random((count, len(lo)))) * (hi - lo)
    result = planner.plan(PlanInput(waypoints, max_jerk=jerk), budget_ms=budget)
    answers.append([count, budget, result.code, result.message])
    if budget is not None:
        after = built()
last = built()

start = np.array([0.2, 0.3, 0.4, 0.1, 0.6, 0.2])
pose = [0.7, 0.17, -0.04, 0.07, 0.61, 0.02, 0.789]
planner.plan(PlanInput(start, [pose, [0.7, 0.27, -0.04, 0.07, 0.61, 0.02, 0.789]], "linear"))
planner.plan(PlanInput(start, [pose], "joint"))
rng = np.random.default_rng(7)
for _ in range(4):
    planner.plan(PlanInput(lo + (0.15 + 0.7 * rng.random((8, len(lo)))) * (hi - lo)))
planner.plan(PlanInput(lo + (0.3 + 0.4 * rng.random((3, len(lo)))) * (hi - lo), max_jerk=jerk))
new = {k: sorted(set(v) - set(kernels.get(k, []))) for k, v in signatures().items()}
compiled = {k: v for k, v in new.items() if v}
print(json.dumps({"compiled": compiled, "before": before, "after": after, "last": last, "answers": answers,
                  "times": times}))
"""


@pytest.fixture(scope="module")
def seen() -> dict[str, Any]:
    """What the child saw (it plans for 10-20 s: once for both tests)."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_no_plan_compiles_after_the_warm_up(seen: dict[str, Any]) -> None:
    assert seen["compiled"] == {}


def test_after_the_warm_up_no_jerk_limited_plan_builds_a_solver(seen: dict[str, Any]) -> None:
    """Every casadi program and solver a jerk-limited request within a deadline may need is built by
    the warm-up (both solvers of every program size a deadline may use: a build is 0.6 s, past any
    budget), the first request after it included: the deadline is kept by the solve, not lost to a
    build. The wall time at budget_ms 50 is bench/plan_budget.py's (bench/RESULTS.md)."""
    assert seen["after"] == seen["before"]
    assert all(solvers == ["fatrop", "ipopt"] for solvers in seen["before"].values())
    # every grid a path of up to 44 waypoints may be solved on within a deadline: 48, 96, each with every
    # joint's rows and with the fewer a deadline solves (planner/jerk/screen.py)
    shapes = [ast.literal_eval(shape) for shape in seen["before"]]
    assert sorted(n for n, _, _ in shapes) == [48, 48, 96, 96]
    assert all(sorted(d for m, d, _ in shapes if m == n)[-1] == 6 for n in (48, 96))  # the cell's 6 joints
    assert all(sorted(d for m, d, _ in shapes if m == n)[0] < 6 for n in (48, 96))
    # without a deadline the finest grid (planner.jerk.DEFAULT_JERK_INTERVALS), built by the first such plan
    assert sorted(ast.literal_eval(shape)[0] for shape in seen["last"]) == [48, 48, 96, 96, 192]
    assert seen["answers"][-1][2] == "ok", seen["answers"][-1]
    # the first request after the start, at the cell's default budget: never a timeout
    assert seen["answers"][0][2] == "ok", seen["answers"][0]
    # the programs a deadline solves know their time per iteration from the warm-up (whether a first
    # request's solve starts: planner/jerk/solve.py), none of the warm-up's solve times
    screened = [shape for shape in seen["times"] if ast.literal_eval(shape)[1] < 6]
    assert screened and all(seen["times"][shape][0] >= 1 for shape in screened)
    assert all(fatrop == 0 for _, fatrop in seen["times"].values())
