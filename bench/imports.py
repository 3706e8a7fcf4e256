"""What the axes layer and ``pvtflow validate`` load, and how long the import takes (issue 18).

Each case runs in a fresh interpreter (5 runs, median wall time of the import or command alone):

    python3 bench/imports.py [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WATCHED = ("pinocchio", "toppra", "casadi", "scipy", "numba", "yaml", "zenoh", "matplotlib", "canopen", "can")
PROGRAM = {
    "format": "pvtflow.pvt-program",
    "version": 1,
    "cell": "bench",
    "axes": [
        {
            "name": "joint_1",
            "node_id": 1,
            "profile": "epos2_pvt",
            "scaling": {
                "qc_per_motor_rev": 2000,
                "motor_rev_per_joint_unit": 25.464790894703256,
                "velocity_unit_rpm": 1,
            },
            "limits": {
                "max_profile_velocity_rpm": 4000,
                "max_acceleration_rpm_s": 30000,
                "min_position_qc": -100000,
                "max_position_qc": 100000,
            },
            "records": [[0, 0, 1], [100, 0, 50], [100, 0, 0]],
        }
    ],
}


def probe(code: str) -> tuple[float, list[str]]:
    script = (
        "import time, sys, io, contextlib\n"
        "t = time.perf_counter()\n"
        f"with contextlib.redirect_stdout(io.StringIO()):\n    {code}\n"
        "dt = time.perf_counter() - t\n"
        "import json\n"
        f"print(json.dumps([dt, sorted({{m.split('.')[0] for m in sys.modules}} & set({list(WATCHED)!r}))]))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    dt, loaded = json.loads(out.stdout.strip().splitlines()[-1])
    return dt, loaded


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        program = Path(tmp) / "p.json"
        program.write_text(json.dumps(PROGRAM))
        cases = {
            "import axes.master.group.axis_group": "import pvtflow.axes.master.group.axis_group",
            "import axes (group, bus, sim cell)": "import pvtflow.axes.master.group.axis_group, "
            "pvtflow.axes.master.bus.cell_bus, pvtflow.axes.sim.cell",
            "pvtflow validate PROGRAM": f"from pvtflow.service.cli import main; main(['validate', {str(program)!r}])",
        }
        print(f"python3 bench/imports.py --runs {args.runs}")
        print("| case | median s | loads |")
        print("|---|---|---|")
        for name, code in cases.items():
            runs = [probe(code) for _ in range(args.runs)]
            print(f"| {name} | {statistics.median(r[0] for r in runs):.3f} | {', '.join(runs[0][1])} |")


if __name__ == "__main__":
    main()
