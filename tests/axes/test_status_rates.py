"""Status TPDOs every n SYNCs (bus.status_every_syncs): written at configuration, sent by the
simulated drives on every n-th SYNC, and the master runs, halts and counts SYNCs with them."""

from __future__ import annotations

import dataclasses

import can
import numpy as np
from axes_programs import check_limits, program
from axes_rig import with_profiles

from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.axes.master.group.outcome import Result


class StatusCounter:
    """The master's SYNCs and the status TPDO frames (COB-IDs given) it received, per COB-ID."""

    def __init__(self, cobs: set[int]) -> None:
        self.syncs = 0
        self.frames = dict.fromkeys(cobs, 0)

    def seen(self, msg: can.Message) -> None:
        if msg.arbitration_id == SYNC_COB_ID and not msg.is_rx:
            self.syncs += 1
        elif msg.is_rx and msg.arbitration_id in self.frames:
            self.frames[msg.arbitration_id] += 1


def _sent_at_syncs(drive, tpdo: int) -> list[int]:
    """The drive's SYNC count at each frame of its TPDO ``tpdo`` from now on (the drive's account)."""
    at: list[int] = []
    send = drive.pdo._send

    def spy(pdo, data: bytes) -> None:
        if pdo.number == tpdo and not pdo.receive:
            at.append(drive.sync_count)
        send(pdo, data)

    drive.pdo._send = spy
    return at


def _mixed_cell(arm6, every: int):
    cell = with_profiles(
        arm6,
        {
            "joint_1": {"profile": "cia402_ip_linear", "period_ms": 2},
            "joint_2": {"profile": "sync_setpoint", "period_ms": 2},
            "joint_3": {"profile": "parker_slvdn", "period_ms": 2, "interpolation_submode": 0},
            "joint_4": {"profile": "epos2_pvt"},
        },
        sync_period_ms=2.0,
    )
    return dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, time_stamp=False, status_every_syncs=every))


def test_status_every_third_sync_runs_a_program_exactly(arm6, make_rig):
    """Fixed-period axes and an EPOS2, status TPDOs of type 3: each drive holds type 3 after
    configuration, answers one SYNC in three, and the program runs to its end as with type 1."""
    cell = _mixed_cell(arm6, 3)
    rig = make_rig(cell)
    rig.group.configure()
    for link, profile in zip(rig.group.links, rig.group.profiles, strict=True):
        assert link.read(0x1800 + profile.sync_tpdo - 1, 2, "B") == 3
        assert rig.sim.drive(link.node_id).pdo.tpdos[profile.sync_tpdo].transmission_type == 3
    cobs = {p.sync_answer_cob_id for p in rig.group.profiles}
    counter = StatusCounter(cobs)
    rig.bus.recorder.taps.append(counter.seen)
    sent = {p.link.node_id: _sent_at_syncs(rig.sim.drive(p.link.node_id), p.sync_tpdo) for p in rig.group.profiles}
    prog = program(cell.ordered_axes(), 300, fraction=0.4)
    check_limits(prog)
    result = rig.group.run(prog, timeout_s=30)
    assert result.result is Result.FINISHED, result.message
    # the master sees ip mode when a status answers: within the n - 1 SYNCs a status is late at most
    assert result.start_skew_syncs is not None and result.start_skew_syncs <= 2
    for axis in prog.axes:  # every drive started on the start SYNC and ran the program exactly
        drive = rig.sim.drive(axis.node_id)
        assert drive.faults == [] and drive.ip_active_sync == result.start_sync
        assert drive.actual == axis.records[-1, 0]
        samples = [s for s in drive.history if s.sync >= result.start_sync]
        t = np.array([(s.sync - result.start_sync) * cell.bus.sync_period_ms for s in samples])
        demand = np.array([s.demand for s in samples])
        np.testing.assert_allclose(demand, axis.reconstruction().position(t), atol=1e-6, err_msg=axis.joint)
    assert rig.sim.internal_errors == []
    # each drive answered one SYNC in three, on its own every third SYNC, and the master heard them all
    assert counter.syncs > 150
    for node, at in sent.items():
        assert set(np.diff(at)) == {3}, (node, at[:10])
    for cob, frames in counter.frames.items():
        assert abs(frames - counter.syncs / 3) <= 1, (hex(cob), frames, counter.syncs)
    assert result.end_sync is not None and result.end_sync >= result.start_sync + 150  # 300 ms at 2 ms


def test_a_stop_halts_every_axis_with_status_every_fourth_sync(arm6, make_rig):
    cell = _mixed_cell(arm6, 4)
    rig = make_rig(cell)
    prog = program(cell.ordered_axes(), 2000, fraction=0.4)
    assert rig.group.start(prog) is None
    assert rig.sim.drive(1).wait_sync(rig.bus.sync.count + 60)
    rig.group.stop("operator")
    result = rig.group.wait(timeout_s=30)
    assert result.result is Result.STOPPED and result.message == "operator"
    assert result.halt_latency_syncs == 1
    for link, profile in zip(rig.group.links, rig.group.profiles, strict=True):
        drive = rig.sim.drive(link.node_id)
        assert drive.faults == []
        if profile.ramps_by_itself:
            assert drive.halts  # the halt bit: its own ramp
        else:
            assert drive.halts == [] and drive.velocity == 0.0  # the master's braking setpoints, then at rest
