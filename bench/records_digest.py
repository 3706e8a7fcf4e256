"""A digest of the records pvtflow places on bench-drawn paths: a refactoring must leave it unchanged.

Plans 40 arm6 and 15 gantry3 paths of 8 waypoints (80 % of every joint range, seed 1, the benches'
drawing) with the cells' own settings and hashes every axis's records (int64). Run it on two
commits: the same digest means the same programs, bit for bit. It finds the cell planner where
that commit keeps it (service/cell_planner.py, or service/plan_cmd.py before it moved).

``--jerk``: the same for the first 10 arm6 and 5 gantry3 of those paths timed jerk-limited
(max_jerk 10 x each joint's acceleration limit per second), the knots holding the drive's window
jerk (``planner.knots.window_jerk``); a second digest. The digests of this tree are ``EXPECTED``:
the script says whether they match.

Run:  python bench/records_digest.py [--jerk]
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

from pvtflow.service.config import CONFIG_DIR, load_cell_config  # noqa: E402

CELLS = (("arm6", 40), ("gantry3", 15))
JERK_CELLS = (("arm6", 10), ("gantry3", 5))
EXPECTED = {
    "topp": "a663223b694cf38c1dae61fbafe20b7324b4d6cb6af37ba4b3c12bb90cb41148",
    "jerk": "35ae3652f43e2a9d3b449262fa082b9dd9fb256b7c83cf89b2fc747d35ff1315",
}


def digest_of(plan_cell_program, takes_input: bool, cells: tuple[tuple[str, int], ...], jerk: bool) -> tuple[str, int]:
    digest, programs = hashlib.sha256(), 0
    if takes_input:
        from pvtflow.planner.plan import PlanInput
    for name, count in cells:
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        lim = cell.joint_limits()
        rng = np.random.default_rng(1)
        for _ in range(count):
            waypoints = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))
            if jerk:
                inp = PlanInput(waypoints, max_jerk=10.0 * lim.acceleration)
            else:
                inp = PlanInput(waypoints) if takes_input else waypoints
            result = plan_cell_program(cell, inp)
            if not result.ok or result.program is None:
                digest.update(b"refused")
                continue
            for axis in result.program.axes:
                digest.update(np.ascontiguousarray(axis.records, dtype=np.int64).tobytes())
                programs += 1
    return digest.hexdigest(), programs


def main() -> int:
    home = (
        "pvtflow.service.cell_planner"
        if (ROOT / "service" / "cell_planner.py").exists()
        else "pvtflow.service.plan_cmd"
    )
    plan_cell_program = importlib.import_module(home).plan_cell_program
    # since the plan input became an object (planner.plan.PlanInput) it is passed as one
    takes_input = "inp" in inspect.signature(plan_cell_program).parameters
    parts = [("topp", CELLS, False)] + ([("jerk", JERK_CELLS, True)] if "--jerk" in sys.argv[1:] else [])
    for part, cells, jerk in parts:
        digest, programs = digest_of(plan_cell_program, takes_input, cells, jerk)
        same = "matches" if digest == EXPECTED[part] else "DIFFERS from"
        print(f"{part}: {programs} axis programs, records sha256 {digest} ({same} this tree's {EXPECTED[part][:12]})")
    print("command: python bench/records_digest.py" + (" --jerk" if len(parts) > 1 else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
