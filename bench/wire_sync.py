"""SYNC on the wall clock with a cell's simulated drives in a process of their own (axes.sim.process).

The master (CellBus + AxisGroup, SYNC on the wall clock) in this process, the cell's drives and
the simulated wire in a child, as ``pvtflow execute --real-time`` runs them; ``--drives here``
puts them in this process instead (the unit-test rigs' way), for comparison. Each run moves
every axis rest to rest (a quintic of ``--seconds``, toward the middle of its range, one record
per drive period) to its end. The SYNC intervals are the wire's, from the medium's own accounting
(each SYNC's start on the wire, ``Medium.stats().sync_intervals``), not a thread's: no monitor node
in the master's process, whose reader and listener threads would take the master's GIL at every frame.

Figures per run: the motion's result; SYNC interval p50 / p99 / max in periods; bursts
(intervals under half a period); the late SYNCs the medium counted (started more than 5 % of a
period after the previous one's start + period); the master's skipped periods.

    python3 bench/wire_sync.py [--cell gantry3-ip-linear] [--seconds 3] [--runs 3] [--drives process|here]
                               [--period-ms MS]

``--period-ms``: the cell at another SYNC period (a copy of its file, as ``bench/stall.py`` makes).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the tests' shared helpers (axes_programs, axes_rig)
sys.path.insert(0, str(ROOT / "tests" / "axes"))

from axes_programs import axis_program, safe_distance  # noqa: E402
from test_stall import at_period  # noqa: E402  (the stall test's copy of a cell at another period)

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.drive.program import PvtProgram  # noqa: E402
from pvtflow.axes.master.bus.cell_bus import CellBus  # noqa: E402
from pvtflow.axes.master.group.axis_group import AxisGroup  # noqa: E402
from pvtflow.axes.sim.process import DrivesProcess, LocalDrives  # noqa: E402
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config  # noqa: E402


def toward_middle(cell: CellConfig, here: list[int | None], duration_ms: int) -> PvtProgram:
    axes = []
    for axis, start in zip(cell.ordered_axes(), here, strict=True):
        start = int(start or 0)
        middle = (axis.limits.min_position_qc + axis.limits.max_position_qc) / 2
        sign = 1 if middle > start else -1
        axes.append(axis_program(axis, start, sign * safe_distance(axis, duration_ms), duration_ms))
    return PvtProgram(cell.name, tuple(axes))


def run(cell: CellConfig, seconds: float, where: str) -> dict[str, object]:
    drives = DrivesProcess(cell, "wall").start() if where == "process" else LocalDrives(cell, "wall").start()
    bus = CellBus(drives.bus, clock=Clock.WALL).open()
    group = AxisGroup(bus, cell.ordered_axes())
    try:
        group.refresh()
        prog = toward_middle(cell, [link.position for link in group.links], int(seconds * 1000))
        medium = bus.network.bus.medium
        before = medium.stats()
        result = group.run(prog, timeout_s=seconds + 30)
        after = medium.stats()
        late = len(after.late_syncs) - len(before.late_syncs)
        skipped = bus.sync.skipped
        # the intervals that end in this motion's SYNCs (the first: from the start's check SYNC)
        motion = after.sync_intervals[len(before.sync_intervals) :]
    finally:
        group.close()
        bus.close()
        drives.stop()
    period = cell.bus.sync_period_ms / 1000.0
    intervals = np.array(motion) / period if motion else np.array([np.nan])
    return {
        "result": result.result.name,
        "message": result.message,
        "syncs": len(motion) + 1 if motion else 0,
        "p50": float(np.percentile(intervals, 50)),
        "p99": float(np.percentile(intervals, 99)),
        "max": float(np.max(intervals)),
        "bursts": int(np.sum(intervals < 0.5)),
        "late": late,
        "skipped": skipped,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cell", default="gantry3-ip-linear")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--drives", choices=("process", "here"), default="process")
    parser.add_argument("--period-ms", type=float, default=None, help="the cell's SYNC period (a copy of its file)")
    args = parser.parse_args()
    cell_file = CONFIG_DIR / "cells" / f"{args.cell}.yaml"
    with tempfile.TemporaryDirectory() as directory:
        if args.period_ms is not None:
            cell_file = at_period(cell_file, args.period_ms, Path(directory))
        cell = load_cell_config(cell_file)
    print(
        f"python3 bench/wire_sync.py --cell {args.cell} --seconds {args.seconds:g} --runs {args.runs} "
        f"--drives {args.drives}"
        + (f" --period-ms {args.period_ms:g}" if args.period_ms is not None else "")
        + f"   ({cell.bus.sync_period_ms:g} ms SYNC)"
    )
    head = ("run", "result", "SYNCs", "p50", "p99", "max", "bursts", "late", "skipped")
    print("{:>3} {:10} {:>6} {:>6} {:>6} {:>6} {:>6} {:>5} {:>7}".format(*head))
    for i in range(args.runs):
        r = run(cell, args.seconds, args.drives)
        print(
            f"{i + 1:3d} {r['result']:10} {r['syncs']:6d} {r['p50']:6.3f} {r['p99']:6.3f} {r['max']:6.2f} "
            f"{r['bursts']:6d} {r['late']:5d} {r['skipped']!s:>7}"
            + ("" if r["result"] == "FINISHED" else f"  {r['message']}")
        )
        time.sleep(0.5)


if __name__ == "__main__":
    main()
