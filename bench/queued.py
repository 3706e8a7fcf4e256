"""Queued motions (issue 38): the SYNC periods of standstill between two queued plans, on the drives.

    PYTHONPATH=. python3 bench/queued.py [--pairs 5]

A MotionService on simulated drives (in this process, so that the drives' per-SYNC demand can be read),
per cell: ``--pairs`` pairs of full-speed plans drawn at random (seed 1) between 15 % and 85 % of every
joint's range, the second from where the first ends; the first executed, the second executed with
``queue`` at once. From every drive's demand at every SYNC of the run: the SYNC periods in which no axis
moved within 40 periods of the junction, against the same count on the two programs joined (their own:
ends at rest, the EPOS2's start dwell); the difference is the standstill the queue added. Also the queued
motion's start SYNC against the SYNC after the first one's last record. Lockstep for EPOS2 and fixed-
period cells; the wall clock for the EPOS2 cells (a fixed-period drive in the master's interpreter on a
shared host misses setpoint deadlines: tests/service/test_stop_then_move.py says why). On the wall clock,
other pairs executed one after the other (the second once the first has ended) are the stop-and-go line:
the dead time between them (``separate_pair``).
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
sys.path.insert(0, str(ROOT / "tests"))

from axes_programs import standstill_syncs  # noqa: E402
from svc_helpers import on_own_channel  # noqa: E402

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.drive.program import joined  # noqa: E402
from pvtflow.service.api import ApiError, parse_execute, parse_home, parse_plan, parse_recover  # noqa: E402
from pvtflow.service.config import CONFIG_DIR, load_cell_config  # noqa: E402
from pvtflow.service.motion import MotionService  # noqa: E402

JUNCTION_PERIODS = 40  # SYNC periods either side of the junction in which the standstill between the two is counted
CASES = [
    ("arm6", True),
    ("gantry3", True),
    ("gantry3-sync-setpoint", True),
    ("gantry3-ip-linear", True),
    ("arm6", False),
    ("gantry3", False),
]
ONLY = [c for c in CASES if any(arg == f"--{c[0]}-{'lockstep' if c[1] else 'wall'}" for arg in sys.argv)]


def cell_of(name: str, lockstep: bool):  # type: ignore[no-untyped-def]
    cell = on_own_channel(load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml"))
    axes = tuple(  # an axis that homes powers up near its home (a short homing: not what is measured)
        dataclasses.replace(a, simulation=dataclasses.replace(a.simulation, power_up_qc=a.homing.offset_qc))
        if a.homing is not None and a.simulation is not None
        else a
        for a in cell.axes
    )
    cell = dataclasses.replace(cell, axes=axes)
    if not lockstep:  # the drives share the master's interpreter (as tests/service/test_stop_then_move.py)
        cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, heartbeat_timeout_factor=10))
    return cell


def at(svc: MotionService, f: np.ndarray) -> list[float]:
    lim = svc.cell.joint_limits()
    return [float(x) for x in lim.lower + f * (lim.upper - lim.lower)]


def plan(svc: MotionService, waypoints: list[list[float]], start: str) -> str:
    req = parse_plan({"waypoints": waypoints, "start": start}, svc.cell.joint_names, svc.cell.joint_limits())
    return str(svc.plan(req)["plan_id"])


def queued_pair(svc: MotionService, a: np.ndarray, b: np.ndarray) -> tuple[int, int, int] | str:
    """(standstill periods measured, the programs' own, the queued start SYNC minus the SYNC after the first's end).
    The first goes through the far corner first: long enough to be queued after (the end-record hold). A run
    that did not finish (on the wall clock on a loaded host: a late SYNC, the gap rule): its outcome, recovered."""
    first_plan = plan(svc, [at(svc, 1.0 - a), at(svc, a)], "current")
    then_plan = plan(svc, [at(svc, a), at(svc, b)], "first")
    first = svc.execute(parse_execute({"plan_id": first_plan}))
    try:
        queued = svc.execute(parse_execute({"plan_id": then_plan, "queue": True}))
    except ApiError as exc:  # the first motion shorter than the end record's hold: refused, as it must be
        running = svc.motion
        assert running is not None and running.done.wait(120.0)
        return f"refused: {exc.message[:100]}"
    second = next(m for m in svc.activity.queued() if m.motion_id == queued["motion_id"])
    assert second.done.wait(120.0) and second.outcome is not None, "the queued motion did not end"
    if second.outcome["result"] != "finished":
        settle(svc)
        return f"{second.outcome['result']}: {second.outcome['message'][:90]}"
    programs = [svc.stored_plan(p).program for p in (first_plan, then_plan)]
    whole = joined(programs)
    period = svc.cell.bus.sync_period_ms
    start = int(first["start_sync"])
    end = start + int(np.ceil(whole.duration_ms / period))
    t = (np.arange(start, end + 1) - start) * period
    planned = np.array([ax.reconstruction().position(t) for ax in whole.axes]).T
    demand = []
    for ax in whole.axes:
        history = {s.sync: s.demand for s in svc.sim.drive(ax.node_id).history}
        demand.append([history[n] for n in range(start, end + 1)])
    after = start + int(np.ceil(programs[0].duration_ms / period))
    # between the two: the periods from the last move of the first to the first move of the second, within a
    # window about the junction (on the wall clock a drive's sample now and then repeats one mid-motion: a
    # SYNC processed late, not a standstill of the queue's)
    near = slice(max(0, after - start - JUNCTION_PERIODS), after - start + JUNCTION_PERIODS)
    measured = standstill_syncs(np.array(demand).T[near])
    return measured, standstill_syncs(planned[near]), int(second.start_sync or -1) - after


def settle(svc: MotionService) -> None:
    """After a run that did not finish: recovered, at rest, positions read again."""
    if svc.state == "fault":
        svc.recover(parse_recover({}))
    assert svc.group is not None
    svc.group.settle(5.0)
    time.sleep(0.5)
    svc.positions_qc(refresh=True)


def separate_pair(svc: MotionService, a: np.ndarray, b: np.ndarray) -> float | None:
    """Stop and go on the wall clock: the same pair planned first, the second executed once the first has
    ended; the wall time (ms) from the first's start to the second's start less the first's duration (execute
    replies just after its start SYNC): the end's detection, journaling, cleanup, check and start."""
    first_plan = plan(svc, [at(svc, a)], "current")
    then_plan = plan(svc, [at(svc, a), at(svc, b)], "first")
    svc.execute(parse_execute({"plan_id": first_plan}))
    t_first = time.perf_counter()
    first = svc.motion
    assert first is not None and first.done.wait(120.0)
    if first.outcome is None or first.outcome["result"] != "finished":
        settle(svc)
        return None
    svc.execute(parse_execute({"plan_id": then_plan}))
    t_then = time.perf_counter()
    second = svc.motion
    assert second is not None and second.done.wait(120.0)
    if second.outcome is None or second.outcome["result"] != "finished":
        settle(svc)
    return 1000.0 * (t_then - t_first) - svc.stored_plan(first_plan).program.duration_ms


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pairs", type=int, default=5)
    args, _ = ap.parse_known_args()  # and --CELL-lockstep / --CELL-wall: those cases only
    print(
        "| cell | SYNC | pairs | standstill periods: measured / the programs' own / added | queued start SYNC - "
        "SYNC after the first's end | stop and go: dead time ms p50 / max (SYNC periods) |"
    )
    print("|---|---|---|---|---|---|")
    for name, lockstep in ONLY or CASES:
        rng = np.random.default_rng(1)
        with tempfile.TemporaryDirectory() as journal:
            svc = MotionService(cell_of(name, lockstep), journal_dir=journal, clock=Clock.of(lockstep)).open()
            try:
                if svc.cell.requires_homing:
                    assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
                dof = svc.cell.joint_limits().dof
                rows, gaps = [], []
                for _ in range(args.pairs):
                    a, b = 0.15 + 0.7 * rng.random(dof), 0.15 + 0.7 * rng.random(dof)
                    try:
                        rows.append(queued_pair(svc, a, b))
                    except ApiError as exc:  # after a run that ended on a late SYNC: the axes still settling
                        rows.append(f"refused: {exc.message[:90]}")
                        settle(svc)
                for _ in range(args.pairs if not lockstep else 0):  # lockstep: no wall time to speak of
                    a, b = 0.15 + 0.7 * rng.random(dof), 0.15 + 0.7 * rng.random(dof)
                    try:
                        gap = separate_pair(svc, a, b)
                    except ApiError as exc:  # after a run that ended on a late SYNC: the axes still settling
                        print(f"  ({name}: stop and go refused: {exc.message[:90]})")
                        settle(svc)
                        continue
                    if gap is not None:
                        gaps.append(gap)
            finally:
                svc.close()
        failed = [r for r in rows if isinstance(r, str)]
        done = [r for r in rows if not isinstance(r, str)]
        measured = "/".join(str(r[0]) for r in done)
        own = "/".join(str(r[1]) for r in done)
        added = max((r[0] - r[1] for r in done), default=None)
        late = sorted({r[2] for r in done})
        for why in failed:
            print(f"  ({name}: a run ended {why})")
        period = svc.cell.bus.sync_period_ms
        stop_go = "-"
        if gaps:
            p50, worst = float(np.median(gaps)), max(gaps)
            stop_go = f"{p50:.1f} / {worst:.1f} ({p50 / period:.0f} / {worst / period:.0f})"
        print(
            f"| {name} | {'lockstep' if lockstep else 'wall clock'} | {len(done)} of {args.pairs} | "
            f"{measured} / {own} / {added} at most | {late} | {stop_go} |"
        )
    print(f"command: PYTHONPATH=. python3 bench/queued.py --pairs {args.pairs}")


if __name__ == "__main__":
    main()
