"""Linear tool moves on arm6: latency, straightness in the drives' reconstruction, TCP speed, refusals.

Random pairs of joint positions inside 70 % of the ranges; the move starts at the first and goes on
a straight tool line to the pose of the second (``CellPlanner.plan_poses``: IK, TOPP-RA, knots,
validated program). Until ``--moves`` are planned, it prints:

- plan latency p50 / p99 (wall clock and CPU time of the planning thread), IK included, and the IK's
  own share;
- the tool's deviation from the commanded line in the drives' reconstruction of the records
  (axes: each axis's ``AxisProgram.reconstruction()``, the drive's own interpolation), sampled at
  1 kHz, joint positions -> Pinocchio FK -> ``ToolLine.deviation``: worst and p99 of the moves' worst;
- the worst tool speed (reconstructed joint velocities -> |v| of the tool frame) / max_tcp_speed;
- the duration over the duration of a joint move between the same two poses (``motion="joint"``);
- the attempts refused, by result (a straight line between two reachable poses can need a joint
  past its limit or cross a singularity).

Run:  python bench/cartesian.py [--moves 100] [--seed 14]
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the pvtflow command sets it (service/cli.py)

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.cartesian import LineTolerance, ToolLine, placement_pose
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def reconstructed(program: PvtProgram, joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and velocities (n, dof) at the drives' 1 kHz samples, from the records."""
    axes = [program.axis(name) for name in joint_names]
    cubics = [a.reconstruction() for a in axes]
    t = cubics[0].sample_times()
    for c in cubics[1:]:
        if len(c.sample_times()) > len(t):
            t = c.sample_times()
    pairs = list(zip(axes, cubics, strict=True))
    q = np.column_stack([a.scaling.qc_to_position(c.position(t)) for a, c in pairs])
    qd = np.column_stack([a.scaling.rpm_to_velocity(a.scaling.qc_per_ms_to_rpm(c.velocity(t))) for a, c in pairs])
    return q, qd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=100, help="planned moves to measure (default 100)")
    ap.add_argument("--seed", type=int, default=14)
    args = ap.parse_args()

    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    planner = CellPlanner(cell)
    planner.warm_up()
    assert planner.planner is not None and planner.planner.poses is not None
    ik = planner.planner.poses.ik
    model, frame = cell.model, cell.planning.tcp_frame
    assert frame is not None and cell.planning.max_tcp_speed is not None
    limits = planner.limits
    mid, half = 0.5 * (limits.lower + limits.upper), 0.5 * (limits.upper - limits.lower)
    rng = np.random.default_rng(args.seed)
    tol = LineTolerance()

    wall, cpu, ik_s, samples = [], [], [], []
    worst_p, worst_r, speed, ratio = [], [], [], []
    refused: collections.Counter[str] = collections.Counter()
    attempts = 0
    while len(wall) < args.moves and attempts < 50 * args.moves:
        attempts += 1
        qa = mid + 0.7 * half * rng.uniform(-1.0, 1.0, limits.dof)
        qb = mid + 0.7 * half * rng.uniform(-1.0, 1.0, limits.dof)
        pose = placement_pose(ik.fk(qb))
        t0, c0 = time.perf_counter(), time.thread_time()
        result = planner.plan(PlanInput(qa, [pose], "linear"))
        t1, c1 = time.perf_counter(), time.thread_time()
        if not result.ok or result.program is None or result.waypoints is None:
            refused[result.code] += 1
            continue
        wall.append(t1 - t0)
        cpu.append(c1 - c0)
        ik_s.append(result.timing["ik"])
        samples.append(len(result.waypoints))
        q, qd = reconstructed(result.program, cell.joint_names)
        line = ToolLine(ik.fk(qa), ik.fk(qb))
        dev = np.array([line.deviation(ik.fk(x), tol)[:2] for x in q])
        worst_p.append(dev[:, 0].max())
        worst_r.append(dev[:, 1].max())
        speed.append(model.frame_speeds(q, qd, frame).max() / cell.planning.max_tcp_speed)
        joint = planner.plan(PlanInput(qa, [pose], "joint"))
        if joint.program is not None:
            ratio.append(result.program.duration_ms / joint.program.duration_ms)

    ms = 1000.0
    print(f"arm6, {len(wall)} linear moves planned of {attempts} attempts (seed {args.seed})")
    print(
        f"plan latency (IK + TOPP-RA + knots + validation): wall p50 {np.percentile(wall, 50) * ms:.1f} ms, "
        f"p99 {np.percentile(wall, 99) * ms:.1f} ms; CPU p50 {np.percentile(cpu, 50) * ms:.1f} ms, "
        f"p99 {np.percentile(cpu, 99) * ms:.1f} ms; of which IK (wall) p50 {np.percentile(ik_s, 50) * ms:.1f} ms, "
        f"p99 {np.percentile(ik_s, 99) * ms:.1f} ms"
    )
    print(f"joint samples per move: p50 {np.percentile(samples, 50):.0f}, max {max(samples)}")
    print(
        f"deviation from the line in the drives' reconstruction at 1 kHz: position worst "
        f"{max(worst_p) * 1000:.4f} mm, p99 {np.percentile(worst_p, 99) * 1000:.4f} mm; orientation worst "
        f"{np.degrees(max(worst_r)):.4f} deg, p99 {np.degrees(np.percentile(worst_r, 99)):.4f} deg"
    )
    print(f"worst tool speed / max_tcp_speed: {max(speed):.4f} (p50 of the moves' worst {np.median(speed):.3f})")
    print(
        f"duration / joint move between the same poses: min {min(ratio):.3f}, median {np.median(ratio):.3f}, "
        f"max {max(ratio):.3f} ({len(ratio)} moves)"
    )
    print(f"refused: {sum(refused.values())} of {attempts}: " + ", ".join(f"{k} {v}" for k, v in refused.most_common()))
    print(f"command: python bench/cartesian.py --moves {args.moves} --seed {args.seed}")


if __name__ == "__main__":
    main()
