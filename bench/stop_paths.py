"""The stop that does not need SYNC: a dead SYNC thread and a full transmit queue mid-motion.

A simulated cell (every axis of ``--cell`` on its simulated drive, in this process, on the
``virtual`` bus) runs a program with SYNC on the wall clock. ``--at-ms`` into the motion:

- ``dead SYNC thread``: the SYNC thread raises (a sender of ``SyncClock`` that fails); the failure
  is the raise;
- ``queue full``: the interface refuses every frame (the test double of the BUS of
  tests/axes_rig.py raises ``can.CanOperationError`` as socketcan does on ENOBUFS) from 0.3 ms
  before a SYNC is due for ``--full-ms`` (default ``tx_retry_ms`` + 1 ms: longer than the master
  retries a frame, so that SYNC cannot go out; a SYNC sent so late that the window was over gets
  through, and the window is set again before the next). The failure is the master giving a
  frame up past its retries (``FaultKind.TX_FAILED`` reported), which is also given from the
  moment the queue became full. The queue still refuses frames for a while after it (the quick stop
  requests wait for it to drain, as on a real bus).

Figures per case over ``--runs``, from the failure: to the quick stop requests on the bus, to the
moment the last drive took the quick stop (drive side: its controlword 0x0002 acted on, QUICK STOP
ACTIVE; by the SDO request or, where that was not confirmed in time, by the NMT stop's 0x6007
reaction), to the last drive's SDO confirmation of the quick stop (master side; a run where a drive
did not confirm within the ``quick_stop_confirm_ms`` bound is counted apart: that drive was sent
NMT stop; 10 ms, 50 ms for drives in this interpreter, ``sharing_the_interpreter``, with the runs
confirmed within 10 ms counted), and how many runs needed NMT stop. Target: quick stop confirmed on every axis
within 10 ms of the failure.

``--drives process``: the drives run in a process of their own (``pvtflow sim --wall-clock``
serving the simulated wire on loopback, as a real master never shares its interpreter with its
drives) and the master opens that wire through a test double of the interface that refuses frames
like FlakyBus (``FlakyWire``); the cell is a copy of ``--cell`` at ``--period-ms`` with its first
``--axes`` axes moving (the loopback wire server carries a few thousand frames/s), and the
drive-side column is empty (their process is not instrumented).

    python3 bench/stop_paths.py [--runs 10] [--cell arm6] [--at-ms 300] [--full-ms MS]
    python3 bench/stop_paths.py --drives process [--cell gantry3-ip-linear] [--period-ms 8] [--axes 2]
    [--bus-threads-normal]: the master's bus threads left at normal priority, for comparison
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import can
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "axes"))  # test_stall: the drives in their own process

from axes_programs import program  # noqa: E402  (the tests' programs: quintic moves inside the limits)
from axes_rig import FlakyBus, unique_channel  # noqa: E402  (the test double of the BUS)
from test_stall import at_period, serve, toward_the_middle  # noqa: E402  (drives in their own process)

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.drive.cia402 import PowerState  # noqa: E402
from pvtflow.axes.master.bus.cell_bus import CellBus  # noqa: E402
from pvtflow.axes.master.bus.faults import BusFault, FaultKind  # noqa: E402
from pvtflow.axes.master.group.axis_group import AxisGroup  # noqa: E402
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter  # noqa: E402
from pvtflow.axes.sim.drive import SimulatedDrive  # noqa: E402
from pvtflow.axes.sim.wire import SimWireBus  # noqa: E402
from pvtflow.service.config import CONFIG_DIR, load_cell_config  # noqa: E402


class FlakyWire(SimWireBus):
    """The simulated wire's interface whose transmit path refuses frames as FlakyBus's does (ENOBUFS)."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if FlakyBus.failing(self.channel):
            raise can.CanOperationError("Failed to transmit: [Errno 105] No buffer space available")
        super().send(msg, timeout)


LEAD_S = 0.0003  # the queue becomes full this long before the SYNC is due


can.interfaces.BACKENDS["pvtflow_bench_flaky_wire"] = (__name__, "FlakyWire")
can.interfaces.VALID_INTERFACES = can.util.VALID_INTERFACES = frozenset(can.interfaces.BACKENDS)


def watch_quick_stop(drive: SimulatedDrive, acted: dict[int, float]) -> None:
    """Note when the drive first enters QUICK STOP ACTIVE (bench instrumentation, the drive unchanged)."""
    original = drive._on_controlword

    def on_controlword(cw: int) -> None:
        before = drive.state
        original(cw)
        if before != drive.state and drive.state == PowerState.QUICK_STOP_ACTIVE.value:
            acted.setdefault(drive.node_id, time.monotonic())

    drive._on_controlword = on_controlword  # type: ignore[method-assign]


def one_run(
    cell_name: str,
    case: str,
    at_ms: float,
    full_ms: float | None,
    process: Process | None = None,
    lift: bool = True,
) -> dict[str, float | int]:
    if process is not None:
        served = serve(at_period(CONFIG_DIR / "cells" / f"{cell_name}.yaml", process.period_ms, process.directory))
        cell, _ = next(served)
        channel = cell.bus.channel
        interface = "pvtflow_bench_flaky_wire"
    else:
        # the drives in this interpreter answer late: their confirmations are awaited 50 ms, so that
        # the figure says when they came (the runs within the 10 ms target are counted)
        cell = sharing_the_interpreter(load_cell_config(CONFIG_DIR / "cells" / f"{cell_name}.yaml"))
        channel = unique_channel("stop")
        interface = "pvtflow_test_flaky"
    if full_ms is None:
        full_ms = cell.bus.tx_retry_ms + 1.0
    bus_config = dataclasses.replace(cell.bus, channel=channel, max_sync_gap_periods=1e6)
    cell = dataclasses.replace(cell, bus=bus_config)
    sim = None if process is not None else SimulatedCell(cell, channel=channel, interface="virtual").start()
    bus = CellBus(dataclasses.replace(bus_config, interface=interface), clock=Clock.WALL).open()
    bus.sync.lift_bus_threads = lift and bus.sync.lift_bus_threads
    group = AxisGroup(bus, cell.ordered_axes()[: process.axes] if process is not None else cell.ordered_axes())
    failed_at: list[float] = []  # when the master failed: the SYNC thread raised, or a frame was given up
    full_at: list[float] = []  # when the transmit queue became full (the last window injected)
    at_sync = round(at_ms / bus_config.sync_period_ms)
    acted: dict[int, float] = {}  # node -> time.monotonic() when the drive took the quick stop
    for drive in sim or ():
        watch_quick_stop(drive, acted)
    period_s = bus_config.sync_period_ms / 1000.0

    def inject(n: int) -> None:
        start = group.start_sync
        if start is None or n < start + at_sync or failed_at:
            return
        if case.startswith("dead"):
            failed_at.append(time.monotonic())
            raise RuntimeError("injected")
        if full_at and time.monotonic() < full_at[-1] + full_ms / 1000.0:
            return  # this window is not over yet
        # full from just before the next SYNC is due, for longer than the master retries a frame:
        # that SYNC cannot go out (a SYNC sent late, after the window, gets through: then again)
        assert bus.sync.sent_at is not None
        after = bus.sync.sent_at + period_s - LEAD_S - time.monotonic()
        FlakyBus.fail(channel, full_ms / 1000.0, after=max(after, 0.0))
        full_at.append(FlakyBus.failing_from[channel])

    def on_fault(fault: BusFault) -> None:
        if fault.kind is FaultKind.TX_FAILED and not failed_at:
            failed_at.append(time.monotonic())

    answered: dict[int, float] = {}  # node -> when its first SDO confirmation after the failure came, late ones too

    def tap(msg: can.Message) -> None:
        node = msg.arbitration_id - 0x580
        if failed_at and msg.is_rx and 0 < node < 0x80 and msg.data[:1] == b"\x60" and node not in answered:
            answered[node] = time.monotonic()

    try:
        bus.recorder.taps.append(tap)
        bus.sync.add_sender(inject)
        bus._fault_callbacks.insert(0, on_fault)  # heard before the group acts on it
        if process is not None:
            group.refresh()
            prog = toward_the_middle([lk.config for lk in group.links], [lk.position for lk in group.links], 2000)
        else:
            prog = program(cell.ordered_axes(), 2000, fraction=0.3)
        if group.start(prog) is not None:
            raise RuntimeError(f"not started: {group.last_result}")
        result = group.wait(30.0)
        stop = group.last_quick_stop
        if stop is None or not failed_at:  # ended otherwise: counted apart, with its outcome
            return {
                "requests_ms": float("nan"),
                "acted_ms": float("nan"),
                "confirmed_ms": float("nan"),
                "detected_ms": float("nan"),
                "windows": len(full_at),
                "nmt": 0,
                "axes": 0,
                "other": f"{result.result.value}: {result.message[:90]}",
            }
        stop.done.wait(2.0)
        confirmed = max(stop.confirmed.values()) if not stop.missing else float("nan")
        every = max(acted[n] for n in stop.node_ids) if all(n in acted for n in stop.node_ids) else float("nan")
        return {
            "requests_ms": (stop.started - failed_at[0]) * 1000.0,
            "acted_ms": (every - failed_at[0]) * 1000.0,
            "confirmed_ms": (confirmed - failed_at[0]) * 1000.0,
            "detected_ms": (failed_at[0] - full_at[-1]) * 1000.0 if full_at else float("nan"),
            "windows": len(full_at),
            "nmt": int(bool(stop.nmt_stopped)),
            "axes": len(stop.node_ids),
            "described": stop.describe()
            + "; the answers came "
            + ", ".join(f"node {n} at {(t - failed_at[0]) * 1000:.1f} ms" for n, t in sorted(answered.items())),
        }
    finally:
        FlakyBus.failing_until.pop(channel, None)
        FlakyBus.failing_from.pop(channel, None)
        group.close()
        bus.close()
        if sim is not None:
            sim.stop()
        else:
            served.close()


@dataclasses.dataclass(frozen=True)
class Process:
    """Drives in their own process: the cell's copy at this SYNC period, the first ``axes`` moving."""

    period_ms: float
    axes: int
    directory: Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--cell", default="arm6")
    parser.add_argument("--at-ms", type=float, default=300.0)
    parser.add_argument("--full-ms", type=float, default=None)
    parser.add_argument("--drives", choices=("here", "process"), default="here")
    parser.add_argument("--period-ms", type=float, default=8.0, help="--drives process: the cell's SYNC period")
    parser.add_argument("--axes", type=int, default=2, help="--drives process: the first N axes move")
    parser.add_argument(
        "--bus-threads-normal",
        action="store_true",
        help="leave the master's bus threads at normal priority (SyncClock.lift_bus_threads off): for comparison",
    )
    args = parser.parse_args()
    process = None
    if args.drives == "process":
        process = Process(args.period_ms, args.axes, Path(tempfile.mkdtemp(prefix="pvtflow-stop-")))
    logging.disable(logging.ERROR)  # the injected failure's traceback, logged by the SYNC thread
    warnings.simplefilter("ignore", RuntimeWarning)  # a case where no run confirmed: nan
    where = (
        "in this process" if process is None else f"in their own process, {args.period_ms:g} ms SYNC, {args.axes} axes"
    )
    lifted = (
        "normal priority"
        if args.bus_threads_normal or process is None  # drives here: BusConfig.lift_bus_threads off
        else "SCHED_FIFO below SYNC"
    )
    print(
        f"cell {args.cell}, drives {where}, failure {args.at_ms:g} ms into the motion, {args.runs} runs per case, "
        f"the master's bus threads at {lifted}"
    )
    print(
        "| case | axes | to the requests (p50 / max ms) | to every drive in quick stop (p50 / max ms, runs "
        "within 10 ms) | to every axis confirmed (p50 / max ms) | NMT stop needed | runs that ended otherwise |"
    )
    print("|---|---|---|---|---|---|---|")
    full = "tx_retry_ms + 1 ms" if args.full_ms is None else f"{args.full_ms:g} ms"
    for case in ("dead SYNC thread", f"queue full {full}"):
        runs = [
            one_run(args.cell, case, args.at_ms, args.full_ms, process, not args.bus_threads_normal)
            for _ in range(args.runs)
        ]
        req = np.array([r["requests_ms"] for r in runs])
        conf = np.array([r["confirmed_ms"] for r in runs])
        acted = np.array([r["acted_ms"] for r in runs])
        others = [str(r["other"]) for r in runs if "other" in r]
        within = int((acted <= 10.0).sum())
        detected = np.array([r["detected_ms"] for r in runs])
        windows = sum(int(r["windows"]) for r in runs)
        after = (
            ""
            if np.isnan(detected).all()
            else f"; the failure {np.nanmedian(detected):.2f} / {np.nanmax(detected):.2f} after the queue "
            f"became full, {windows} windows for {len(runs)} runs"
        )
        drive_side = (
            "-"
            if process is not None
            else f"{np.nanmedian(acted):.2f} / {np.nanmax(acted):.2f} ({within} of {len(runs) - len(others)})"
        )
        nmt = sum(int(r["nmt"]) for r in runs)
        late = int(np.isnan(conf).sum()) - len(others)
        for other in others:
            print(f"<!-- {case}: no quick stop, the run ended {other} -->")
        for r in runs:
            if r["nmt"]:
                print(f"<!-- {case}: {r['described']} -->")
        print(
            f"| {case} | {max(int(r['axes']) for r in runs)} | {np.nanmedian(req):.2f} / {np.nanmax(req):.2f} | "
            f"{drive_side} | "
            f"{np.nanmedian(conf):.2f} / {np.nanmax(conf):.2f}, {int((conf <= 10.0).sum())} of {len(runs)} within "
            f"10 ms{after} (+ {late} not within the bound) | "
            f"{nmt} of {len(runs)} | {len(others)} |",
            flush=True,
        )
    threading.Event().wait(0.1)


if __name__ == "__main__":
    main()
