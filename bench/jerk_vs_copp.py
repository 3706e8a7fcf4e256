"""Jerk-limited plans side by side with copp-py's TOPP3 (issue 39): the same paths, the same limits.

For N random arm6 paths of W waypoints (bench/pvt_quality.py's drawing, seeded), max_jerk = F x each
joint's acceleration limit per second:

- pvtflow's whole cell plan (TOPP-RA, jerk-limited timing, knots, validation) at every budget of
  ``--budgets`` ("none": no deadline), as the service plans it (``CellPlanner.plan``);
- copp-py's TOPP3 (second-order cone program, Clarabel, started from its own TOPP2-RA) at every station
  count of ``--stations``, on pvtflow's own path (the same polynomial pieces, read through
  ``JointPath.pieces``: q, q_s, q_ss at every station and q_sss of its piece; a station just before
  each inner waypoint, where q_sss jumps), the same joint limits, rest to rest between the rests of
  pvtflow's motion: its ends and every C1 waypoint (where q_ss jumps, a finite jerk passes at rest;
  TOPP3 holds jerk at its stations only and would run through it).

Both get the joint velocity, acceleration and jerk limits only: the cell's TCP speed and torque rows
are switched off for pvtflow here (``--cell-constraints`` keeps them, pvtflow only), since TOPP3 has
no TCP speed row and its torque rows would need the robot model in a Python callback.

Prints, per planner: motion duration over copp's at the most stations (p50, max; pvtflow's is its
program's motion, the trajectory's duration times the knots' slow-down), the worst limit fraction
at every ms (pvtflow: the drives' own reconstruction of the program, ``AxisProgram.reconstruction``;
copp: its s(t) sampled every ms through the exact path, velocity and acceleration by central
differences), the worst 10-ms-window jerk over the limit, and wall time p50 / p99 / max (pvtflow:
the whole plan; copp: the TOPP2 + TOPP3 solves). copp holds its limits at its stations only: its
duration slowed down uniformly to hold velocity and acceleration at every ms is printed beside it.

copp-py (MIT, 0.2.3 measured) is a benchmark reference, not a dependency of pvtflow.

Run:  python bench/jerk_vs_copp.py [--paths 20] [--waypoints 8] [--factor 10] [--seed 1]
      [--budgets 20,50,100,none] [--stations 500,1000] [--intervals N] [--cell-constraints]
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the pvtflow command sets it (service/cli.py)
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

from pvtflow.planner.jerk.warm import rests_of
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlan, CellPlanner
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

DT = 0.001  # s: the drives' millisecond


@dataclass
class Runs:
    """One planner's figures over the paths."""

    duration: list[float] = field(default_factory=list)  # s
    wall: list[float] = field(default_factory=list)  # s
    limit: list[float] = field(default_factory=list)  # worst max(|v| / vmax, |a| / amax) at every ms
    jerk: list[float] = field(default_factory=list)  # worst 10-ms-window jerk / limit
    slowed: list[float] = field(default_factory=list)  # s: copp's duration slowed to hold v, a at every ms
    optimal: int = 0
    answers: list[str] = field(default_factory=list)


def third_derivative(path: JointPath, s: NDArray[np.float64]) -> NDArray[np.float64]:
    """q_sss at ``s``: the constant of the cubic piece each lies in (the right one at a waypoint)."""
    x, c = path.pieces
    piece = np.clip(np.searchsorted(x, s, side="right") - 1, 0, len(x) - 2)
    return 6.0 * c[0][piece]


def copp_plan(
    path: JointPath, limits: JointLimits, jmax: NDArray[np.float64], stations: int
) -> tuple[float, NDArray[np.float64], float]:
    """copp-py's TOPP3-SOCP along ``path``, rest to rest between pvtflow's rests (``rests_of``), with
    ``stations`` stations over the whole path shared out by length: (duration s, s(t) every ms, wall s)."""
    import copp_py as copp

    began = time.perf_counter()
    length = path.length
    rests = rests_of(path)
    duration, samples = 0.0, []
    for lo, hi in itertools.pairwise(rests):
        count = max(50, round(stations * (hi - lo) / length))
        inner = path.waypoint_s[(path.waypoint_s > lo) & (path.waypoint_s < hi)]
        s = np.union1d(np.linspace(lo, hi, count), inner - 1e-7 * length)
        at = s.copy()
        at[-1] -= 1e-9 * length  # the path's derivatives at a rest: of the piece that ends there
        n = len(s)
        robot = copp.Robot(limits.dof)
        robot.append_s(s)
        robot.set_q(path(at), path(at, 1), path(at, 2), 0, dddq=third_derivative(path, at))
        robot.add_velocity_limits(limits.velocity, -limits.velocity, start_idx_s=0, length=n)
        robot.add_acceleration_limits(limits.acceleration, -limits.acceleration, start_idx_s=0, length=n)
        robot.add_jerk_limits(jmax, -jmax, start_idx_s=0, length=n)
        a2 = copp.solver.topp2_ra.solve(copp.solver.topp2_ra.Problem(robot.constraints, (0, n - 1), (0.0, 0.0)))
        problem = copp.solver.topp3_socp.Problem(
            robot.constraints, a2, a_boundary=(0.0, 0.0), b_boundary=(0.0, 0.0), num_stationary_max=1
        )
        profile = copp.solver.topp3_socp.solve(problem)
        part, t_s = copp.interpolation.s_to_t_topp3(s, profile)
        duration += float(part)
        samples.append(np.clip(copp.interpolation.t_to_s_topp3_uniform(s, profile, t_s, DT), lo, hi))
    return duration, np.concatenate(samples), time.perf_counter() - began


def sampled_ratios(
    q: NDArray[np.float64], dt: float, limits: JointLimits, jmax: NDArray[np.float64]
) -> tuple[float, float, float]:
    """Worst |v| / vmax, |a| / amax (central differences) and 10-ms-window jerk / limit of positions
    ``q`` (samples, dof) every ``dt``, at rest before and after."""
    q = np.vstack((q[:1], q[:1], q, q[-1:], q[-1:]))
    v = (q[2:] - q[:-2]) / (2.0 * dt)
    a = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / (dt * dt)
    w = max(1, round(WINDOW_MS / 1000.0 / dt))
    j = np.abs(a[w:] - a[:-w]) / (w * dt)
    return (
        float(np.max(np.abs(v) / limits.velocity)),
        float(np.max(np.abs(a) / limits.acceleration)),
        float(np.max(j / jmax)),
    )


def drive_ratios(
    res: CellPlan, cell: CellConfig, limits: JointLimits, jmax: NDArray[np.float64]
) -> tuple[float, float]:
    """Worst max(|v| / vmax, |a| / amax) of the drives' reconstruction at every ms, and the worst
    10-ms-window jerk / limit (``planner.knots.window_jerk``)."""
    assert res.program is not None
    worst, jerk = 0.0, 0.0
    for i, (cfg, ap) in enumerate(zip(cell.ordered_axes(), res.program.axes, strict=True)):
        recon = ap.reconstruction()
        unit = cfg.scaling.qc_per_joint_unit
        t = np.arange(recon.start[0], recon.end_time + 1e-9, 1.0)
        v = np.abs(recon.velocity(t)) * 1e3 / unit / limits.velocity[i]
        a = np.abs(recon.acceleration(t)) * 1e6 / unit / limits.acceleration[i]
        worst = max(worst, float(v.max()), float(a.max()))
        jerk = max(jerk, window_jerk(recon) * 1e9 / unit / jmax[i])
    return worst, jerk


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--budgets", default="20,50,100,none")
    ap.add_argument("--stations", default="500,1000")
    ap.add_argument("--intervals", type=int, default=None, help="pvtflow grid at most (jerk_intervals)")
    ap.add_argument("--cell-constraints", action="store_true", help="pvtflow keeps the cell's TCP speed and torque")
    args = ap.parse_args()
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    if not args.cell_constraints:
        cell = replace(cell, planning=replace(cell.planning, max_tcp_speed=None, torque_limits=False))
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    limits = cp.limits
    jmax = args.factor * limits.acceleration
    # the finest grid, which a plan without a deadline builds on first use (the warm-up builds the ones a
    # deadline may use): built here, not inside the first timed plan
    lo, hi = limits.lower, limits.upper
    warm = np.array([lo + 0.4 * (hi - lo), lo + 0.6 * (hi - lo)])
    cp.plan(PlanInput(warm, max_jerk=jmax, jerk_intervals=args.intervals))
    budgets = [None if b.strip() == "none" else float(b) for b in args.budgets.split(",")]
    stations = [int(n) for n in args.stations.split(",")]
    names = [f"pvtflow {'none' if b is None else f'{b:g} ms'}" for b in budgets] + [f"copp {n}" for n in stations]
    runs = {name: Runs() for name in names}
    reference = f"copp {max(stations)}"
    ref_duration: list[float] = []
    ref_slowed: list[float] = []
    rng = np.random.default_rng(args.seed)
    for _ in range(args.paths):
        wp = random_waypoints(cell, rng, args.waypoints)
        path = None
        for b, name in zip(budgets, names, strict=False):
            began = time.perf_counter()
            res = cp.plan(PlanInput(wp, max_jerk=jmax, jerk_intervals=args.intervals), budget_ms=b)
            wall = time.perf_counter() - began
            run = runs[name]
            run.answers.append(res.code)
            if not res.ok or res.plan is None or res.build is None:
                run.duration.append(np.nan)  # no motion (a timeout: past its budget)
                continue
            traj = res.plan.trajectory
            path = traj.path
            run.duration.append(traj.duration * res.build.knots.time_scale)
            run.wall.append(wall)
            run.optimal += int(res.optimal)
            worst, jerk = drive_ratios(res, cell, limits, jmax)
            run.limit.append(worst)
            run.jerk.append(jerk)
        assert path is not None, "no pvtflow plan on this path"
        for n in stations:
            duration, s_t, wall = copp_plan(path, limits, jmax, n)
            rv, ra, rj = sampled_ratios(path(s_t), DT, limits, jmax)
            run = runs[f"copp {n}"]
            run.duration.append(duration)
            run.wall.append(wall)
            run.limit.append(max(rv, ra))
            run.jerk.append(rj)
            run.slowed.append(duration * max(1.0, rv, np.sqrt(ra)))
            run.answers.append("ok")
        ref_duration.append(runs[reference].duration[-1])
        ref_slowed.append(runs[reference].slowed[-1])
    print(
        f"arm6, {args.paths} paths of {args.waypoints} waypoints (seed {args.seed}), "
        f"max_jerk {args.factor:g} x amax/s, "
        f"{'the cell TCP speed and torque for pvtflow' if args.cell_constraints else 'joint limits only'}"
    )
    print(
        f"{'planner':<18} {'answers':>8} {'optimal':>7} {'dur/' + reference + ' p50':>18} {'max':>6} "
        f"{'limit@1ms max':>13} {'win jerk max':>12} {'wall ms p50':>11} {'p99':>7} {'max':>7}"
    )
    for name in names:
        run = runs[name]
        ratio = np.array(run.duration) / np.array(ref_duration)  # nan: no answer (over the answered only)
        ok = sum(a == "ok" for a in run.answers)
        wall = 1000.0 * np.array(run.wall)
        print(
            f"{name:<18} {ok:>4}/{len(run.answers):<3} {run.optimal if name.startswith('pvtflow') else '-':>7} "
            f"{np.nanmedian(ratio):>18.4f} {np.nanmax(ratio):>6.4f} {max(run.limit, default=np.nan):>13.4f} "
            f"{max(run.jerk, default=np.nan):>12.3f} {percentile(list(wall), 50):>11.1f} "
            f"{percentile(list(wall), 99):>7.1f} {np.max(wall) if len(wall) else np.nan:>7.1f}"
        )
        if run.slowed:
            slowed = np.array(run.slowed) / np.array(ref_duration)
            print(f"{'  slowed to 1 ms':<18} {'':>8} {'':>7} {np.median(slowed):>18.4f} {slowed.max():>6.4f}")
    for name in names:
        if name.startswith("pvtflow"):
            r = np.array(runs[name].duration) / np.array(ref_slowed)
            within = float(np.mean(r <= 1.03))  # no answer: not within
            codes = sorted({a for a in runs[name].answers if a != "ok"})
            print(
                f"{name}: / {reference} slowed to 1 ms: p50 {np.nanmedian(r):.4f} max {np.nanmax(r):.4f}, "
                f"within 1.03x: {within:.0%}" + (f"; not answered: {', '.join(codes)}" if codes else "")
            )
    print(
        f"command: python bench/jerk_vs_copp.py --paths {args.paths} --waypoints {args.waypoints} --factor "
        f"{args.factor:g} --seed {args.seed} --budgets {args.budgets} --stations {args.stations}"
        + (f" --intervals {args.intervals}" if args.intervals else "")
        + (" --cell-constraints" if args.cell_constraints else "")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
