"""Bus load per SYNC period of every shipped cell, measured on a lockstep run: does the master fit the bus?

Each cell (configs/cells/*.yaml) runs a planned tour on its simulated drives, SYNC in lockstep, twice:
the first start (drives enabled by SDO, the records sent before the start SYNC with no SYNC running)
and the start of a ready cell (one check SYNC, the records out in its period, the start SYNC one
period later: docs/development.md, "The start of a ready cell"). Cells that require homing home first, unmeasured.
Every frame of the runs is costed with ``axes.canbus.frame_time.frame_bits`` (exact stuffing) and assigned
to a SYNC period by the SYNC frames in order: everything between SYNC n and SYNC n + 1 is period n,
which in lockstep is exact whatever the wall clock did. Frames the master sends are taken as it sends
them, frames the drives send as they arrive, before the master acts on them (so an answer is never
counted after the SYNC it made the master send).

Per cell, as % of the bus (bit rate x SYNC period): mean load over the motion, the worst single period,
the worst 10-period window, the periods before the start SYNC (the check SYNC's), the most EPOS2
records sent in one period, the lowest FIFO level the feeders kept (and underflows), and the cell's
budget (``axes.master.budget``). Target: every period <= 100 %, every 10-period window <= 70 %.

    python3 bench/wire.py [--cells arm6,gantry3] [--tour-points 4]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import uuid
from pathlib import Path

import can
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.frame_time import frame_bits
from pvtflow.axes.drive.objects import EPOS2_RPDOS, SYNC_COB_ID
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.homing import CellHoming
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config
from pvtflow.service.demo_cmd import tour

WINDOW = 10


class WireTap(can.Listener):
    """Every frame on the cell's bus in the order the master saw it: its own as it sends them (the
    recorder's tap), the drives' as they arrive (first of the notifier's listeners)."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self.on = False
        self._lock = threading.Lock()

    def sent(self, msg: can.Message) -> None:
        if not msg.is_rx:
            self._add(msg)

    def on_message_received(self, msg: can.Message) -> None:
        self._add(msg)

    def _add(self, msg: can.Message) -> None:
        if self.on and not msg.is_error_frame:
            with self._lock:
                self.frames.append(msg)


@dataclasses.dataclass
class Periods:
    """Bits per SYNC period of one run (period 0: the first SYNC's)."""

    bits: list[int]
    records: list[int]
    before_sync_bits: int  # frames before the run's first SYNC (no SYNC running: no period)
    start_index: int  # the start SYNC's period
    capacity: float  # bits the bus carries in one period

    def load(self) -> np.ndarray:
        return np.asarray(self.bits, dtype=float) / self.capacity

    def windows(self) -> np.ndarray:
        b = np.asarray(self.bits, dtype=float)
        if len(b) < WINDOW:
            return np.array([b.sum() / (WINDOW * self.capacity)])
        c = np.concatenate([[0.0], np.cumsum(b)])
        return (c[WINDOW:] - c[:-WINDOW]) / (WINDOW * self.capacity)


def periods(frames: list[can.Message], cell: CellConfig, start_offset: int) -> Periods:
    """Cost the frames and sum them per SYNC period; the last (open) period is left out."""
    record_cobs = {EPOS2_RPDOS[0].cob_id(a.node_id, True) for a in cell.axes if a.profile == "epos2_pvt"}
    bits: list[int] = []
    records: list[int] = []
    before = 0
    for msg in frames:
        cost = frame_bits(
            msg.arbitration_id,
            bytes(msg.data),
            extended=msg.is_extended_id,
            remote=msg.is_remote_frame,
            dlc=msg.dlc,
        )
        if msg.arbitration_id == SYNC_COB_ID and not msg.is_extended_id:
            bits.append(0)
            records.append(0)
        if not bits:
            before += cost
            continue
        bits[-1] += cost
        if msg.arbitration_id in record_cobs:
            records[-1] += 1
    capacity = cell.bus.bitrate * cell.bus.sync_period_ms / 1000.0
    return Periods(bits[:-1], records[:-1], before, start_offset, capacity)


def measure(cell: CellConfig, tour_points: int) -> dict[str, object]:
    channel = f"wire-{uuid.uuid4().hex[:10]}"
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=channel))
    planner = CellPlanner(cell)
    lim = planner.limits
    cell = sharing_the_interpreter(cell)  # the drives run in this interpreter
    sim = SimulatedCell(cell, channel=channel).start()
    bus = CellBus(cell.bus, clock=Clock.LOCKSTEP).open()
    tap = WireTap()
    bus.recorder.taps.append(tap.sent)
    assert bus.network.notifier is not None
    bus.network.notifier.listeners.insert(0, tap)
    group = AxisGroup(bus, cell.ordered_axes())
    out: dict[str, object] = {"cell": cell.name}
    try:
        stages = cell.homing_stages()
        if stages:
            homing = CellHoming(group).run(stages)
            if not homing.ok:
                raise RuntimeError(f"{cell.name}: homing failed: {homing}")
        group.configure_if_needed()
        group.refresh()
        here = np.array(
            [
                cell.axis_for_joint(j).scaling.qc_to_position(lk.position)
                for j, lk in zip(cell.joint_names, group.links, strict=True)
            ],
            dtype=float,
        )
        here = np.clip(here, lim.lower, lim.upper)
        points = np.array(tour(lim.lower, lim.upper, tour_points))
        runs = []
        for label, waypoints in (("first start", np.vstack([here, points])), ("ready start", points[::-1])):
            plan = planner.plan(PlanInput(waypoints))
            if not plan.ok or plan.program is None:
                raise RuntimeError(f"{cell.name}: plan failed: {plan.code} {plan.message}")
            tap.frames.clear()
            tap.on = True
            result = group.run(plan.program, timeout_s=120)
            tap.on = False
            if not result.ok:
                raise RuntimeError(f"{cell.name}: {label}: {result.result}: {result.message}")
            p = periods(list(tap.frames), cell, 0)
            levels = [
                a.feed.min_level for a in result.axes if a.profile == "epos2_pvt" and a.feed.min_level is not None
            ]
            underflows = sum(a.feed.underflows for a in result.axes)
            start = result.start_sync or 0
            # the run's first SYNC is the check SYNC (ready start) or the start SYNC (first start)
            first_sync = start - (1 if label == "ready start" else 0)
            before_start = p.bits[: start - first_sync]
            runs.append(
                {
                    "label": label,
                    "duration_ms": plan.program.duration_ms,
                    "periods": len(p.bits),
                    "mean": float(np.mean(p.load())),
                    "worst": float(np.max(p.load())),
                    "worst_at": int(np.argmax(p.load())) - (start - first_sync),
                    "window": float(np.max(p.windows())),
                    "pre_start": max(before_start) / p.capacity if before_start else None,
                    "before_sync_ms": p.before_sync_bits / cell.bus.bitrate * 1000.0,
                    "records_max": max(p.records) if p.records else 0,
                    "min_level": min(levels) if levels else None,
                    "underflows": underflows,
                }
            )
        out["runs"] = runs
    finally:
        group.close()
        bus.close()
        sim.stop()
    return out


def budget_line(cell: CellConfig) -> str:
    try:
        from pvtflow.axes.master.budget import bus_budget
    except ImportError:
        return "budget: (axes.master.budget not there)"
    b = bus_budget(cell)
    return (
        f"budget {100 * b.window_fraction:.1f} % of a 10-period window, {100 * b.peak_fraction:.1f} % in the worst "
        f"period ({b.window_bits:.0f} of {10 * b.capacity_bits:.0f} bits per window)"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", help="comma-separated cell names (default: every file in configs/cells)")
    p.add_argument("--tour-points", type=int, default=4)
    args = p.parse_args()
    files = sorted((CONFIG_DIR / "cells").glob("*.yaml"))
    if args.cells:
        names = set(args.cells.split(","))
        files = [f for f in files if f.stem in names]
    print(
        f"{'cell':22} {'bus':>9} {'SYNC':>6} {'run':12} {'motion':>8} {'mean':>6} {'worst':>7} {'at':>5} "
        f"{'10-win':>7} {'pre-start':>9} {'rec/per':>7} {'minFIFO':>7} {'underfl':>7}"
    )
    for f in files:
        cell = load_cell_config(f)
        res = measure(cell, args.tour_points)
        for r in res["runs"]:  # type: ignore[attr-defined]
            pre = "-" if r["pre_start"] is None else f"{100 * r['pre_start']:.0f} %"
            print(
                f"{cell.name:22} {cell.bus.bitrate // 1000:>5} k/s {cell.bus.sync_period_ms:>4g}ms {r['label']:12} "
                f"{r['duration_ms']:>6} ms {100 * r['mean']:>5.0f}% {100 * r['worst']:>6.0f}% {r['worst_at']:>5} "
                f"{100 * r['window']:>6.0f}% {pre:>9} {r['records_max']:>7} "
                f"{'-' if r['min_level'] is None else r['min_level']:>7} {r['underflows']:>7}"
            )
        print(
            f"{'':22} {budget_line(cell)}; first start: {res['runs'][0]['before_sync_ms']:.2f} ms of bus "  # type: ignore[index]
            "before its start SYNC (no SYNC running)"
        )
    print("at: the worst period's index from the start SYNC (negative: before it); pre-start: the check SYNC's period")
    print(
        f"command: python3 bench/wire.py{' --cells ' + args.cells if args.cells else ''}"
        f"{'' if args.tour_points == 4 else f' --tour-points {args.tour_points}'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
