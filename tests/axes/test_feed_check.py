"""A program whose records the bus cannot feed as fast as the drives run them is refused before
anything moves (axes/master/feed_check.py), naming the axis, its records' time and the bus's allowance."""

from __future__ import annotations

import dataclasses

from axes_programs import axis_program, program

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.feed_check import BufferedAxis, feed_shortfall
from pvtflow.axes.master.group.outcome import Result


def _axis(arm6, spacing_ms: int, duration_ms: int = 2000) -> BufferedAxis:
    a = arm6.axes[0]
    return BufferedAxis(a.joint, axis_program(a, 0, 20000, duration_ms, spacing_ms).records, BufferConfig())


def test_records_shorter_than_the_allowance_lasts_run_the_buffer_dry(arm6):
    """2 ms records at a 5 ms SYNC: 2.5 records a period; an allowance of 2 loses half a record a period."""
    message = feed_shortfall([_axis(arm6, 2)], per_sync=2, period_ms=5.0)
    assert message is not None
    assert message.startswith(f"axis {arm6.axes[0].joint}: its records last 2 ms on average")
    assert "the bus feeds 2 record(s) per 5 ms SYNC period shared by 1 EPOS2 axis" in message
    assert "bus.records_per_sync" in message
    # three a period keep up: the preload and the FIFO carry the rest
    assert feed_shortfall([_axis(arm6, 2)], per_sync=3, period_ms=5.0) is None


def test_a_short_burst_of_short_records_rides_on_the_fifo(arm6):
    """Twenty 1 ms records after 400 ms of 10 ms records: the level the FIFO built up carries them;
    forty of them right after the preload are more than it holds by then."""
    axis = _axis(arm6, 10)
    late, early = axis.records.copy(), axis.records.copy()
    late[40:60, 2] = 1
    early[10:50, 2] = 1
    assert feed_shortfall([dataclasses.replace(axis, records=late)], per_sync=1, period_ms=5.0) is None
    assert feed_shortfall([dataclasses.replace(axis, records=early)], per_sync=1, period_ms=5.0) is not None


def test_the_allowance_is_shared_by_the_buffered_axes(arm6):
    """Six axes of 5 ms records at a 5 ms SYNC need six records a period: five is short for one of them."""
    axes = [dataclasses.replace(_axis(arm6, 5), name=f"j{i}") for i in range(6)]
    assert feed_shortfall(axes, per_sync=6, period_ms=5.0) is None
    message = feed_shortfall(axes, per_sync=5, period_ms=5.0)
    assert message is not None and "shared by 6 EPOS2 axis/axes (a record per 6 ms each)" in message


def test_the_group_refuses_such_a_program_before_anything_moves(arm6, make_rig):
    """arm6 feeds 8 records per 5 ms SYNC period to six EPOS2 axes; 2 ms records need 15."""
    rig = make_rig(arm6)
    rig.group.configure()
    rig.group.refresh()
    axes = arm6.ordered_axes()
    starts = [int(lk.position or 0) for lk in rig.group.links]
    dense = program(axes, 600, starts=starts, spacing_ms=2)
    before = [rig.sim.drive(a.node_id).actual for a in axes]
    syncs = rig.bus.sync.count
    result = rig.group.run(dense, timeout_s=30)
    assert result.result is Result.REJECTED
    assert result.message.startswith(f"axis {axes[0].joint}: its records last 2 ms on average")
    assert f"{rig.group.allowance.per_sync} record(s) per 5 ms SYNC period shared by 6 EPOS2" in result.message
    assert rig.bus.sync.count == syncs and [rig.sim.drive(a.node_id).actual for a in axes] == before
    assert all(not rig.sim.drive(a.node_id).ip_active for a in axes)
    # the same path at 5 ms records runs
    fine = PvtProgram(dense.cell, tuple(program(axes, 600, starts=starts, spacing_ms=5).axes))
    assert rig.group.run(fine, timeout_s=60).ok
