"""Quality of the PVT programs pvtflow emits, over random paths on the shipped robots.

For every path: plan (TOPP-RA, default grid, flattened within the cell planner's speed band),
place the knots, validate the program on the drives' own reconstruction, and compare with a
3000-gridpoint TOPP-RA reference of the same path and limits (not flattened: the time-optimal
motion, so the duration ratio includes what the speed band costs). Prints, over all paths:

- limit violations after reconstruction of the quantized records (validator errors), and the worst
  |v|/0x607F and |a|/0x60C5 (exact, closed form per segment);
- the worst deviation from the plan in counts (at the drive's 1 kHz samples);
- the program duration over the reference duration (and the planner's own share of it);
- records per axis per second, and the CAN bus load that implies for 8 axes at 1 Mbit/s;
- the latency of plan (trajectory + knots + validated program) for 6 axes and 8 waypoints, with
  its breakdown: trajectory, knots + program + validation, and inside that knot placement and
  validation (p50, p99);
- how many drawn waypoint sets the planner refused (every one is planned: none is redrawn), and
  against the path before issue 13 (the not-a-knot spline, bench/old_spline.py): on the sets it
  accepted, the new trajectory's duration and the path's length over the spline's; on the sets it
  refused (it left the position limits), the same against the spline timed as if it had not;
- the same paths planned with velocity_scale 0.5: the worst |v| / (0.5 x 0x607F) of the drives'
  reconstruction over every program (the validator's exact check).

Run:  python bench/pvt_quality.py [--paths 200] [--gantry-paths 50] [--waypoints 8] [--seed 1]
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from old_spline import arc_length, spline_path

from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import parameterize
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlanner, plan_cell_program, planner_for_cell
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config


# CAN 2.0A data frame: 47 bits of overhead + 8 per data byte, plus at most one stuff bit per 4 of
# the 34 + 8n stuffable bits (worst case); the typical case is about half of that stuffing.
def frame_bits(data_bytes: int, worst: bool = True) -> float:
    stuffable = 34 + 8 * data_bytes
    stuff = math.floor((stuffable - 1) / 4) if worst else stuffable / 10
    return 47 + 8 * data_bytes + stuff


@dataclass
class PathResult:
    cell: str
    violations: int
    v_ratio: float
    a_ratio: float
    deviation_qc: float
    duration_ratio: float  # program motion time / reference
    planner_ratio: float  # planned trajectory / reference (the planner's share)
    time_scale: float
    records_per_axis_s: float
    t_plan: float  # s: trajectory only
    t_total: float  # s: trajectory + knots + validated program
    t_knots: float = math.nan  # s: knot placement (inside build_program)
    t_validation: float = math.nan  # s: the validation of the program (inside build_program)
    spline_accepted: bool = True  # the path before issue 13 (the not-a-knot spline) stayed inside the limits
    spline_duration_ratio: float = math.nan  # planned duration / the spline's (timed as if it were allowed)
    spline_length_ratio: float = math.nan  # path length in joint space / the spline's
    half_speed_v_ratio: float = math.nan  # velocity_scale 0.5: worst |v| / (0.5 x 0x607F), reconstruction
    half_speed_a_ratio: float = math.nan  # ... and |a| / 0x60C5 (acceleration_scale 1)


def random_waypoints(cell: CellConfig, rng: np.random.Generator, n: int) -> np.ndarray:
    lim = cell.joint_limits()
    return lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((n, lim.dof)))


def independent_deviation(cell: CellConfig, result) -> float:
    """|reconstruction - plan| at every drive ms, recomputed here from the program and the trajectory."""
    traj = result.plan.trajectory
    scale = result.build.knots.time_scale
    n = math.ceil(traj.duration * 1000.0 * scale - 1e-6)
    t_ms = np.arange(n + 1.0)
    q = traj.position(t_ms / (1000.0 * scale))
    worst = 0.0
    for i, (cfg, ap) in enumerate(zip(cell.ordered_axes(), result.program.axes, strict=True)):
        recon = ap.reconstruction()
        shift = recon.start[0] + recon.duration[0]
        worst = max(worst, float(np.abs(recon.position(t_ms + shift) - cfg.scaling.position_to_qc(q[:, i])).max()))
    return worst


def against_spline(planner: CellPlanner, wp: np.ndarray, result) -> tuple[bool, float, float]:
    """(the old spline accepted these waypoints, duration / the spline's, path length / the spline's)."""
    spline, accepted = spline_path(wp, planner.limits)
    p = planner.planner
    old = parameterize(spline, planner.limits, p.constraints, p.gridpoints)
    traj = result.plan.trajectory
    return accepted, traj.duration / old.duration, arc_length(traj.path) / arc_length(spline)


def half_speed(planner: CellPlanner, wp: np.ndarray) -> tuple[float, float]:
    """velocity_scale 0.5: the worst |v| / (0.5 x 0x607F) and |a| / 0x60C5 of the drives' reconstruction."""
    result = planner.plan(PlanInput(wp, velocity_scale=0.5))
    if not result.ok:
        print(f"  velocity_scale 0.5 NOT PLANNED on {planner.cell.name}: {result.message}", file=sys.stderr)
        return math.inf, math.inf
    report = validate_program(result.program)
    return max(a.velocity_ratio or 0.0 for a in report.axes) / 0.5, max(
        a.acceleration_ratio or 0.0 for a in report.axes
    )


def run_path(cell: CellConfig, wp: np.ndarray, planner: CellPlanner) -> PathResult | None:
    result = plan_cell_program(cell, PlanInput(wp))
    if not result.ok:
        if result.code == "program_error":
            print(f"  PROGRAM ERROR on {cell.name}: {result.message}", file=sys.stderr)
            return PathResult(
                cell.name,
                1,
                math.nan,
                math.nan,
                math.nan,
                math.nan,
                math.nan,
                math.nan,
                math.nan,
                result.timing.get("plan", 0.0),
                math.nan,
            )
        print(f"  REFUSED on {cell.name}: {result.code}: {result.message}", file=sys.stderr)
        return None  # the planner refused the waypoints: not a program
    report = validate_program(result.program)
    reference = planner_for_cell(cell, 3000)
    reference.speed_band = 0.0  # the time-optimal profile itself, not flattened (planner.speed_band)
    ref = reference.plan(PlanInput(wp))
    knots = result.build.knots
    motion_s = knots.duration_ms / 1000.0
    ref_s = ref.trajectory.duration if ref.ok and ref.trajectory is not None else math.nan
    accepted, spline_duration, spline_length = against_spline(planner, wp, result)
    half_v, half_a = half_speed(planner, wp)
    return PathResult(
        cell=cell.name,
        violations=len(report.errors),
        v_ratio=max(a.velocity_ratio or 0.0 for a in report.axes),
        a_ratio=max(a.acceleration_ratio or 0.0 for a in report.axes),
        deviation_qc=independent_deviation(cell, result),
        duration_ratio=motion_s / ref_s,
        planner_ratio=result.plan.trajectory.duration / ref_s,
        time_scale=knots.time_scale,
        records_per_axis_s=float(np.mean([len(a.records) for a in result.program.axes])) / motion_s,
        t_plan=result.timing["plan"],
        t_total=result.timing["total"],
        t_knots=result.build.timing.get("knots", math.nan),
        t_validation=result.build.timing.get("validation", math.nan),
        spline_accepted=accepted,
        spline_duration_ratio=spline_duration,
        spline_length_ratio=spline_length,
        half_speed_v_ratio=half_v,
        half_speed_a_ratio=half_a,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=200, help="random paths on the 6-axis arm (default 200)")
    ap.add_argument("--gantry-paths", type=int, default=50, help="random paths on the 3-axis gantry (default 50)")
    ap.add_argument("--waypoints", type=int, default=8, help="waypoints per path (default 8)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()

    # the first plan of a process loads numba's compiled loops (on a new machine: compiles them);
    # a service does that at start (CellPlanner.warm_up), so it is not part of the latency here
    t0 = time.perf_counter()
    CellPlanner(load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")).warm_up()
    print(f"  warm-up (compiled loops loaded or compiled): {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    rng = np.random.default_rng(args.seed)
    results: list[PathResult] = []
    refused = 0
    for cell_file, n_paths in (("arm6.yaml", args.paths), ("gantry3.yaml", args.gantry_paths)):
        cell = load_cell_config(CONFIG_DIR / "cells" / cell_file)
        planner = CellPlanner(cell)
        for done in range(1, n_paths + 1):  # every drawn set is a result: none is redrawn
            r = run_path(cell, random_waypoints(cell, rng, args.waypoints), planner)
            if r is None:
                refused += 1
            else:
                results.append(r)
            if done % 25 == 0:
                print(f"  {cell.name}: {done}/{n_paths} paths", file=sys.stderr)

    ok = [r for r in results if not math.isnan(r.a_ratio)]
    arm = [r for r in ok if r.cell == "arm6"]
    rec = np.array([r.records_per_axis_s for r in ok])
    dur = np.array([r.duration_ratio for r in ok])
    planner = np.array([r.planner_ratio for r in ok])
    scale = np.array([r.time_scale for r in ok])
    t_total = np.array([r.t_total for r in arm]) * 1000
    t_plan = np.array([r.t_plan for r in arm]) * 1000
    t_knots = np.array([r.t_knots for r in arm]) * 1000
    t_valid = np.array([r.t_validation for r in arm]) * 1000

    rec_mean = float(rec.mean())
    per_record = frame_bits(8)  # the 0x20C1 record RPDO
    status = frame_bits(4)  # the buffer status + statusword TPDO the drive answers with
    load_records = 8 * rec_mean * per_record / 1e6
    load_with_status = 8 * rec_mean * (per_record + status) / 1e6
    sync_and_stamp = 1000 * (frame_bits(0) + frame_bits(4)) / 1e6  # SYNC + 0x1013 every 1 ms

    print(
        f"pvt_quality: {len(results)} paths ({len(arm)} arm6 6-axis, {len(results) - len(arm)} gantry3), "
        f"{args.waypoints} waypoints each, seed {args.seed}; {refused} of {args.paths + args.gantry_paths} drawn "
        "waypoint sets refused by the planner (none redrawn)"
    )
    print(
        f"  limit violations after reconstruction (validator errors): {sum(r.violations for r in results)} "
        f"on {sum(r.violations > 0 for r in results)} path(s); program errors: {len(results) - len(ok)}"
    )
    print(f"  worst |v|/0x607F {max(r.v_ratio for r in ok):.6f}, worst |a|/0x60C5 {max(r.a_ratio for r in ok):.6f}")
    print(f"  worst deviation from the plan: {max(r.deviation_qc for r in ok):.3f} qc (tolerance 1 qc)")
    print(
        f"  duration / 3000-gridpoint reference: mean {dur.mean():.4f}, p95 {np.percentile(dur, 95):.4f}, "
        f"max {dur.max():.4f}  (planner alone: mean {planner.mean():.4f}, max {planner.max():.4f}; "
        f"knots' slow-down: mean {scale.mean():.4f}, max {scale.max():.4f})"
    )
    per_cell = ", ".join(
        f"{c} {np.mean([r.records_per_axis_s for r in ok if r.cell == c]):.1f}"
        for c in dict.fromkeys(r.cell for r in ok)
    )
    print(
        f"  records per axis per second: mean {rec_mean:.1f} ({per_cell}), p95 {np.percentile(rec, 95):.1f}, "
        f"max {rec.max():.1f}  (a uniform 10 ms grid: 100)"
    )
    print(
        f"  CAN load, 8 axes at 1 Mbit/s (worst-case bit stuffing): records {100 * load_records:.1f}%, "
        f"records + buffer-status TPDOs {100 * load_with_status:.1f}%, plus SYNC + 0x1013 at 1 kHz "
        f"{100 * sync_and_stamp:.1f}%  (10 ms grid: records {100 * 8 * 100 * per_record / 1e6:.1f}%)"
    )

    def p50_p99(x: np.ndarray) -> str:
        return f"p50 {np.percentile(x, 50):.1f} ms, p99 {np.percentile(x, 99):.1f} ms"

    print(f"  plan latency, arm6 6 axes {args.waypoints} waypoints: total {p50_p99(t_total)}")
    print(f"    trajectory {p50_p99(t_plan)}; knots + program + validation {p50_p99(t_total - t_plan)}")
    print(f"    of which knot placement {p50_p99(t_knots)}, validation {p50_p99(t_valid)}")
    for cell_name in dict.fromkeys(r.cell for r in ok):
        mine = [r for r in ok if r.cell == cell_name]
        kept = [r for r in mine if r.spline_accepted]
        moved = [r for r in mine if not r.spline_accepted]
        print(
            f"  against the not-a-knot spline (the path before issue 13), {cell_name}: {len(kept)} of {len(mine)} "
            f"sets it accepted, {len(moved)} it refused"
        )
        for what, rs in (("accepted (same waypoints)", kept), ("refused (spline timed as if allowed)", moved)):
            if rs:
                d = np.array([r.spline_duration_ratio for r in rs])
                n = np.array([r.spline_length_ratio for r in rs])
                print(
                    f"    {what}: duration / spline's median {np.median(d):.4f}, worst {d.max():.4f} "
                    f"(min {d.min():.4f}); path length / spline's median {np.median(n):.4f}, "
                    f"min {n.min():.4f}, max {n.max():.4f}"
                )
    half_v = max(r.half_speed_v_ratio for r in ok)
    half_a = max(r.half_speed_a_ratio for r in ok)
    print(
        f"  velocity_scale 0.5 on every path: worst |v| / (0.5 x 0x607F) {half_v:.9f}, worst |a| / 0x60C5 "
        f"{half_a:.6f} (the drives' reconstruction of every program)"
    )
    print(
        f"command: python bench/pvt_quality.py --paths {args.paths} --gantry-paths {args.gantry_paths} "
        f"--waypoints {args.waypoints} --seed {args.seed}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
