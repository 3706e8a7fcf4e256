"""Parker SLVDN mode 202 submodes: moves planned, and the program's duration against submode 0 and
against the planned trajectory (issue 12).

Random single-target moves of the gantry3 and arm6 robots (every axis a Parker drive, one submode
and one SYNC period at a time; start at rest inside the ranges, targets in 10-90 % of each range),
planned as the service plans them (``CellPlanner``: TOPP-RA, then the integer setpoints):

    python3 bench/parker_submodes.py [--moves 20] [--periods 1,2,4] [--seed 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics

import numpy as np

from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

SUBMODES = (0, -1, -2)


def variant(cell: CellConfig, submode: int, period_ms: int) -> CellConfig:
    axes = tuple(
        dataclasses.replace(a, profile="parker_slvdn", period_ms=period_ms, interpolation_submode=submode)
        for a in cell.axes
    )
    return dataclasses.replace(cell, axes=axes, bus=dataclasses.replace(cell.bus, sync_period_ms=float(period_ms)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=20)
    ap.add_argument("--periods", default="1,2,4")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    periods = [int(p) for p in args.periods.split(",")]
    print(f"python3 bench/parker_submodes.py --moves {args.moves} --periods {args.periods} --seed {args.seed}")
    print("| robot | period ms | submode | planned | duration / submode 0 | duration / trajectory |")
    print("|---|---|---|---|---|---|")
    for robot in ("gantry3", "arm6"):
        base = load_cell_config(CONFIG_DIR / "cells" / f"{robot}.yaml")
        lim = base.joint_limits()
        lo, hi = np.asarray(lim.lower), np.asarray(lim.upper)
        rng = np.random.default_rng(args.seed)
        moves = [
            (lo + rng.uniform(0.2, 0.8, len(lo)) * (hi - lo), lo + rng.uniform(0.1, 0.9, len(lo)) * (hi - lo))
            for _ in range(args.moves)
        ]
        for period in periods:
            durations: dict[int, list[float | None]] = {}
            trajectory: list[float | None] = []
            for submode in SUBMODES:
                planner = CellPlanner(variant(base, submode, period))
                durations[submode] = []
                for start, target in moves:
                    out = planner.plan(PlanInput(np.array([start, target])))
                    if submode == 0:
                        traj = out.plan.trajectory if out.plan is not None else None
                        trajectory.append(traj.duration * 1000.0 if traj is not None else None)
                    durations[submode].append(out.program.duration_ms if out.ok and out.program else None)
            for submode in SUBMODES:
                d = durations[submode]
                vs0 = [x / y for x, y in zip(d, durations[0], strict=True) if x and y]
                vst = [x / y for x, y in zip(d, trajectory, strict=True) if x and y]
                planned = sum(x is not None for x in d)
                r0 = f"{statistics.median(vs0):.3f}, {max(vs0):.3f}" if vs0 else "-"
                rt = f"{statistics.median(vst):.3f}, {max(vst):.3f}" if vst else "-"
                print(f"| {robot} | {period} | {submode} | {planned}/{len(d)} | {r0} | {rt} |", flush=True)


if __name__ == "__main__":
    main()
