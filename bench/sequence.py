"""Motion sequences on arm6 (issue 38): a pick-and-place cycle blended vs stop-and-go.

    PYTHONPATH=. python3 bench/sequence.py [--runs 30]

The cycle is configs/sequences/arm6-pick-and-place.yaml's six items (PTP above the pick, LIN
0.12 m down, LIN up, PTP above the place, LIN down, LIN up), run twice in one sequence; its cycle
time is the second cycle's (item 6's start to item 11's end). Blends of 0, 20 and 50 mm on the
items the example blends (the PTPs and the LIN ups; the LIN downs stop: the gripper acts there),
against the same six items planned one by one as separate rest-to-rest motions (the sum of their
programs' durations, without the dead time between motions). Both on the programs' time line: the
drives' time, with the knots' slow-down and the start dwell (a sequence with exact stops is planned
as rest-to-rest chunks joined into one program: service/sequence_chunks.py). On each blended
program, on the drives' reconstruction every ms: the worst fraction of 0x607F, 0x60C5 and the TCP
speed limit and of each joint's effort limit (RNEA, the URDF's effort: arm6 plans with torque limits) inside
the blend spheres, and the tool's worst distance to the items' paths outside them.
Then the plan latency (CellPlanner.plan: IK, TOPP-RA, knots, validation) of a 10-item sequence, p50 / p99.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
import yaml

from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
EXAMPLE = yaml.safe_load((CONFIG_DIR / "sequences" / "arm6-pick-and-place.yaml").read_text())


def cycle(r: float, repeats: int = 2) -> list[dict]:
    items = []
    for _ in range(repeats):
        for item in copy.deepcopy(EXAMPLE["sequence"]):
            if item.get("blend_radius", 0.0) > 0.0:
                item["blend_radius"] = r
            items.append(item)
    return items


def reconstructed(program) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Joint positions, velocities (/s), accelerations (/s^2) every ms of the drives' reconstruction."""
    t = np.arange(0, program.duration_ms + 1, dtype=float)
    q, v, a = [], [], []
    for axis in program.axes:
        c = axis.reconstruction()
        k = axis.scaling.qc_per_joint_unit
        q.append(axis.scaling.qc_to_position(c.position(t)))
        v.append(c.velocity(t) * 1e3 / k)
        a.append(c.acceleration(t) * 1e6 / k)
    return np.column_stack(q), np.column_stack(v), np.column_stack(a)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=30)
    args = ap.parse_args()
    planner = CellPlanner(ARM)
    planner.warm_up()
    solver = planner.planner.sequences
    limits = ARM.joint_limits()
    model = ARM.model
    effort = np.array([j.effort for j in model.joints])
    start = np.array(EXAMPLE["start"], dtype=float)

    # stop and go: each item of the second cycle from the previous item's goal, alone
    items0 = cycle(0.0)
    solved0 = solver.solve(start, items0)
    goals = [solved0.tool.path.points[k] for k in solved0.item_end]
    separate = 0.0
    for i in range(6, 12):
        out = planner.plan(PlanInput(goals[i - 1], sequence=[items0[i]]))
        assert out.ok, out.message
        separate += out.program.duration_ms / 1000.0  # what the drives run (knots' slow-down, start dwell)
    print(f"stop-and-go, 6 separate programs: {separate:.3f} s per cycle (without the dead time between them)")
    print(
        "| blend | cycle time | vs stop-and-go | worst inside blends: v/0x607F, a/0x60C5, TCP/limit, torque/effort | "
        "tool to path outside spheres |"
    )
    for r in (0.0, 0.02, 0.05):
        items = cycle(r)
        result = planner.plan(PlanInput(start, sequence=items))
        assert result.ok, result.message
        spans = result.program.metadata["items"]
        t_cycle = spans[11]["end_s"] - spans[6]["start_s"]
        solved = solver.solve(start, items)
        q, v, a = reconstructed(result.program)
        dp, _, outside = solver.deviations(solved, q)
        tool = np.array([solver.ik.fk(x).translation for x in q])
        tcp = np.r_[0.0, np.linalg.norm(np.diff(tool, axis=0), axis=1) / 1e-3]
        inside = ~outside
        if r > 0.0:
            fv = float(np.max(np.abs(v[inside]) / limits.velocity))
            fa = float(np.max(np.abs(a[inside]) / limits.acceleration))
            ft = float(np.max(tcp[inside]) / ARM.planning.max_tcp_speed)
            tau = model.inverse_dynamics_rows(q[inside], v[inside], a[inside])
            fe = float(np.max(np.abs(tau) / effort))
            worst = f"{fv:.3f}, {fa:.3f}, {ft:.3f}, {fe:.3f}"
        else:
            worst = "(no blends)"
        print(
            f"| {1000 * r:.0f} mm | {t_cycle:.3f} s | {100 * (t_cycle / separate - 1):+.1f} % | {worst} | "
            f"{1000 * float(dp[outside].max()):.4f} mm |"
        )

    ten = cycle(0.02)[:10]
    times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        result = planner.plan(PlanInput(start, sequence=ten))
        times.append(time.perf_counter() - t0)
        assert result.ok
    ms = 1000 * np.array(times)
    print(
        f"10-item sequence (blends 20 mm), CellPlanner.plan over {args.runs} runs: "
        f"p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms"
    )


if __name__ == "__main__":
    main()
