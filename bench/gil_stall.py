"""Does a jerk-limited solve stall other threads of its interpreter? (issue 39 item 4)

A ticker thread asks to wake every 1 ms (what a SYNC producer in the same interpreter would do)
while the main thread plans: arm6 8-waypoint paths, max_jerk F x amax per second, through
``CellPlanner.plan`` (TOPP-RA, the casadi/fatrop solve, knots) without a deadline on ``--intervals``,
and with ``--budget-ms``. Prints the ticker's longest gap (ms) during each kind of plan and during
an idle stretch of the same length, and the gaps during the casadi solve alone (``jerk_limited``
as the plan calls it, no knots), which tells whether casadi releases the interpreter's lock while it
solves (a gap near the solve's length: it does not); and during builds of the program and both
solvers of 48 and 192 intervals (a cache of the bench's own: built, not found).

Run:  python bench/gil_stall.py [--paths 10] [--intervals 96] [--budget-ms 50]
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
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


class Ticker:
    """A thread that sleeps 1 ms at a time and keeps the longest gap between its wake-ups."""

    def __init__(self) -> None:
        self.worst = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = time.perf_counter()
        while not self._stop.is_set():
            time.sleep(0.001)
            now = time.perf_counter()
            self.worst = max(self.worst, now - last)
            last = now

    def measure(self, work) -> tuple[float, float]:  # type: ignore[no-untyped-def]
        """(wall of ``work``, longest gap during it), both ms."""
        self.worst = 0.0
        began = time.perf_counter()
        work()
        wall = time.perf_counter() - began
        return 1000.0 * wall, 1000.0 * self.worst

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10)
    ap.add_argument("--intervals", type=int, default=96)
    ap.add_argument("--budget-ms", type=float, default=50.0)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    import pvtflow.planner.jerk as jerk_module
    from pvtflow.planner.jerk.solve import ProgramCache

    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    rng = np.random.default_rng(args.seed)
    jerk = args.factor * cp.limits.acceleration
    ticker = Ticker()
    rows: dict[str, list[tuple[float, float]]] = {
        "idle": [],
        "plan, no deadline": [],
        "plan, budget": [],
        "solve, no deadline": [],
        "solve, budget": [],
    }
    solve = jerk_module.jerk_limited

    def timed_solve(*a, **k):  # type: ignore[no-untyped-def]
        out: list[object] = []
        deadline = a[6] if len(a) > 6 else k.get("deadline")
        key = "solve, no deadline" if deadline is None else "solve, budget"
        rows[key].append(ticker.measure(lambda: out.append(solve(*a, **k))))
        return out[0]

    jerk_module.jerk_limited = timed_solve  # planner.plan imports it at the call: the solve alone, timed
    builds = ProgramCache()
    for n in (48, 192):
        rows[f"build {n}"] = [ticker.measure(lambda n=n: builds.get(n, cp.limits.dof, True))]
    try:
        for _ in range(args.paths):
            wp = random_waypoints(cell, rng, 8)
            inp = PlanInput(wp, max_jerk=jerk, jerk_intervals=args.intervals)
            wall, gap = ticker.measure(lambda inp=inp: cp.plan(inp))
            rows["plan, no deadline"].append((wall, gap))
            rows["idle"].append(ticker.measure(lambda wall=wall: time.sleep(wall / 1000.0)))
            rows["plan, budget"].append(ticker.measure(lambda inp=inp: cp.plan(inp, None, None, args.budget_ms)))
    finally:
        ticker.close()
    print(
        f"arm6, {args.paths} paths, {args.intervals} intervals, budget {args.budget_ms:g} ms; "
        f"load average {os.getloadavg()[0]:.1f}; switch interval {1000 * sys.getswitchinterval():.0f} ms"
    )
    for name, values in rows.items():
        if not values:
            print(f"  {name:18s} (not measured)")
            continue
        v = np.array(values)
        print(
            f"  {name:18s} wall p50 {np.median(v[:, 0]):6.1f} ms   longest 1-ms tick gap p50 {np.median(v[:, 1]):6.1f}"
            f"  max {np.max(v[:, 1]):6.1f} ms"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
