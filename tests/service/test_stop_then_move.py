"""After a stop, a fault and a recovery the cell moves again, on every seed drive, in lockstep and on
the wall clock (issue 19).

A stopped motion must leave nothing behind in the drives: every EPOS2 FIFO empty, every
interpolation ended, every demand at rest on the position the drive reports; the next motion,
planned from where the axes stand, then runs to its end with no drive fault. The service is driven
directly (MotionService, no zenoh: the zenoh path is tested elsewhere), on simulated drives.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import pytest
from svc_helpers import CONFIGS, UNHURRIED_BUDGET_MS, on_own_channel, wait_until

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.sim.profiles.epos2 import Epos2Drive
from pvtflow.service.api import parse_execute, parse_home, parse_plan, parse_recover, parse_stop
from pvtflow.service.config import CellConfig, load_cell_config
from pvtflow.service.motion import MotionService

CELLS = sorted(p.stem for p in (CONFIGS / "cells").glob("*.yaml"))  # every cell the project ships
STOP_AFTER_MS = 300.0  # program time at which the motion is interrupted (every tour lasts longer)


def cell_file(name: str) -> CellConfig:
    """The shipped cell; an axis that homes powers up near its home (a short homing: not what is tested)."""
    cell = on_own_channel(load_cell_config(CONFIGS / "cells" / f"{name}.yaml"))
    axes = tuple(
        dataclasses.replace(a, simulation=dataclasses.replace(a.simulation, power_up_qc=a.homing.offset_qc))
        if a.homing is not None and a.simulation is not None
        else a
        for a in cell.axes
    )
    return dataclasses.replace(cell, axes=axes)


def tour(cell: CellConfig, fractions: list[float]) -> list[list[float]]:
    """Waypoints at these fractions of every joint's range (joint order), from where the axes stand."""
    lim = cell.joint_limits()
    return [[lo + f * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)] for f in fractions]


# On the wall clock only the cells whose drives run their records on their own clocks (EPOS2): a
# fixed-period drive on the wall clock takes one setpoint per SYNC at its arrival, and the master,
# the simulated wire and three simulated drives in one interpreter on a shared 2-core host miss
# 2-3 ms setpoint deadlines by more than a period now and then (the drives then fault, as they
# must). What fixed-period drives do on the wall clock is tested in tests/axes/sim/test_drive_clock.py,
# measured with the master alone in bench/realtime.py (bench/RESULTS.md).
OWN_CLOCK_CELLS = ("arm6", "gantry3")
CASES = [(c, True) for c in CELLS] + [(c, False) for c in CELLS if c in OWN_CLOCK_CELLS]


@pytest.fixture(params=CASES, ids=[f"{c}-{'lockstep' if lock else 'wall-clock'}" for c, lock in CASES])
def service(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[MotionService]:
    name, lockstep = request.param
    cell = cell_file(name)
    if not lockstep:
        # the drives share the master's interpreter here (the test reads their state), on the wall
        # clock: their heartbeats and the master's wait 10 periods, as the shipped cells did while
        # their drives ran in the master's interpreter (the commands run them in a process of their own)
        cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, heartbeat_timeout_factor=10))
    svc = MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.of(lockstep)).open()
    try:
        if svc.cell.requires_homing:  # incremental encoders: nothing moves before the cell has homed
            assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        yield svc
    finally:
        svc.close()


def plan(svc: MotionService, waypoints: list[list[float]]) -> str:
    req = parse_plan(
        {"waypoints": waypoints, "start": "current", "budget_ms": UNHURRIED_BUDGET_MS},
        svc.cell.joint_names,
        svc.cell.joint_limits(),
    )
    return str(svc.plan(req)["plan_id"])


def start_long_motion(svc: MotionService, fraction: float = 0.85) -> None:
    """A straight move across most of every joint's range, interrupted later at STOP_AFTER_MS."""
    svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [fraction]))}))
    period = svc.cell.bus.sync_period_ms
    progressed = wait_until(lambda: (svc.group.elapsed_syncs() or 0) * period >= STOP_AFTER_MS, timeout=30.0)
    assert progressed, f"the motion did not get {STOP_AFTER_MS} ms far: {svc.motion and svc.motion.outcome}"
    assert svc.running, f"the motion ended before it could be interrupted: {svc.motion and svc.motion.outcome}"


def assert_nothing_left(svc: MotionService) -> None:
    """Every buffer empty, no interpolation running, every demand at rest where the drive says it is."""
    for drive in svc.sim:
        assert not drive.ip_active, f"node {drive.node_id}: interpolation still active"
        if isinstance(drive, Epos2Drive):
            assert drive.level == 0, f"node {drive.node_id}: {drive.level} records left in the FIFO"
        assert drive.demand == round(drive.demand), f"node {drive.node_id}: demand {drive.demand} not on a count"


def move_again(svc: MotionService) -> None:
    """A new motion from where the axes stand runs to its end, with no drive fault."""
    faults_before = {d.node_id: len(d.faults) for d in svc.sim}
    out = svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [0.45])), "wait": True}))
    assert out["outcome"]["result"] == "finished", out["outcome"]["message"]
    assert {d.node_id: len(d.faults) for d in svc.sim} == faults_before
    assert svc.state == "idle"


def test_stop_then_move(service: MotionService) -> None:
    """The quick stop (every axis halted at once, off the path); the path stop: test_path_stop_served.py."""
    start_long_motion(service)
    reply = service.stop(parse_stop({"mode": "quick"}))
    assert reply["was_moving"] and reply["outcome"]["result"] == "stopped"
    assert_nothing_left(service)
    move_again(service)
    assert service.sim.internal_errors == []


def test_stop_twice_then_move(service: MotionService) -> None:
    """Stops in a row (the second motion stopped too) leave nothing behind either."""
    for fraction in (0.85, 0.1):
        start_long_motion(service, fraction)
        assert service.stop(parse_stop({"mode": "quick"}))["outcome"]["result"] == "stopped"
        assert_nothing_left(service)
    move_again(service)


def test_fault_recover_then_move(service: MotionService) -> None:
    start_long_motion(service)
    faulty = next(iter(service.sim))
    faulty.inject_emcy(0x2310)  # an overcurrent, in the middle of the motion
    motion = service.motion
    assert motion is not None and motion.done.wait(10.0)
    assert motion.outcome is not None and motion.outcome["result"] in ("emcy", "drive_fault")
    assert service.state == "fault"
    assert service.group is not None and service.group.settle(5.0)
    assert_nothing_left(service)
    assert service.recover(parse_recover({}))["ok"]
    assert_nothing_left(service)
    move_again(service)
