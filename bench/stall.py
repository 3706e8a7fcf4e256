"""A 50 ms stall of the master's process mid-motion: every axis halted, and said why (``sync_gap``).

The drives run in their own process (``pvtflow sim --wall-clock`` on ``--cell``, serving the
simulated wire on loopback), the master in this one, SYNC on the wall clock. ``--at-ms`` into a
motion another process stops the master (SIGSTOP) and continues it (SIGCONT) ``--stall-ms`` later:
the whole interpreter, every thread, as a preempted or swapped-out master is. The drives keep
their own clocks meanwhile (a fixed-period drive holds its last setpoint, an EPOS2 runs its
records). Figures per run (times on the host's monotonic clock, from the SIGCONT): the gap the
master reported, to the quick stop requests, to every drive's SDO confirmation, NMT stop needed,
every drive out of OPERATION ENABLED and at rest afterwards (read by SDO), the outcome. Target: every
axis halted within the drives' tolerance (the fixed-period drives ride out 2 periods), reported.

    python3 bench/stall.py [--runs 5] [--cell gantry3-ip-linear] [--axes 2] [--period-ms 4] [--at-ms 500]
                           [--stall-ms 50] [--max-gap-periods N] [--tx-retry-ms MS]

``--period-ms``: the cell runs at this SYNC period (a copy of its file): 4 ms by default, half the
frames of the shipped 2 ms, which the simulated wire's loopback server (Python) does not always
carry on a loaded host (the master's transmit queue then fills: ``tx_failed`` before the stall);
``--axes``: the first N axes move (2 by default, for the same reason). ``--max-gap-periods`` and
``--tx-retry-ms`` set the master's gap limit and retry bound (a loaded host holds the master for tens
of ms by itself: runs that end before the stall are listed apart, with their outcome).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the tests' shared helpers (axes_programs, axes_rig)
sys.path.insert(0, str(ROOT / "tests" / "axes"))

from test_stall import at_period, serve, stall_this_process, toward_the_middle  # noqa: E402  (the test's harness)

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.master.bus.cell_bus import CellBus  # noqa: E402
from pvtflow.axes.master.group.axis_group import AxisGroup  # noqa: E402
from pvtflow.axes.master.group.outcome import Event  # noqa: E402
from pvtflow.service.config import CONFIG_DIR  # noqa: E402


def one_run(
    cell_file: Path, at_ms: float, stall_ms: float, axes: int, max_gap: float | None, retry_ms: float | None
) -> dict[str, object]:
    served = serve(cell_file)
    cell, drives = next(served)
    bus_config = dataclasses.replace(cell.bus, max_sync_gap_periods=max_gap)
    if retry_ms is not None:
        bus_config = dataclasses.replace(bus_config, tx_retry_ms=retry_ms)
    cell = dataclasses.replace(cell, bus=bus_config)
    bus = CellBus(cell.bus, clock=Clock.WALL).open()
    group = AxisGroup(bus, cell.ordered_axes()[:axes])
    events: list[Event] = []
    group.on_event = events.append
    try:
        group.refresh()
        here = [lk.position for lk in group.links]
        prog = toward_the_middle([lk.config for lk in group.links], here, int(at_ms) + 3000)
        if group.start(prog) is not None:
            raise RuntimeError(f"not started: {group.last_result}")
        while group.running and (group.elapsed_syncs() or 0) * cell.bus.sync_period_ms < at_ms:
            time.sleep(0.002)
        if not group.running:  # ended before the stall (the host's own stalls): counted apart, with its outcome
            early = group.wait(1.0)
            return {"outcome": f"ended before the stall: {early.result.value}: {early.message[:100]}"}
        _, resumed = stall_this_process(stall_ms / 1000.0)
        result = group.wait(30.0)
        stop = group.last_quick_stop
        gaps = [
            str(getattr(e, "message", "")) for e in events if getattr(e, "kind", None) and e.kind.value == "sync_gap"
        ]
        # "no setpoint for" where the wire sends SYNC itself (axes.master.bus.sync_follower)
        what = "no setpoint for " if bus.sync.native else "no SYNC for "
        gap = float(gaps[0].split(what, 1)[1].split(" ms", 1)[0]) if gaps and what in gaps[0] else float("nan")
        if stop is not None:
            stop.done.wait(5.0)
        time.sleep(0.3)
        before = [lk.read(0x6064, 0, "i") for lk in group.links]
        time.sleep(0.1)
        still = before == [lk.read(0x6064, 0, "i") for lk in group.links]
        halted = all(lk.read_statusword() & 0x6F != 0x27 for lk in group.links)
        confirmed = max(stop.confirmed.values()) if stop is not None and stop.confirmed and not stop.missing else None
        return {
            "outcome": result.result.value,
            "gap_ms": gap,
            "requests_ms": (stop.started - resumed) * 1000.0 if stop is not None else float("nan"),
            "confirmed_ms": (confirmed - resumed) * 1000.0 if confirmed is not None else float("nan"),
            "nmt": len(stop.nmt_stopped) if stop is not None else 0,
            "halted": halted and still,
            "axes": len(group.links),
        }
    finally:
        group.close()
        bus.close()
        served.close()
        assert drives.poll() is not None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--cell", default="gantry3-ip-linear")
    parser.add_argument("--at-ms", type=float, default=500.0)
    parser.add_argument("--stall-ms", type=float, default=50.0)
    parser.add_argument("--axes", type=int, default=2, help="the first N axes of the cell move")
    parser.add_argument("--max-gap-periods", type=float, default=None, help="bus.max_sync_gap_periods (the profiles')")
    parser.add_argument("--tx-retry-ms", type=float, default=None, help="bus.tx_retry_ms (the cell's)")
    parser.add_argument("--period-ms", type=float, default=4.0, help="the cell's SYNC period (a copy of its file)")
    args = parser.parse_args()
    directory = Path(tempfile.mkdtemp(prefix="pvtflow-stall-"))
    cell_file = at_period(CONFIG_DIR / "cells" / f"{args.cell}.yaml", args.period_ms, directory)
    print(
        f"cell {args.cell} at {args.period_ms:g} ms SYNC, master stopped {args.stall_ms:g} ms at {args.at_ms:g} ms "
        f"into the motion, {args.runs} runs"
    )
    print(
        "| run | outcome | gap reported (ms) | SIGCONT to requests (ms) | to every axis confirmed (ms) | NMT stop "
        "| every axis halted, at rest |"
    )
    print("|---|---|---|---|---|---|---|")
    rows = []
    for k in range(args.runs):
        r = one_run(cell_file, args.at_ms, args.stall_ms, args.axes, args.max_gap_periods, args.tx_retry_ms)
        if "gap_ms" not in r:
            print(f"| {k + 1} | {r['outcome']} | | | | | |", flush=True)
            continue
        rows.append(r)
        print(
            f"| {k + 1} | {r['outcome']} | {r['gap_ms']:.1f} | {r['requests_ms']:.2f} | {r['confirmed_ms']:.2f} | "
            f"{r['nmt']} of {r['axes']} | {'yes' if r['halted'] else 'NO'} |",
            flush=True,
        )
    conf = np.array([float(r["confirmed_ms"]) for r in rows])  # type: ignore[arg-type]
    print(
        f"\nconfirmed after SIGCONT: p50 {np.nanmedian(conf):.2f} ms, max {np.nanmax(conf):.2f} ms; "
        f"halted in {sum(bool(r['halted']) for r in rows)} of {len(rows)} runs stalled"
    )


if __name__ == "__main__":
    main()
