"""A program queued on a running run goes on where the running one ends, on the same SYNC time line:
no halt, no restart, no SYNC period of standstill beyond the programs' own (issue 38 item 5)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
from axes_programs import program, standstill_syncs
from axes_rig import with_profiles

from pvtflow.axes.drive.program import AxisProgram, PvtProgram, joined
from pvtflow.axes.master.group.outcome import GroupError, Result
from pvtflow.axes.master.run_queue import end_hold_ms


def mixed_cell(arm6):
    """Every fixed-period behaviour and an EPOS2 on one bus (tests/axes/test_group_fixed_period.py)."""
    cell = with_profiles(
        arm6,
        {
            "joint_1": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_2": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_3": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_4": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_5": {"profile": "parker_slvdn", "period_ms": 2, "interpolation_submode": 0},
            "joint_6": {"profile": "epos2_pvt"},
        },
        sync_period_ms=2.0,
    )
    return dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, time_stamp=False))


def two_programs(rig, duration_ms: int = 1500) -> tuple[PvtProgram, PvtProgram]:
    axes = rig.cell.ordered_axes()
    rig.group.refresh()
    here = [lk.position for lk in rig.group.links]
    first = program(axes, duration_ms, starts=here, fraction=0.4, spacing_ms=rig.cell.bus.sync_period_ms)
    ends = [int(a.records[-1, 0]) for a in first.axes]
    then = program(axes, duration_ms, starts=ends, fraction=0.4, spacing_ms=rig.cell.bus.sync_period_ms, sign=-1)
    return first, then


def demands(rig, start_sync: int, end_sync: int) -> np.ndarray:
    per_axis = []
    for axis in rig.cell.ordered_axes():
        samples = {s.sync: s.demand for s in rig.sim.drive(axis.node_id).history}
        per_axis.append([samples[n] for n in range(start_sync, end_sync + 1)])
    return np.array(per_axis).T


@pytest.mark.parametrize("cell_name", ["arm6", "mixed"])
def test_a_queued_program_runs_on_from_the_end_of_the_running_one(arm6, make_rig, cell_name):
    """arm6 (six EPOS2, records in their FIFO) and a cell of every fixed-period behaviour beside an EPOS2:
    the queued program is told on in one run; each drive took both programs' records as one (one time-0
    end), interpolated without a restart from the start SYNC to the end, its demand the joined programs'
    reconstruction at every SYNC, so the axes stood still between them exactly as long as the joined
    programs say (the same number of SYNC periods), and the queued program's start was announced once
    on the SYNC where its t = 0 is."""
    cell = arm6 if cell_name == "arm6" else mixed_cell(arm6)
    rig = make_rig(cell)
    first, then = two_programs(rig)
    started: list[int] = []
    assert rig.group.start(first) is None
    entry = rig.group.append(then, started.append)
    result = rig.group.wait(timeout_s=60)
    assert result.result is Result.FINISHED, result.message
    period = cell.bus.sync_period_ms
    assert entry.start_ms == first.duration_ms
    assert started == [entry.start_syncs] and entry.start_syncs * period >= first.duration_ms
    whole = joined([first, then])
    for axis in whole.axes:
        drive = rig.sim.drive(axis.node_id)
        assert drive.faults == [], drive.faults
        assert drive.ip_active_sync == result.start_sync  # started once, never again
        assert drive.actual == axis.records[-1, 0]
        if axis.profile == "epos2_pvt":
            taken = np.array([[r.position, r.velocity, r.time] for r in drive.records_consumed])
            np.testing.assert_array_equal(taken, axis.records)
            assert drive.ended_by_time_zero == 1
        samples = [s for s in drive.history if s.sync >= result.start_sync]
        assert all(s.ip_active for s in samples if (s.sync - result.start_sync) * period < whole.duration_ms - period)
        t = np.array([(s.sync - result.start_sync) * period for s in samples])
        np.testing.assert_allclose([s.demand for s in samples], axis.reconstruction().position(t), atol=1e-6)
    # no SYNC period of standstill beyond the programs' own
    end_sync = result.start_sync + int(np.ceil(whole.duration_ms / period))
    t = (np.arange(result.start_sync, end_sync + 1) - result.start_sync) * period
    planned = np.array([a.reconstruction().position(t) for a in whole.axes]).T
    assert standstill_syncs(demands(rig, result.start_sync, end_sync)) == standstill_syncs(planned)
    assert rig.sim.internal_errors == []


def test_a_queued_program_that_does_not_start_where_the_running_one_ends_is_refused(arm6, make_rig):
    """Refused with the axis and both positions; the run goes on and ends as if nothing was asked."""
    rig = make_rig(arm6)
    first, then = two_programs(rig)
    wrong = PvtProgram(
        then.cell,
        tuple(
            AxisProgram.of(a, a.records + np.array([[1000, 0, 0]])) if i == 2 else a for i, a in enumerate(then.axes)
        ),
    )
    assert rig.group.start(first) is None
    before = [len(f.records) for f in rig.group.feeders]
    with pytest.raises(GroupError, match=r"axis 3: the queued program starts at .* it must start where that one ends"):
        rig.group.append(wrong)
    assert [len(f.records) for f in rig.group.feeders] == before
    assert rig.group.queue.entries == []
    result = rig.group.wait(timeout_s=60)
    assert result.result is Result.FINISHED, result.message
    for axis in first.axes:
        drive = rig.sim.drive(axis.node_id)
        taken = np.array([[r.position, r.velocity, r.time] for r in drive.records_consumed])
        np.testing.assert_array_equal(taken, axis.records)


def test_a_program_queued_too_late_or_with_nothing_running_is_refused(arm6, make_rig):
    rig = make_rig(arm6)
    first, then = two_programs(rig)
    with pytest.raises(GroupError, match="no program runs"):
        rig.group.append(then)
    assert rig.group.start(first) is None
    period = arm6.bus.sync_period_ms
    late = first.duration_ms - end_hold_ms(arm6.bus)
    while (rig.group.elapsed_syncs() or 0) * period < late and rig.group.running:
        time.sleep(0.001)
    with pytest.raises(GroupError, match="queued at least"):
        rig.group.append(then)
    assert rig.group.wait(timeout_s=60).result is Result.FINISHED


def test_stop_ends_the_running_and_the_queued_program(arm6, make_rig):
    rig = make_rig(arm6)
    first, then = two_programs(rig, duration_ms=2000)
    started: list[int] = []
    assert rig.group.start(first) is None
    rig.group.append(then, started.append)
    rig.group.stop("enough")
    result = rig.group.wait(timeout_s=60)
    assert result.result is Result.STOPPED
    assert started == []  # the queued program never began
    for drive in rig.sim:
        assert drive.halts and not drive.ip_active and drive.faults == []
