"""Drives without a ramp of their own (bufferless servodrive, Parker below 2.5 ms) are stopped by the
master's braking setpoints within 0x60C5, and the simulated drives judge those setpoints as they judge
a motion: a stop that is too abrupt faults them."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest
from axes_programs import axis_program, safe_distance

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Statusword
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.drive.stop_ramp import braking_positions
from pvtflow.axes.master.group.outcome import Result
from pvtflow.service.config import load_cell_config

CELLS = Path(__file__).resolve().parents[2] / "configs" / "cells"
HALT_AT_SYNC = 150  # SYNCs after the start: the axes are at speed (program of 400 ms)
EMCY_TEMPERATURE = 0x4210  # CiA 301: excess temperature, device (an EMCY that does not fault the drive)


def gantry(name: str):
    cell = load_cell_config(CELLS / f"{name}.yaml")
    if name == "gantry3-parker":  # its direct loop: a cycle below 2.5 ms
        axes = tuple(dataclasses.replace(a, period_ms=2) for a in cell.axes)
        cell = dataclasses.replace(cell, axes=axes, bus=dataclasses.replace(cell.bus, sync_period_ms=2.0))
    return cell


def inside_travel(cell, duration_ms: int = 400) -> PvtProgram:
    """Every axis from 0 (where its encoder counts from) into its travel, at 0.6 of its limits."""
    axes = []
    for a in cell.ordered_axes():
        sign = 1 if a.limits.max_position_qc > 0 else -1
        axes.append(axis_program(a, 0, sign * safe_distance(a, duration_ms, 0.6), duration_ms))
    return PvtProgram(cell.name, tuple(axes))


def halt_mid_motion(rig, action) -> object:
    """Start the program, call ``action`` once the axes are HALT_AT_SYNC SYNCs in (a thread of the
    test's own: the progress callback runs in the bus's receive thread), return the result."""
    reached = threading.Event()
    rig.group.on_progress = lambda p: reached.set() if p.sync >= HALT_AT_SYNC else None
    rig.group.progress_every = 1
    assert rig.group.start(inside_travel(rig.cell)) is None
    assert reached.wait(30)
    action()
    return rig.group.wait(timeout_s=30)


@pytest.mark.parametrize("name", ["gantry3-sync-setpoint", "gantry3-parker"])
@pytest.mark.parametrize("how", ["stop", "halt"])
def test_stop_and_halt_brake_within_the_limits_and_end_at_rest(make_rig, name, how):
    cell = gantry(name)
    rig = make_rig(cell)
    other = rig.sim.drive(cell.ordered_axes()[0].node_id)
    if how == "stop":
        result = halt_mid_motion(rig, lambda: rig.group.stop("operator"))
        assert result.result is Result.STOPPED, result.message
    else:  # a warning EMCY halts the run (quick: within 0x6085 too); no drive is in fault
        result = halt_mid_motion(rig, lambda: other.inject_emcy(EMCY_TEMPERATURE, fault=False))
        assert result.result is Result.EMCY, result.message
    period = cell.bus.sync_period_ms
    for axis in cell.ordered_axes():
        drive = rig.sim.drive(axis.node_id)
        assert drive.faults == [], drive.faults  # every setpoint judged against 0x607F / 0x60C5: none too abrupt
        assert drive.halts == []  # braked by setpoints, not by the halt bit
        demand = np.array([s.demand for s in drive.history if s.sync >= result.start_sync])
        steps = np.diff(demand) / period
        amax = float(axis.scaling.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s))
        assert np.abs(steps).max() > 20 * amax * period  # it was at speed: the stop had something to brake
        assert np.all(np.abs(np.diff(steps)) <= amax * period + 2.0 / period + 1e-9)  # 0x60C5, whole counts
        assert steps[-1] == 0.0 and drive.velocity == 0.0  # at rest, holding
        assert drive.statusword() & int(Statusword.TARGET_REACHED)
        assert drive.actual == round(demand[-1])
        target = int(result.axes[cell.ordered_axes().index(axis)].target_position)
        assert abs(drive.actual) < abs(target)  # stopped short of the program's end: stopped, not finished
    assert rig.sim.internal_errors == []


@pytest.mark.parametrize("name", ["gantry3-sync-setpoint", "gantry3-parker"])
def test_setpoints_frozen_at_speed_fault_the_drive(make_rig, name):
    """A master that stops feeding a drive without a ramp (no halt bit, no ramp: the old way) asks its
    loop for the whole velocity change in one period: the simulated drive faults on 0x60C5."""
    cell = gantry(name)
    rig = make_rig(cell)
    node = cell.ordered_axes()[0].node_id

    def freeze() -> None:
        with rig.bus.sync.lock:
            rig.group.feeders[0].enabled = False

    result = halt_mid_motion(rig, freeze)
    assert result.result in (Result.EMCY, Result.DRIVE_FAULT) and result.node_id == cell.ordered_axes()[0].node_id
    drive = rig.sim.drive(node)
    assert [f.check for f in drive.faults] == ["max acceleration 0x60C5"]
    assert drive.emcy.sent[-1][0] == od.EMCY_VELOCITY_LIMIT


@pytest.mark.parametrize("name", ["gantry3-sync-setpoint", "gantry3-parker"])
def test_a_setpoint_jump_faults_the_drive(make_rig, name):
    """The rest of the stream 40 counts further on (within 0x607F) is a velocity
    change no drive makes in one period: 0x60C5."""
    cell = gantry(name)
    rig = make_rig(cell)
    feeder_box = {}

    def jump() -> None:
        with rig.bus.sync.lock:
            feeder = rig.group.feeders[0]
            feeder_box["at"] = feeder.next
            rows = feeder.records[feeder.next :].copy()
            rows[:, 0] += 40
            feeder.decelerate(rows)  # the rest of the program, 40 qc further on: one step of 40 qc more

    result = halt_mid_motion(rig, jump)
    assert result.result in (Result.EMCY, Result.DRIVE_FAULT) and result.node_id == cell.ordered_axes()[0].node_id
    drive = rig.sim.drive(cell.ordered_axes()[0].node_id)
    assert [f.check for f in drive.faults] == ["max acceleration 0x60C5"]


def test_braking_positions_stop_on_a_whole_count_within_the_deceleration():
    period, a = 2.0, 0.05  # qc/ms^2
    positions = braking_positions(1000, 960, period, a)  # 20 qc/ms
    path = np.concatenate(([960, 1000], positions, [positions[-1]]))
    v = np.diff(path) / period
    assert np.all(np.abs(np.diff(v)) <= a * period + 2.0 / period)
    assert positions[-1] == np.ceil(1000 + 20.0**2 / (2 * a))  # the first whole count at or past the natural stop
    assert np.all(np.diff(positions) >= 0)  # never backwards
    assert braking_positions(1000, 1000, period, a).size == 0  # at rest: nothing to brake
