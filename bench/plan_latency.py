"""Planning latency and optimality on the 6-axis arm (issue: foundation).

200 random paths of 8 in-limit waypoints on the arm6 cell, one core. For each path: the wall
time of Planner.plan (path + TOPP-RA + post-check) and its duration divided by the duration of a
TOPP-RA reference with 3000 gridpoints under the same constraints. The VM is shared and its wall
clock noisy: the CPU time of each plan (process time, the same single thread) is printed as well.

The full plan as the service makes it (``CellPlanner.plan``: the cell's constraints, trajectory,
knot placement, the validated PVT program) is timed on the same waypoint sets, wall and CPU time
(this thread's) side by side, with its parts (trajectory, knots, validation); its target (issue
25) is wall p50 <= 3 ms, p99 <= 5 ms. On a loaded host the wall figures are upper bounds; the CPU
figures are inflated less.

Every drawn waypoint set is planned (none is redrawn); the refused count is printed. The figures
are also given apart for the sets the path before issue 13 (the not-a-knot spline,
bench/old_spline.py) accepted, where the path is that spline, and for those it refused, with the
duration and path length against the spline timed as if it had been allowed.

Run:  python bench/plan_latency.py [--paths 200] [--seed 1] [--constraints joint|cell]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # this tree's planner, not an installed one

from old_spline import arc_length, spline_path

from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.timing import parameterize
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import load_cell_config


def p50_p99(x: np.ndarray) -> str:
    return f"p50 {np.percentile(x, 50):.2f} ms  p99 {np.percentile(x, 99):.2f} ms"


def full_plans(cell, paths: list[np.ndarray]) -> np.ndarray:
    """(wall, CPU, trajectory, knots, validation) in ms of ``CellPlanner.plan`` on every set, after
    a warm-up (compiled loops loaded, caches filled) on other sets."""
    cp = CellPlanner(cell)
    cp.warm_up()
    warm = np.random.default_rng(4242)
    lim = cp.limits
    for _ in range(20):
        cp.plan(PlanInput(warm.uniform(0.3 * lim.lower, 0.3 * lim.upper, (len(paths[0]), lim.dof))))
    rows = []
    for w in paths:
        c0, t0 = time.thread_time(), time.perf_counter()
        res = cp.plan(PlanInput(w))
        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if not res.ok or res.build is None:
            print(f"full plan REFUSED: {res.code}: {res.message}", file=sys.stderr)
            continue
        b = res.build.timing
        rows.append((wall, cpu, res.timing["plan"], b["knots"], b["validation"]))
    return np.array(rows) * 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--paths", type=int, default=200)
    parser.add_argument("--waypoints", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--range", type=float, default=0.7, help="waypoints drawn in this fraction of each joint range")
    parser.add_argument(
        "--constraints",
        choices=("joint", "cell"),
        default="joint",
        help="joint: the drive-derived joint velocity/acceleration limits (the issue's case); "
        "cell: plus the cell's torque (RNEA) and TCP speed limits",
    )
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[-1]})

    cell = load_cell_config(None)
    limits = cell.joint_limits()
    extra = {}
    if args.constraints == "cell":
        extra = dict(
            model=cell.model,
            tcp_frame=cell.planning.tcp_frame,
            max_tcp_speed=cell.planning.max_tcp_speed,
            torque_limits=cell.planning.torque_limits,
        )
    planner = Planner(limits, **extra)
    reference = Planner(limits, gridpoints=3000, speed_band=0.0, **extra)  # the time-optimal profile

    rng = np.random.default_rng(args.seed)
    warm = np.random.default_rng(args.seed + 1000)  # warm caches and clocks on paths that are not measured
    for _ in range(20):
        planner.plan(PlanInput(warm.uniform(0.3 * limits.lower, 0.3 * limits.upper, (args.waypoints, limits.dof))))
    latencies, cpu_times, durations, paths, planned, refused = [], [], [], [], [], 0
    for k in range(args.paths):  # every drawn set is planned: none is redrawn
        mid, half = 0.5 * (limits.upper + limits.lower), 0.5 * args.range * (limits.upper - limits.lower)
        waypoints = rng.uniform(mid - half, mid + half, (args.waypoints, limits.dof))
        c0, t0 = time.process_time(), time.perf_counter()
        out = planner.plan(PlanInput(waypoints))
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        if not out.ok:
            print(f"path {k}: REFUSED: {out.result.value}: {out.message}", file=sys.stderr)
            refused += 1
            continue
        latencies.append(elapsed)
        cpu_times.append(cpu)
        durations.append(out.trajectory.duration)
        paths.append(waypoints)
        planned.append(out.trajectory)
    full = full_plans(cell, paths)
    # the references afterwards, so that their big solves do not disturb the timed ones
    ratios = [d / reference.plan(PlanInput(w)).trajectory.duration for d, w in zip(durations, paths, strict=True)]
    accepted, spline_duration, spline_length = [], [], []
    for w, traj in zip(paths, planned, strict=True):
        spline, ok = spline_path(w, limits)
        old = parameterize(spline, limits, planner.constraints, planner.gridpoints)
        accepted.append(ok)
        spline_duration.append(traj.duration / old.duration)
        spline_length.append(arc_length(traj.path) / arc_length(spline))

    lat = np.array(latencies) * 1e3
    cpu = np.array(cpu_times) * 1e3
    r = np.array(ratios)
    kept = np.array(accepted, dtype=bool)
    print(
        f"command: python bench/plan_latency.py --paths {args.paths} --seed {args.seed} "
        f"--range {args.range} --constraints {args.constraints}"
    )
    print(
        f"cell arm6, {limits.dof} axes, {args.waypoints} waypoints in {args.range:.0%} of each range, "
        f"{args.paths} drawn waypoint sets, {refused} refused by the planner (none redrawn), one core"
    )
    print(
        f"planning latency  p50 {np.percentile(lat, 50):.2f} ms   p99 {np.percentile(lat, 99):.2f} ms   "
        f"max {lat.max():.2f} ms"
    )
    print(
        f"planning CPU time p50 {np.percentile(cpu, 50):.2f} ms   p99 {np.percentile(cpu, 99):.2f} ms   "
        f"max {cpu.max():.2f} ms"
    )
    print(
        f"full plan with its PVT program (CellPlanner.plan, the cell's constraints), {len(full)} sets: "
        f"wall {p50_p99(full[:, 0])}; CPU {p50_p99(full[:, 1])}"
    )
    print(
        f"  of which (wall) trajectory {p50_p99(full[:, 2])}, knot placement {p50_p99(full[:, 3])}, "
        f"validation {p50_p99(full[:, 4])}"
    )
    print(f"duration / 3000-gridpoint reference   min {r.min():.4f}   median {np.median(r):.4f}   max {r.max():.4f}")
    print(f"paths over 1.01: {int(np.sum(r > 1.01))}")
    d, n = np.array(spline_duration), np.array(spline_length)
    for what, sel in (("the old spline accepted", kept), ("the old spline refused", ~kept)):
        if not sel.any():
            continue
        print(
            f"{int(sel.sum())} sets {what}: latency p50 {np.percentile(lat[sel], 50):.2f} ms   "
            f"p99 {np.percentile(lat[sel], 99):.2f} ms   CPU p50 {np.percentile(cpu[sel], 50):.2f} ms   "
            f"p99 {np.percentile(cpu[sel], 99):.2f} ms"
        )
        print(
            f"  duration / the spline's (timed as if allowed) median {np.median(d[sel]):.4f}   "
            f"min {d[sel].min():.4f}   max {d[sel].max():.4f};   path length / the spline's median "
            f"{np.median(n[sel]):.4f}   min {n[sel].min():.4f}   max {n[sel].max():.4f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
