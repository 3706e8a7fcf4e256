"""Jerk-limited time-optimal timing (casadi) against TOPP-RA, on random arm6 (and gantry3) paths.

For every path (bench/pvt_quality.py's drawing) and every jerk limit (max_jerk = F x each joint's
acceleration limit per second, for each F of --factors): plan with TOPP-RA and with the jerk
limit, place the knots of both and validate both programs. Prints, per factor:

- the jerk-limited solve time (the nonlinear program and its dense check: ``planner.jerk``),
  p50 / p99, and the whole jerk-limited plan (TOPP-RA warm start + solve + knots + validation);
- the planned duration over TOPP-RA's (and the programs' durations);
- the worst planned |jerk| / limit, |v| / vmax and |a| / amax, densely (64 samples per interval);
- validator errors of the programs (the drives' own reconstruction against 0x607F / 0x60C5);
- records per axis per second, TOPP-RA's and jerk-limited;
- the jerk of the drive's reconstruction per segment (the cubic's 6 c3, in joint units / s^3)
  over the jerk limit: p50 / p99 / max over all segments, TOPP-RA's programs against the
  jerk-limited ones;
- the drive's executed jerk: the 10-ms-window jerk of each axis's reconstruction (peak over t of
  |a(t + 10 ms) - a(t)| / 10 ms, ``planner.knots.window_jerk``) over the jerk limit, as a maximum
  over every axis and every path (target: <= 1.2), and its p50 over the paths.

``--plot FILE`` writes one path's acceleration and jerk, TOPP-RA against jerk-limited.

Run:  python bench/jerk.py [--cells arm6,gantry3] [--paths 100] [--waypoints 8] [--factors 10,4] [--seed 1]
      [--plot bench/jerk.png]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the pvtflow command sets it (service/cli.py)
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pvt_quality import random_waypoints

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.jerk import JerkTrajectory
from pvtflow.planner.knots.window_jerk import window_jerk
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlan, CellPlanner
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

DENSE = 64  # samples per grid interval for the planned jerk / velocity / acceleration


@dataclass
class PathResult:
    factor: float
    t_solve: float  # s: the jerk-limited timing (nonlinear program + dense check)
    t_total: float  # s: the whole jerk-limited plan (TOPP-RA, timing, knots, validation)
    duration_ratio: float  # planned jerk-limited duration / TOPP-RA's
    program_ratio: float  # program durations, same ratio
    jerk_ratio: float  # worst planned |q'''| / limit
    v_ratio: float
    a_ratio: float
    violations: int  # validator errors of the jerk-limited program
    topp_violations: int
    records: float  # per axis per second, jerk-limited
    topp_records: float
    segment_jerk: np.ndarray  # per reconstruction segment |jerk| / limit, jerk-limited program
    topp_segment_jerk: np.ndarray
    window_jerk: float  # the drive's 10-ms-window jerk / limit, worst axis of the jerk-limited program
    topp_window_jerk: float
    solver: str
    iterations: int


def segment_jerk(program: PvtProgram, cell: CellConfig, max_jerk: np.ndarray) -> np.ndarray:
    """|jerk| of every segment of the drives' reconstruction (6 c3 qc/ms^3), over the joint's limit."""
    out = []
    for cfg, ap, jmax in zip(cell.ordered_axes(), program.axes, max_jerk, strict=True):
        recon = ap.reconstruction()
        jerk = np.abs(6.0 * recon.c3) * 1e9 / cfg.scaling.qc_per_joint_unit  # joint units / s^3
        out.append(jerk / jmax)
    return np.concatenate(out)


def drive_window_jerk(program: PvtProgram, cell: CellConfig, max_jerk: np.ndarray) -> float:
    """The worst axis's 10-ms-window jerk of the drive's own reconstruction, over its limit."""
    return max(
        window_jerk(ap.reconstruction()) * 1e9 / cfg.scaling.qc_per_joint_unit / jmax  # joint units / s^3
        for cfg, ap, jmax in zip(cell.ordered_axes(), program.axes, max_jerk, strict=True)
    )


def records_per_axis_s(program: PvtProgram) -> float:
    return float(np.mean([len(a.records) for a in program.axes])) / (program.duration_ms / 1000.0)


def dense_ratios(traj: JerkTrajectory, cp: CellPlanner, max_jerk: np.ndarray) -> tuple[float, float, float]:
    t = traj.check_times(DENSE)
    lim = cp.limits
    return (
        float(np.max(np.abs(traj.velocity(t)) / lim.velocity)),
        float(np.max(np.abs(traj.acceleration(t)) / lim.acceleration)),
        float(np.max(np.abs(traj.jerk(t)) / max_jerk)),
    )


def run_path(cp: CellPlanner, wp: np.ndarray, factor: float, topp: CellPlan) -> PathResult:
    max_jerk = factor * cp.limits.acceleration
    res = cp.plan(PlanInput(wp, max_jerk=max_jerk))
    if not res.ok or res.program is None or res.plan is None:
        raise RuntimeError(f"jerk-limited plan failed ({res.code}): {res.message}")
    traj = res.plan.trajectory
    assert isinstance(traj, JerkTrajectory)
    assert topp.program is not None and topp.plan is not None and topp.plan.trajectory is not None
    v, a, j = dense_ratios(traj, cp, max_jerk)
    return PathResult(
        factor=factor,
        t_solve=float(res.plan.details.get("jerk_s", math.nan)),  # type: ignore[arg-type]
        t_total=res.timing["total"],
        duration_ratio=traj.duration / topp.plan.trajectory.duration,
        program_ratio=res.program.duration_ms / topp.program.duration_ms,
        jerk_ratio=j,
        v_ratio=v,
        a_ratio=a,
        violations=len(validate_program(res.program).errors),
        topp_violations=len(validate_program(topp.program).errors),
        records=records_per_axis_s(res.program),
        topp_records=records_per_axis_s(topp.program),
        segment_jerk=segment_jerk(res.program, cp.cell, max_jerk),
        topp_segment_jerk=segment_jerk(topp.program, cp.cell, max_jerk),
        window_jerk=drive_window_jerk(res.program, cp.cell, max_jerk),
        topp_window_jerk=drive_window_jerk(topp.program, cp.cell, max_jerk),
        solver=traj.solver,
        iterations=traj.iterations,
    )


def plot(cp: CellPlanner, wp: np.ndarray, factor: float, out: Path) -> None:
    """Acceleration (planned) and jerk (the drives' reconstruction) of one path, normalised by the
    limits: TOPP-RA against jerk-limited."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    max_jerk = factor * cp.limits.acceleration
    topp, jl = cp.plan(PlanInput(wp)), cp.plan(PlanInput(wp, max_jerk=max_jerk))
    assert topp.plan and topp.plan.trajectory and jl.plan and jl.plan.trajectory and topp.program and jl.program
    fig, axes = plt.subplots(2, 2, figsize=(13, 7), sharex="col", sharey="row")
    for col, (name, res) in enumerate((("TOPP-RA", topp), (f"jerk-limited ({factor:g} x amax / s)", jl))):
        traj, program = res.plan.trajectory, res.program  # type: ignore[union-attr]
        t = np.linspace(0.0, traj.duration, 4000)
        acc = traj.acceleration(t) / cp.limits.acceleration
        ax = axes[0, col]
        for j, name_j in enumerate(cp.limits.names):
            ax.plot(t, acc[:, j], lw=0.9, label=name_j)
        ax.set_title(f"{name}: {traj.duration:.2f} s")
        ax.set_ylabel("planned acceleration / amax")
        ax.axhline(1.0, color="k", lw=0.5, ls=":")
        ax.axhline(-1.0, color="k", lw=0.5, ls=":")
        ax = axes[1, col]
        dwell = program.axes[0].records[0, 2]
        for j, (cfg, ap) in enumerate(zip(cp.cell.ordered_axes(), program.axes, strict=True)):
            recon = ap.reconstruction()
            jerk = 6.0 * recon.c3 * 1e9 / cfg.scaling.qc_per_joint_unit / max_jerk[j]
            ts = (np.column_stack((recon.start, recon.start + recon.duration)).ravel() - dwell) / 1000.0
            ax.plot(ts, np.repeat(jerk, 2), lw=0.9, label=cp.limits.names[j])
        ax.set_ylabel("drive's jerk / max_jerk")
        ax.set_xlabel("t [s]")
        ax.axhline(1.0, color="k", lw=0.5, ls=":")
        ax.axhline(-1.0, color="k", lw=0.5, ls=":")
        ax.set_ylim(-6, 6)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2)
    fig.suptitle(
        "arm6, 8 waypoints: planned acceleration and the jerk of the drives' cubic segments (TOPP-RA's is clipped at 6)"
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"  plot written to {out}", file=sys.stderr)


def run_cell(
    cell: CellConfig, args: argparse.Namespace, factors: list[float]
) -> tuple[CellPlanner, list[tuple[np.ndarray, CellPlan]]]:
    """Every figure of the module docstring on ``args.paths`` random paths of ``cell``."""
    t0 = time.perf_counter()
    cp = CellPlanner(cell)
    cp.warm_up(jerk=True)
    print(f"  warm-up (compiled loops, casadi program): {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    rng = np.random.default_rng(args.seed)
    paths: list[tuple[np.ndarray, CellPlan]] = []
    refused = 0
    while len(paths) < args.paths:
        wp = random_waypoints(cell, rng, args.waypoints)
        topp = cp.plan(PlanInput(wp))
        if not topp.ok:
            refused += 1
            continue
        paths.append((wp, topp))
    results: dict[float, list[PathResult]] = {f: [] for f in factors}
    failures: dict[float, list[str]] = {f: [] for f in factors}
    for i, (wp, topp) in enumerate(paths):
        for f in factors:
            try:
                results[f].append(run_path(cp, wp, f, topp))
            except RuntimeError as exc:
                failures[f].append(str(exc))
        if (i + 1) % 20 == 0:
            print(f"  {i + 1}/{len(paths)} paths", file=sys.stderr)

    print(
        f"jerk: {len(paths)} {cell.name} paths, {args.waypoints} waypoints each, seed {args.seed} "
        f"({refused} random paths refused by the planner)"
    )
    for f in factors:
        rs = results[f]
        print(f"max_jerk = {f:g} x amax / s: {len(rs)} planned, {len(failures[f])} failed")
        for msg in failures[f][:3]:
            print(f"  failed: {msg}")
        if not rs:
            continue
        ts = np.array([r.t_solve for r in rs]) * 1000
        tt = np.array([r.t_total for r in rs]) * 1000
        dr = np.array([r.duration_ratio for r in rs])
        pr = np.array([r.program_ratio for r in rs])
        it = np.array([r.iterations for r in rs])
        solvers = {s: sum(r.solver == s for r in rs) for s in dict.fromkeys(r.solver for r in rs)}
        p50, p99 = np.percentile(ts, 50), np.percentile(ts, 99)
        print(
            f"  solve time p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {ts.max():.1f} ms "
            f"(iterations p50 {np.percentile(it, 50):.0f}, max {it.max()}; solvers {solvers})"
        )
        p50, p99 = np.percentile(tt, 50), np.percentile(tt, 99)
        print(f"  whole plan (TOPP-RA + timing + knots + validation) p50 {p50:.1f} ms, p99 {p99:.1f} ms")
        print(
            f"  duration / TOPP-RA's: mean {dr.mean():.3f}, p50 {np.percentile(dr, 50):.3f}, max {dr.max():.3f} "
            f"(programs: mean {pr.mean():.3f})"
        )
        worst_j, worst_v, worst_a = (max(getattr(r, f) for r in rs) for f in ("jerk_ratio", "v_ratio", "a_ratio"))
        print(f"  worst planned |jerk| / limit {worst_j:.6f}, |v| / vmax {worst_v:.6f}, |a| / amax {worst_a:.6f}")
        errors, topp_errors = sum(r.violations for r in rs), sum(r.topp_violations for r in rs)
        print(f"  validator errors: jerk-limited {errors}, TOPP-RA {topp_errors}")
        print(
            f"  records per axis per second: jerk-limited {np.mean([r.records for r in rs]):.1f}, "
            f"TOPP-RA {np.mean([r.topp_records for r in rs]):.1f}"
        )
        sj = np.concatenate([r.segment_jerk for r in rs])
        tj = np.concatenate([r.topp_segment_jerk for r in rs])
        print(
            "  drive's jerk per segment / limit: jerk-limited p50 {:.3f}, p99 {:.3f}, max {:.3f}; "
            "TOPP-RA p50 {:.3f}, p99 {:.3f}, max {:.3f}".format(
                *(np.percentile(sj, q) for q in (50, 99)), sj.max(), *(np.percentile(tj, q) for q in (50, 99)), tj.max()
            )
        )
        wj = np.array([r.window_jerk for r in rs])
        twj = np.array([r.topp_window_jerk for r in rs])
        print(
            f"  drive's 10-ms-window jerk / limit, max over every axis and path: jerk-limited {wj.max():.4f} "
            f"(p50 of the paths' worst axis {np.median(wj):.3f}, paths over 1.2: {int(np.sum(wj > 1.2))}); "
            f"TOPP-RA's programs max {twj.max():.2f}, p50 {np.median(twj):.2f}"
        )
    return cp, paths


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", default="arm6,gantry3", help="cells (configs/cells/NAME.yaml), default arm6,gantry3")
    ap.add_argument("--paths", type=int, default=100, help="random paths per cell (default 100)")
    ap.add_argument("--waypoints", type=int, default=8)
    ap.add_argument("--factors", default="10,4", help="max_jerk = F x amax per second, for each F (default 10,4)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--plot", metavar="FILE", help="write one path's acceleration and jerk (PNG)")
    args = ap.parse_args()
    factors = [float(f) for f in args.factors.split(",")]

    for name in args.cells.split(","):
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        cp, paths = run_cell(cell, args, factors)
        if args.plot and name == "arm6":
            plot(cp, paths[0][0], factors[0], Path(args.plot))
    print(
        f"command: python bench/jerk.py --cells {args.cells} --paths {args.paths} --waypoints {args.waypoints} "
        f"--factors {args.factors} --seed {args.seed}" + (f" --plot {args.plot}" if args.plot else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
