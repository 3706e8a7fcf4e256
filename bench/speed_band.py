"""Records against motion time: TOPP-RA's profile flattened within a speed band (planner.speed_band).

The paths of bench/pvt_quality.py (8 waypoints in 80 % of every range, seed 1; the first
``--paths`` arm6 and ``--gantry-paths`` gantry3 sets of its drawing), planned with each speed band
and placed as the cell planner does. Per band and cell: records per axis per second (mean over
paths, as pvt_quality counts them), the total motion time of the programs against band 0 (the
time-optimal profile as TOPP-RA gives it), the worst deviation from the plan and the validator's
errors. Then the full plan (``CellPlanner.plan``) with the default band against band 0 with the
switch knots from 2 % of 0x60C5 (the settings before issue 25 item 4), interleaved in one process,
this thread's CPU time and the wall time.

Run:  python bench/speed_band.py [--paths 200] [--gantry-paths 50] [--bands 0,0.01,0.025,0.05,0.075,0.1]
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the pvtflow command sets it (service/cli.py)

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import pvtflow.service.cell_planner as cell_planner
from pvtflow.planner.knots import KnotOptions
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

CELLS = (("arm6.yaml", 200), ("gantry3.yaml", 50))  # pvt_quality's drawing: its arm6 sets, then gantry3's


def waypoint_sets(n_arm: int, n_gantry: int, waypoints: int = 8, seed: int = 1) -> list[tuple[CellConfig, np.ndarray]]:
    """pvt_quality's waypoint sets (the same generator, drawn in its order), the first of each cell."""
    rng = np.random.default_rng(seed)
    out = []
    for (name, drawn), wanted in zip(CELLS, (n_arm, n_gantry), strict=True):
        cell = load_cell_config(CONFIG_DIR / "cells" / name)
        lim = cell.joint_limits()
        for k in range(drawn):
            w = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((waypoints, lim.dof)))
            if k < wanted:
                out.append((cell, w))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=200, help="arm6 paths (at most 200)")
    ap.add_argument("--gantry-paths", type=int, default=50, help="gantry3 paths (at most 50)")
    ap.add_argument("--bands", default="0,0.01,0.025,0.05,0.075,0.1")
    args = ap.parse_args()
    bands = [float(b) for b in args.bands.split(",")]
    sets = waypoint_sets(min(args.paths, 200), min(args.gantry_paths, 50))
    planners = {cell.name: cell_planner.CellPlanner(cell) for cell in dict((c.name, c) for c, _ in sets).values()}
    for p in planners.values():
        p.warm_up(jerk=False)
    motion0: dict[str, float] = {}
    head = f"speed_band: {args.paths} arm6 + {args.gantry_paths} gantry3 paths (pvt_quality's)"
    print(f"{head}, default band {DEFAULT_SPEED_BAND}")
    for band in bands:
        rows = []
        for name, cp in planners.items():
            assert cp.planner is not None
            cp.planner.speed_band = band
            rec, motion, dev, errors = [], 0.0, 0.0, 0
            for cell, w in sets:
                if cell.name != name:
                    continue
                r = cp.plan(PlanInput(w))
                if not r.ok:
                    print(f"  band {band} {name}: {r.code}: {r.message}", file=sys.stderr)
                    continue
                s = r.build.knots.duration_ms / 1000.0
                rec.append(np.mean([len(a.records) for a in r.program.axes]) / s)
                motion += s
                dev = max(dev, r.build.knots.deviation_qc)
                errors += len(r.build.report.errors)
            motion0.setdefault(name, motion)
            rows.append(
                f"{name} {np.mean(rec):5.2f} records/axis/s, motion {motion:8.2f} s "
                f"({100 * (motion / motion0[name] - 1):+.2f} %), deviation {dev:.3f} qc, {errors} errors"
            )
        print(f"  band {band:<6} " + "; ".join(rows))
    arm = planners.get("arm6")
    if arm is not None and arm.planner is not None:
        modes = {
            "band 0, switch knots from 2 %": (0.0, functools.partial(KnotOptions, switch_fraction=0.02)),
            f"band {DEFAULT_SPEED_BAND}, switch knots from 1 %": (DEFAULT_SPEED_BAND, KnotOptions),
        }
        cpu: dict[str, list[float]] = {m: [] for m in modes}
        wall: dict[str, list[float]] = {m: [] for m in modes}
        for _ in range(3):
            for cell, w in sets:
                if cell.name != "arm6":
                    continue
                for mode, (band, options) in modes.items():
                    arm.planner.speed_band = band
                    cell_planner.KnotOptions = options  # type: ignore[misc]
                    r = arm.plan(PlanInput(w))
                    cpu[mode].append(r.timing["cpu"] * 1000.0)
                    wall[mode].append(r.timing["total"] * 1000.0)
        cell_planner.KnotOptions = KnotOptions  # type: ignore[misc]
        for mode in modes:
            c, t = np.array(cpu[mode]), np.array(wall[mode])
            print(
                f"  full plan arm6 ({mode}), interleaved x3: CPU p50 {np.percentile(c, 50):.2f} ms, "
                f"p99 {np.percentile(c, 99):.2f} ms; wall p50 {np.percentile(t, 50):.2f} ms, "
                f"p99 {np.percentile(t, 99):.2f} ms"
            )
    options = f"--paths {args.paths} --gantry-paths {args.gantry_paths} --bands {args.bands}"
    print(f"command: python bench/speed_band.py {options}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
