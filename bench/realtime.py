"""Every seed drive on the wall clock: random moves through the service with SYNC in real time.

For each drive behaviour (epos2_pvt, cia402_ip_linear, sync_setpoint, parker_slvdn with submodes
0, -1, -2) at each SYNC period, on the gantry3 and arm6 robots (every axis on that behaviour), a
MotionService with SYNC on the wall clock (``clock=Clock.WALL``, plans in the child process as
``pvtflow serve --real-time`` does) plans random single-target moves from where the axes stand and
executes them to their end; a second run does the same while another thread asks for a plan every
100 ms. Figures per case:

- moves planned / finished / faulted (and refused plans with the planner's reason);
- setpoints late for their SYNC: SYNCs inside a fixed-period drive's stream that validated no new
  setpoint (the drive then holds; must be 0);
- SYNC interval as the drives see it (arrival in the simulated drives' receive thread): p50 / p99 / max;
- EPOS2: the lowest FIFO level while records were still to be sent (the feeder's count, never
  below the drive's), and buffer underflows the drives reported (must be 0).

    python3 bench/realtime.py [--moves 20] [--periods 1,2,4] [--robots gantry3,arm6] [--seed 1]
        [--profiles epos2_pvt,cia402_ip_linear,sync_setpoint,parker_slvdn:0,parker_slvdn:-1,parker_slvdn:-2]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive
from pvtflow.service.api import ApiError, parse_execute, parse_plan, parse_recover
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config
from pvtflow.service.motion import MotionService

PROFILES = "epos2_pvt,cia402_ip_linear,sync_setpoint,parker_slvdn:0,parker_slvdn:-1,parker_slvdn:-2"


def variant(cell: CellConfig, profile: str, submode: int | None, sync_ms: float) -> CellConfig:
    """The cell with every axis on one drive behaviour at one SYNC period, on its own virtual channel
    (without homing: not every behaviour has a homing mode, and the streaming is what is measured)."""
    fixed = profile != "epos2_pvt"
    axes = tuple(
        dataclasses.replace(
            a,
            profile=profile,
            period_ms=round(sync_ms) if fixed else None,
            interpolation_submode=submode if profile == "parker_slvdn" else None,
            homing=None,
            simulation=None,
        )
        for a in cell.axes
    )
    bus = dataclasses.replace(cell.bus, sync_period_ms=sync_ms, channel=f"rt-{uuid.uuid4().hex[:10]}")
    name = f"{cell.name}-{profile}{submode or ''}"
    return dataclasses.replace(cell, axes=axes, bus=bus, name=name, homing_order=(), requires_homing=False)


class SyncArrivals:
    """When each SYNC reaches the simulated drives' receive thread (the drives' view of the period)."""

    def __init__(self, network: Any) -> None:
        self.times: list[float] = []
        network.subscribe(0x80, self._on_sync)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.times.append(time.perf_counter())

    def intervals_ms(self) -> np.ndarray:
        t = np.asarray(self.times)
        d = np.diff(t) * 1000.0
        return d[d < 50.0]  # the gaps between motions are not periods


def late_setpoints(drive: FixedPeriodDrive, since: int) -> int:
    """SYNCs inside the setpoint stream of the run started after SYNC ``since`` that validated no new
    setpoint. (A Parker's interpolation stays active between runs: the run's stream starts with its
    own first setpoint, not with the drive's activation.)"""
    syncs = sorted({s for s, _ in drive.setpoints if s > since})
    return (syncs[-1] - syncs[0] + 1) - len(syncs) if syncs else 0


def run_case(cell: CellConfig, moves: int, rng: np.random.Generator, planning_load: bool) -> dict[str, Any]:
    out: dict[str, Any] = {"planned": 0, "refused": [], "finished": 0, "faulted": [], "late": 0}
    min_level: int | None = None
    underflows = 0
    with tempfile.TemporaryDirectory() as journal:
        svc = MotionService(cell, journal_dir=journal, clock=Clock.WALL, planner_process=True).open()
        arrivals = SyncArrivals(svc.sim.network)
        stop_load = threading.Event()
        load_plans = [0]

        def plan_every_100ms() -> None:
            lim = cell.joint_limits()
            while not stop_load.wait(0.1):
                q = [lo + 0.5 * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)]
                req = parse_plan({"waypoints": [q, [x * 0.99 for x in q]], "start": "first"}, cell.joint_names, lim)
                try:
                    svc.plan(req)
                    load_plans[0] += 1
                except ApiError:
                    pass

        loader = threading.Thread(target=plan_every_100ms, daemon=True) if planning_load else None
        try:
            if loader is not None:
                loader.start()
            lim = cell.joint_limits()
            for _ in range(moves):
                target = [
                    lo + f * (hi - lo)
                    for lo, hi, f in zip(lim.lower, lim.upper, rng.uniform(0.1, 0.9, len(lim.lower)), strict=True)
                ]
                req = parse_plan({"waypoints": [target], "start": "current"}, cell.joint_names, lim)
                try:
                    plan_id = svc.plan(req)["plan_id"]
                except ApiError as exc:
                    out["refused"].append(str(exc)[:140])
                    continue
                out["planned"] += 1
                started = {id(d): d.sync_count for d in svc.sim if isinstance(d, FixedPeriodDrive)}
                try:
                    outcome = svc.execute(parse_execute({"plan_id": plan_id, "wait": True}))["outcome"]
                    result, why = outcome["result"], outcome["message"]
                except ApiError as exc:
                    result, why = "refused", str(exc)
                if result == "finished":
                    out["finished"] += 1
                else:
                    out["faulted"].append(f"{result}: {why}"[:160])
                    try:
                        svc.group.settle(5.0)
                        svc.recover(parse_recover({}))
                    except ApiError:
                        break
                for drive in svc.sim:
                    if isinstance(drive, FixedPeriodDrive):
                        out["late"] += late_setpoints(drive, started[id(drive)])
                if result != "refused":
                    for axis in outcome["axes"]:
                        if axis["min_level"] is not None:
                            min_level = axis["min_level"] if min_level is None else min(min_level, axis["min_level"])
                        underflows += axis["underflows"]
        finally:
            stop_load.set()
            if loader is not None:
                loader.join(2.0)
            svc.close()
        d = arrivals.intervals_ms()
        out["sync_ms"] = (float(np.percentile(d, 50)), float(np.percentile(d, 99)), float(d.max())) if len(d) else None
        out["epos2_min_level"] = min_level
        out["epos2_underflows"] = underflows
        out["load_plans"] = load_plans[0]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--moves", type=int, default=20)
    ap.add_argument("--periods", default="1,2,4")
    ap.add_argument("--robots", default="gantry3,arm6")
    ap.add_argument("--profiles", default=PROFILES)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-load-run", action="store_true", help="skip the run with a plan every 100 ms")
    args = ap.parse_args()
    print(
        f"python3 bench/realtime.py --moves {args.moves} --periods {args.periods} --robots {args.robots} "
        f"--profiles {args.profiles} --seed {args.seed}" + (" --no-load-run" if args.no_load_run else "")
    )
    print(
        "| robot | profile | SYNC ms | load | planned | finished | faulted | late setpoints "
        "| SYNC interval p50/p99/max ms | EPOS2 min level / underflows |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    total_faulted = total_late = 0
    for robot in args.robots.split(","):
        base = load_cell_config(CONFIG_DIR / "cells" / f"{robot}.yaml")
        for spec in args.profiles.split(","):
            profile, _, sub = spec.partition(":")
            submode = int(sub) if sub else (-1 if profile == "parker_slvdn" else None)
            for period in (float(p) for p in args.periods.split(",")):
                for load in [False] if args.no_load_run else [False, True]:
                    rng = np.random.default_rng(args.seed)
                    r = run_case(variant(base, profile, submode, period), args.moves, rng, load)
                    total_faulted += len(r["faulted"])
                    total_late += r["late"]
                    sync = "-" if r["sync_ms"] is None else "{:.3f} / {:.3f} / {:.3f}".format(*r["sync_ms"])
                    epos = "-" if r["epos2_min_level"] is None else f"{r['epos2_min_level']} / {r['epos2_underflows']}"
                    name = profile + (f" {submode}" if profile == "parker_slvdn" else "")
                    print(
                        f"| {robot} | {name} | {period:g} | {'plan/100ms' if load else '-'} "
                        f"| {r['planned']}/{args.moves} "
                        f"| {r['finished']} | {len(r['faulted'])} | {r['late']} | {sync} | {epos} |",
                        flush=True,
                    )
                    for why in r["faulted"][:2]:
                        print(f"|   fault: {why} |", flush=True)
                    for why in sorted(set(r["refused"]))[:2]:
                        print(f"|   refused: {why} |", flush=True)
    print(f"total: {total_faulted} faulted moves, {total_late} late setpoints")


if __name__ == "__main__":
    main()
