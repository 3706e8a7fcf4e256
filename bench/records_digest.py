"""A digest of the records pvtflow places on bench-drawn paths: a refactoring must leave it unchanged.

Plans 40 arm6 and 15 gantry3 paths of 8 waypoints (80 % of every joint range, seed 1, the benches'
drawing) with the cells' own settings and hashes every axis's records (int64). Run it on two
commits: the same digest means the same programs, bit for bit. It finds the cell planner where
that commit keeps it (service/cell_planner.py, or service/plan_cmd.py before it moved).

Run:  python bench/records_digest.py
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from service.config import CONFIG_DIR, load_cell_config  # noqa: E402

CELLS = (("arm6", 40), ("gantry3", 15))


def main() -> int:
    home = "service.cell_planner" if (ROOT / "service" / "cell_planner.py").exists() else "service.plan_cmd"
    plan_cell_program = importlib.import_module(home).plan_cell_program
    # since the plan input became an object (planner.plan.PlanInput) it is passed as one
    takes_input = "inp" in inspect.signature(plan_cell_program).parameters
    if takes_input:
        from planner.plan import PlanInput
    digest, programs = hashlib.sha256(), 0
    for name, count in CELLS:
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        lim = cell.joint_limits()
        rng = np.random.default_rng(1)
        for _ in range(count):
            waypoints = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))
            result = plan_cell_program(cell, PlanInput(waypoints) if takes_input else waypoints)
            if not result.ok or result.program is None:
                digest.update(b"refused")
                continue
            for axis in result.program.axes:
                digest.update(np.ascontiguousarray(axis.records, dtype=np.int64).tobytes())
                programs += 1
    print(f"{programs} axis programs, records sha256 {digest.hexdigest()}")
    print("command: python bench/records_digest.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
