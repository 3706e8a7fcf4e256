"""Homing (CiA 402 mode 6) in simulation: every simulated method, and the not_homed refusals.

1. Every method the simulated drives run (axes.drive.objects.HomingMethod), on axis x of gantry3 (its
   other axes have nothing to home), ``--runs`` times from seeded random power-up positions of the
   machine (``AxisSimulation.seed``): time to homed (drive time, from the start SYNC to the SYNC
   that reported homing attained at rest; and the wall time in SYNC lockstep), position error after
   homing (the position the drive reads minus where the axis really is from the home it found, plus
   the home offset: target 0 counts), and where on the machine the home was found (its spread over
   the runs: 0 for the methods with a fixed home - switches, hard stops, the index pulse after a
   switch -; the index-only and current-position methods find the home near where they start).
2. The refusals on the simulated gantry3 through the service (``MotionService``, as zenoh's
   ``execute`` reaches it): execute before homing, then ``--reboots`` times a drive reboots (NMT
   reset node, or a power cycle: boot-up message) and execute is tried again (target: refused
   every time, ``not_homed``); after each, recover, home that axis again and execute (finished).
3. gantry3 homed once with SYNC on the wall clock (1 ms, as a real cell): drive and wall time.

    python3 bench/homing.py [--runs 5] [--reboots 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import AxisSimulation, HomingConfig
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.homing import CellHoming
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.service.api import ApiError, parse_execute, parse_home, parse_plan, parse_recover
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config
from pvtflow.service.motion import MotionService

M = od.HomingMethod
INDEX = 4096
SWITCHES = AxisSimulation(
    negative_limit_switch_qc=-2000,
    positive_limit_switch_qc=30000,
    home_switch_qc=10000,
    index_spacing_qc=INDEX,
    index_offset_qc=123,
)
NEGATIVE_HOME_SWITCH = dataclasses.replace(SWITCHES, home_switch_active_above=False)
HARD_STOPS = AxisSimulation(
    index_spacing_qc=INDEX, index_offset_qc=123, negative_hard_stop_qc=-3000, positive_hard_stop_qc=33000
)
MACHINES = {
    M.NEGATIVE_HOME_SWITCH_FROM_BELOW: NEGATIVE_HOME_SWITCH,
    M.NEGATIVE_HOME_SWITCH_FROM_ABOVE: NEGATIVE_HOME_SWITCH,
    M.HARD_STOP_POSITIVE_INDEX: HARD_STOPS,
    M.HARD_STOP_NEGATIVE_INDEX: HARD_STOPS,
    M.HARD_STOP_POSITIVE: HARD_STOPS,
    M.HARD_STOP_NEGATIVE: HARD_STOPS,
}
SPEEDS = dict(switch_speed_rpm=1200.0, zero_speed_rpm=200.0, acceleration_rpm_s=20000.0)
OFFSET = 777  # 0x607C: what the position reads at the home position


def x_only(cell: CellConfig, homing: HomingConfig, machine: AxisSimulation) -> CellConfig:
    axes = tuple(
        dataclasses.replace(a, homing=homing, simulation=machine)
        if a.joint == "x"
        else dataclasses.replace(a, homing=None, simulation=None)
        for a in cell.axes
    )
    bus = dataclasses.replace(cell.bus, channel=f"bench-home-{uuid.uuid4().hex[:8]}")
    return dataclasses.replace(cell, axes=axes, bus=bus, homing_order=(), requires_homing=True)


def home_once(cell: CellConfig, lockstep: bool = True) -> tuple[object, float, SimulatedCell]:
    cell = sharing_the_interpreter(cell)  # the drives run in this interpreter
    with SimulatedCell(cell) as sim:
        bus = CellBus(cell.bus, clock=Clock.of(lockstep)).open()
        group = AxisGroup(bus, cell.ordered_axes())
        try:
            t0 = time.perf_counter()
            outcome = CellHoming(group).run(cell.homing_stages())
            wall = time.perf_counter() - t0
        finally:
            group.close()
            bus.close()
    return outcome, wall, sim


def methods(gantry: CellConfig, runs: int) -> bool:
    print(f"## every method: axis x of gantry3, {runs} seeded power-up positions each, home offset {OFFSET} qc")
    print(
        "| method | homed | drive time s (median / max) | wall s (median) | position error qc (max abs) "
        "| home found on the machine (spread qc) |"
    )
    print("|---|---|---|---|---|---|")
    all_ok = True
    for method in sorted(M, key=lambda m: (m < 0, abs(m))):
        machine = MACHINES.get(method, SWITCHES)
        threshold = 1000 if method < 0 else None
        homing = HomingConfig(method, offset_qc=OFFSET, timeout_s=20.0, current_threshold_ma=threshold, **SPEEDS)  # type: ignore[arg-type]
        times, walls, errors, homes, homed = [], [], [], [], 0
        for seed in range(runs):
            cell = x_only(gantry, homing, dataclasses.replace(machine, seed=seed))
            outcome, wall, sim = home_once(cell)
            drive = sim.drive("x")
            run = drive.homing.runs[-1]
            if outcome.ok and run.reference is not None:  # type: ignore[attr-defined]
                homed += 1
                times.append(outcome.axes[0].time_s)  # type: ignore[attr-defined]
                walls.append(wall)
                errors.append(drive.actual - (drive.machine_position - run.reference + OFFSET))
                homes.append(run.reference)
        all_ok &= homed == runs and all(e == 0 for e in errors)
        name = f"{int(method)} {method.name.lower()}"
        if not times:
            print(f"| {name} | 0/{runs} | - | - | - | - |")
            continue
        spread = max(homes) - min(homes)
        print(
            f"| {name} | {homed}/{runs} | {statistics.median(times):.3f} / {max(times):.3f} "
            f"| {statistics.median(walls):.2f} | {max(abs(e) for e in errors):.3g} | {spread:.0f} |",
            flush=True,
        )
    return all_ok


def refusals(gantry: CellConfig, reboots: int) -> bool:
    print(f"\n## refusals on gantry3 (MotionService, lockstep): execute before homing and after {reboots} reboots")
    cell = dataclasses.replace(
        gantry, bus=dataclasses.replace(gantry.bus, channel=f"bench-home-{uuid.uuid4().hex[:8]}")
    )
    refused = tried = finished = plans_refused = 0
    with tempfile.TemporaryDirectory() as journal:
        svc = MotionService(cell, journal_dir=journal, clock=Clock.LOCKSTEP).open()
        try:
            home_q = [float(a.scaling.qc_to_position(a.homing.offset_qc)) for a in cell.ordered_axes()]  # type: ignore[union-attr]
            away = [home_q[0] + 0.05, home_q[1] + 0.04, home_q[2] - 0.03]

            def plan(request: dict[str, object]) -> str:
                return str(svc.plan(parse_plan(request, cell.joint_names, svc.limits))["plan_id"])

            def execute(plan_id: str) -> str:
                try:
                    return str(svc.execute(parse_execute({"plan_id": plan_id, "wait": True}))["outcome"]["result"])
                except ApiError as exc:
                    return exc.code.value

            tried += 1
            refused += execute(plan({"waypoints": [home_q, away], "start": "first"})) == "not_homed"
            try:
                plan({"target": away})
            except ApiError as exc:
                plans_refused += exc.code.value == "not_homed"
            assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
            finished += execute(plan({"target": away})) == "finished"
            there = home_q
            for k in range(reboots):
                joint = cell.joint_names[k % 3]
                node = cell.axis_for_joint(joint).node_id
                stored = plan({"target": there})  # planned while homed, executed after the reboot
                boots = svc.bus.watch.boot_count(node)  # type: ignore[union-attr]
                if k % 2 == 0:
                    svc.bus.nmt(node, 0x81)  # type: ignore[union-attr]  # NMT reset node
                else:
                    svc.sim.drive(node).power_cycle()  # power loss: boot-up message
                deadline = time.monotonic() + 5.0
                while svc.bus.watch.boot_count(node) == boots and time.monotonic() < deadline:  # type: ignore[union-attr]
                    time.sleep(0.005)
                tried += 1
                refused += execute(stored) == "not_homed"
                svc.recover(parse_recover({}))
                outcome = svc.home(parse_home({"joints": [joint], "wait": True}))["outcome"]
                assert outcome["result"] == "homed", outcome
                finished += execute(plan({"target": there})) == "finished"
                there = away if there == home_q else home_q
        finally:
            svc.close()
    print(f"  execute refused with not_homed: {refused}/{tried} (target: every time)")
    print(f"  plan from the current position before homing refused with not_homed: {plans_refused}/1")
    print(f"  execute after homing again: finished {finished}/{reboots + 1}")
    return refused == tried and finished == reboots + 1 and plans_refused == 1


def real_time(gantry: CellConfig) -> bool:
    print("\n## gantry3 homed with SYNC on the wall clock (1 ms, as a real cell)")
    cell = dataclasses.replace(
        gantry, bus=dataclasses.replace(gantry.bus, channel=f"bench-home-{uuid.uuid4().hex[:8]}")
    )
    outcome, wall, sim = home_once(cell, clock=Clock.WALL)
    for a in outcome.axes:  # type: ignore[attr-defined]
        drive = sim.drive(a.joint)
        error = drive.actual - round(drive.machine_position)
        print(f"  {a.joint}: method {a.method}, {a.time_s:.3f} s of drive time, position error {error} qc")
    print(f"  {outcome.result.value}: {outcome.message}; wall time {wall:.2f} s")  # type: ignore[attr-defined]
    return bool(outcome.ok)  # type: ignore[attr-defined]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="seeded power-up positions per method (default 5)")
    ap.add_argument("--reboots", type=int, default=10, help="drive reboots in the refusal test (default 10)")
    args = ap.parse_args()
    gantry = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
    print(f"python3 bench/homing.py --runs {args.runs} --reboots {args.reboots}\n")
    ok = methods(gantry, args.runs)
    ok &= refusals(gantry, args.reboots)
    ok &= real_time(gantry)
    print("\nall targets met" if ok else "\nTARGETS MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
