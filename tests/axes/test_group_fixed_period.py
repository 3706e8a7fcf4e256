"""The three fixed-period behaviours run programs: one setpoint per SYNC, sent ahead by the drive's delay."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
from axes_programs import check_limits, program
from axes_rig import with_profiles

from pvtflow.axes.drive import objects as od
from pvtflow.axes.master.group.outcome import Result


def run_and_check(rig, duration_ms: int = 300):
    axes = rig.cell.ordered_axes()
    prog = program(axes, duration_ms, fraction=0.4)
    check_limits(prog)
    result = rig.group.run(prog, timeout_s=30)
    assert result.result is Result.FINISHED, result.message
    assert result.start_skew_syncs == 0
    period = rig.cell.bus.sync_period_ms
    for axis in prog.axes:
        drive = rig.sim.drive(axis.node_id)
        assert drive.faults == [], drive.faults
        assert drive.actual == axis.records[-1, 0]
        assert drive.ip_active_sync == result.start_sync
        # on the program's timeline the drive's demand is the program's reconstruction
        rec = axis.reconstruction()
        samples = [s for s in drive.history if s.sync >= result.start_sync]
        t = np.array([(s.sync - result.start_sync) * period for s in samples])
        demand = np.array([s.demand for s in samples])
        np.testing.assert_allclose(demand, rec.position(t), atol=1e-6, err_msg=f"{axis.joint} {axis.profile}")
    assert rig.sim.internal_errors == []
    return result


def test_cia402_linear_sync_setpoint_and_parker_direct_at_2ms(arm6, make_rig):
    """Five fixed-period axes and an EPOS2 at the shortest SYNC period whose frames fit the 1 Mbit/s
    wire in every period (at 1 ms they take about 1.9 periods: the wire queues them, as a real one does);
    the Parker still in its direct loop (below 2.5 ms)."""
    cell = with_profiles(
        arm6,
        {
            "joint_1": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_2": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_3": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_4": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_5": {"profile": "parker_slvdn", "period_ms": 2, "interpolation_submode": 0},  # direct loop
            "joint_6": {"profile": "epos2_pvt"},
        },
        sync_period_ms=2.0,
    )
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, time_stamp=False))
    rig = make_rig(cell)
    run_and_check(rig)


@pytest.mark.parametrize("submode", [0, -1, -2])
def test_parker_interpolated_at_4ms(arm6, make_rig, submode):
    fixed = {"period_ms": 4}
    cell = with_profiles(
        arm6,
        {
            "joint_1": {"profile": "parker_slvdn", "interpolation_submode": submode, **fixed},
            "joint_2": {"profile": "parker_slvdn", "interpolation_submode": submode, **fixed},
            "joint_3": {"profile": "sync_setpoint", **fixed},
            "joint_4": {"profile": "cia402_ip_linear", **fixed},
            "joint_5": {"profile": "epos2_pvt"},
            "joint_6": {"profile": "epos2_pvt"},
        },
        sync_period_ms=4.0,
    )
    rig = make_rig(cell)
    run_and_check(rig, duration_ms=400)


def test_fixed_period_halt_on_stop(arm6, make_rig):
    cell = with_profiles(
        arm6,
        {
            "joint_1": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_2": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_3": {"profile": "parker_slvdn", "period_ms": 2, "interpolation_submode": -1},
        },
        sync_period_ms=2.0,
    )
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, time_stamp=False))
    rig = make_rig(cell)
    prog = program(cell.ordered_axes(), 2000, fraction=0.4)
    at_speed = threading.Event()
    rig.group.on_progress = lambda p: at_speed.set() if p.sync >= 100 else None
    assert rig.group.start(prog) is None
    assert at_speed.wait(30)
    rig.group.stop("operator")
    result = rig.group.wait(timeout_s=30)
    assert result.result is Result.STOPPED and result.message == "operator"
    assert result.halt_latency_syncs == 1
    for drive in rig.sim:
        assert drive.faults == []
        # the drives that ramp by themselves get the halt bit; the bufferless one and the Parker in its
        # direct loop (2 ms) have no ramp: the master brakes them with setpoints (tests/axes/test_stop_ramp.py)
        assert bool(drive.halts) == (drive.PROFILE in ("cia402_ip_linear", "epos2_pvt"))


def test_the_first_setpoint_is_primed_with_the_actual_position(arm6, make_rig):
    """The Parker below 2.5 ms latches 0x60C1:01 as it stands at the start SYNC (nothing is sent
    before it, lead 0): whatever an earlier master, a stop or a tool left there. The master primes it
    with the actual position when it enables, so the program starts where the axis stands."""
    cell = with_profiles(
        arm6,
        {"joint_1": {"profile": "parker_slvdn", "period_ms": 1, "interpolation_submode": -1}},
        sync_period_ms=1.0,
    )
    rig = make_rig(cell)
    drive = rig.sim.drive(1)
    drive.store(od.INTERPOLATION_DATA_RECORD, 1, drive.actual + 40000)  # left by an earlier master
    result = rig.group.run(program(cell.ordered_axes(), 300, fraction=0.1), timeout_s=30)
    assert result.ok, result.message
    assert drive.faults == []
    assert drive.first_setpoint_sync is not None
