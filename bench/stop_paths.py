"""The stop that does not need SYNC: a dead SYNC thread and a full transmit queue mid-motion.

A simulated cell (every axis of ``--cell`` on its simulated drive, in this process, on the
``virtual`` bus) runs a program with SYNC on the wall clock. ``--at-ms`` into the motion:

- ``dead SYNC thread``: the SYNC thread raises (a sender of ``SyncClock`` that fails);
- ``queue full``: the interface refuses every frame for ``--full-ms`` (the test double of the BUS
  of tests/axes_rig.py raises ``can.CanOperationError`` as socketcan does on ENOBUFS), longer
  than the master's retries (``tx_retry_ms``, 2 ms).

Figures per case over ``--runs``: time from the failure to the quick stop requests on the bus
(detection: for the queue the retries, for the thread nothing), to the last drive's SDO
confirmation of the quick stop (every axis; a run where a drive did not confirm within the
``quick_stop_confirm_ms`` bound, 10 ms, is counted apart: that drive was sent NMT stop), and how
many runs needed NMT stop. A full queue refuses the quick stop requests too, until it drains. Target: quick stop
confirmed on every axis within 10 ms of the failure.

    python3 bench/stop_paths.py [--runs 5] [--cell arm6] [--at-ms 300] [--full-ms 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from axes_programs import program  # noqa: E402  (the tests' programs: quintic moves inside the limits)
from axes_rig import FlakyBus, unique_channel  # noqa: E402  (the test double of the BUS)

from axes.bus import CellBus  # noqa: E402
from axes.group import AxisGroup  # noqa: E402
from axes.sim.cell import SimulatedCell  # noqa: E402
from service.config import CONFIG_DIR, load_cell_config  # noqa: E402


def one_run(cell_name: str, case: str, at_ms: float, full_ms: float) -> dict[str, float | int]:
    cell = load_cell_config(CONFIG_DIR / "cells" / f"{cell_name}.yaml")
    channel = unique_channel("stop")
    bus_config = dataclasses.replace(cell.bus, channel=channel, max_sync_gap_periods=1e6)
    cell = dataclasses.replace(cell, bus=bus_config)
    sim = SimulatedCell(cell, channel=channel, interface="virtual").start()
    bus = CellBus(dataclasses.replace(bus_config, interface="pvtflow_test_flaky"), lockstep=False).open()
    group = AxisGroup(bus, cell.ordered_axes())
    failed_at: list[float] = []
    at_sync = round(at_ms / bus_config.sync_period_ms)

    def inject(n: int) -> None:
        start = group._start_sync
        if start is None or n < start + at_sync or failed_at:
            return
        failed_at.append(time.monotonic())
        if case.startswith("dead"):
            raise RuntimeError("injected")
        FlakyBus.fail(channel, full_ms / 1000.0)

    try:
        bus.sync.add_sender(inject)
        prog = program(cell.ordered_axes(), 2000, fraction=0.3)
        if group.start(prog) is not None:
            raise RuntimeError(f"not started: {group.last_result}")
        result = group.wait(30.0)
        stop = group.last_quick_stop
        if stop is None or not failed_at:  # ended otherwise: counted apart, with its outcome
            return {
                "requests_ms": float("nan"),
                "confirmed_ms": float("nan"),
                "nmt": 0,
                "axes": 0,
                "other": f"{result.result.value}: {result.message[:90]}",
            }
        stop.done.wait(2.0)
        confirmed = max(stop.confirmed.values()) if not stop.missing else float("nan")
        return {
            "requests_ms": (stop.started - failed_at[0]) * 1000.0,
            "confirmed_ms": (confirmed - failed_at[0]) * 1000.0,
            "nmt": int(bool(stop.nmt_stopped)),
            "axes": len(stop.node_ids),
        }
    finally:
        FlakyBus.failing_until.pop(channel, None)
        group.close()
        bus.close()
        sim.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--cell", default="arm6")
    parser.add_argument("--at-ms", type=float, default=300.0)
    parser.add_argument("--full-ms", type=float, default=5.0)
    args = parser.parse_args()
    logging.disable(logging.ERROR)  # the injected failure's traceback, logged by the SYNC thread
    warnings.simplefilter("ignore", RuntimeWarning)  # a case where no run confirmed: nan
    print(f"cell {args.cell}, failure {args.at_ms:g} ms into the motion, {args.runs} runs per case")
    print(
        "| case | axes | to the requests (p50 / max ms) | to every axis confirmed (p50 / max ms) "
        "| NMT stop needed | runs that ended otherwise |"
    )
    print("|---|---|---|---|---|---|")
    for case in ("dead SYNC thread", f"queue full {args.full_ms:g} ms"):
        runs = [one_run(args.cell, case, args.at_ms, args.full_ms) for _ in range(args.runs)]
        req = np.array([r["requests_ms"] for r in runs])
        conf = np.array([r["confirmed_ms"] for r in runs])
        nmt = sum(int(r["nmt"]) for r in runs)
        others = [str(r["other"]) for r in runs if "other" in r]
        late = int(np.isnan(conf).sum()) - len(others)
        for other in others:
            print(f"<!-- {case}: no quick stop, the run ended {other} -->")
        print(
            f"| {case} | {max(int(r['axes']) for r in runs)} | {np.nanmedian(req):.2f} / {np.nanmax(req):.2f} | "
            f"{np.nanmedian(conf):.2f} / {np.nanmax(conf):.2f} (+ {late} not within the bound) | "
            f"{nmt} of {len(runs)} | {len(others)} |",
            flush=True,
        )
    threading.Event().wait(0.1)


if __name__ == "__main__":
    main()
