"""Simulated EPOS2 in interpolated position mode, driven by a plain canopen master."""

from __future__ import annotations

import numpy as np
import pytest
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.interpolation import epos2_pvt
from pvtflow.axes.drive.objects import EPOS2_RPDOS, EPOS2_TPDOS, BufferStatus, Record
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.sim import Epos2Drive

from .conftest import Bench, configure_pdos, enable

SCALING = AxisScaling(2000.0, 1.0)  # 2000 qc per motor revolution
LIMITS = DriveLimits(8000, 2_000_000, -1_000_000, 1_000_000, 4000, 400_000)
FACTOR = SCALING.qc_per_ms_per_velocity_unit  # qc/ms per rpm

# a smooth move: start point (dwell 3 ms), four segments, rest, end marker
PROGRAM = np.array(
    [
        [0, 0, 3],
        [400, 600, 10],
        [2400, 1200, 15],
        [5000, 600, 17],
        [6000, 0, 12],
        [6000, 0, 0],
    ]
)


def make(bench: Bench, node_id: int, **kw) -> tuple[Epos2Drive, object]:
    drive = bench.add(Epos2Drive(node_id, scaling=SCALING, limits=kw.pop("limits", LIMITS), **kw))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    return drive, node


def push(node, records) -> None:
    for p, v, t in records:
        node.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw = Record(int(p), int(v), int(t)).pack()


def status(node) -> BufferStatus:
    return BufferStatus(node.sdo[od.EPOS2_INTERPOLATION_BUFFER][1].raw)


def demand_error(drive: Epos2Drive, records, period_ms: float = 1.0) -> float:
    """Largest |demand - epos2_pvt| over the SYNC instants since interpolation started."""
    rec = epos2_pvt(records, FACTOR)
    s0 = drive.ip_active_sync
    samples = [s for s in drive.history if s.sync >= s0]
    t = np.array([(s.sync - s0) * period_ms for s in samples])
    d = np.array([s.demand for s in samples])
    assert t[-1] >= rec.end_time
    return float(np.max(np.abs(d - rec.position(t))))


def test_fifo_fill_levels_and_warning_bits(bench: Bench) -> None:
    drive, node = make(bench, 21)
    node.sdo[od.EPOS2_INTERPOLATION_BUFFER][2].raw = 3
    node.sdo[od.EPOS2_INTERPOLATION_BUFFER][3].raw = 6
    assert status(node) == BufferStatus.BUFFER_ENABLED | BufferStatus.UNDERFLOW_WARNING
    push(node, [[0, 0, 1]] * 3)
    assert BufferStatus.UNDERFLOW_WARNING in status(node)  # level 3 == 0x20C4:02: reached
    push(node, [[0, 0, 1]])
    assert status(node) == BufferStatus.BUFFER_ENABLED  # level 4: between the levels
    assert node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][2].raw == 60  # free size
    push(node, [[0, 0, 1]] * 2)
    assert BufferStatus.OVERFLOW_WARNING in status(node)  # level 6 == 0x20C4:03
    assert drive.level == 6 and drive.max_level == 6
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 0  # clear + deny access
    assert drive.level == 0 and BufferStatus.BUFFER_ENABLED not in status(node)
    with pytest.raises(SdoAbortedError) as err:
        push(node, [[0, 0, 1]])
    assert err.value.code == 0x08000022
    with pytest.raises(SdoAbortedError):
        node.sdo[od.EPOS2_INTERPOLATION_BUFFER][3].raw = 65


def test_overflow_error_faults_with_emcy(bench: Bench) -> None:
    drive, node = make(bench, 22)
    push(node, [[0, 0, 5]] * 64)
    assert node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][2].raw == 0
    assert drive.state == "OPERATION ENABLED"
    push(node, [[0, 0, 5]])  # the 65th
    assert drive.state == "FAULT"
    emcy = bench.log.wait_for(0x80 + 22)
    assert int.from_bytes(emcy[0].data[:2], "little") == od.EMCY_EPOS2_IPM_ERROR
    assert BufferStatus.OVERFLOW_ERROR in BufferStatus(int.from_bytes(emcy[0].data[3:5], "little"))
    assert BufferStatus.OVERFLOW_ERROR in status(node)
    assert drive.faults[-1].check == "buffer overflow"
    node.sdo[od.CONTROLWORD].raw = 0x0080
    assert BufferStatus.OVERFLOW_ERROR not in status(node)


def test_start_on_the_sync_after_the_synchronous_controlword(bench: Bench) -> None:
    drive, node = make(bench, 23)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational)
    for p, v, t in PROGRAM:  # records through the asynchronous RPDO 1
        bench.send(0x200 + 23, Record(int(p), int(v), int(t)).to_bytes())
    assert drive.wait_until(lambda: drive.level == len(PROGRAM))
    bench.sync(2)
    bench.send(0x300 + 23, (0x001F).to_bytes(2, "little"))  # synchronous RPDO 2
    assert not drive.wait_until(lambda: drive.ip_active, timeout=0.05)  # nothing before the SYNC
    start = bench.sync(1)
    assert drive.ip_active and drive.ip_active_sync == start
    bench.sync(70)
    assert drive.faults == []
    assert not drive.ip_active and drive.ended_by_time_zero == 1
    assert demand_error(drive, PROGRAM) < 1e-6
    assert drive.statusword() & (1 << 10)  # target reached after the time-0 end
    # the synchronous TPDO 2 carried statusword + position actual at every SYNC
    tpdo2 = bench.log.wait_for(0x280 + 23, 73)
    assert len(tpdo2) == 73  # one per SYNC since the node became operational
    assert int.from_bytes(tpdo2[-1].data[2:6], "little", signed=True) == 6000
    # the event TPDO 1 reported the buffer status changes (ip mode active, then inactive)
    seen = [BufferStatus(int.from_bytes(m.data[:2], "little")) for m in bench.log.of(0x180 + 23)]
    assert any(BufferStatus.IP_MODE_ACTIVE in s for s in seen)
    assert BufferStatus.IP_MODE_ACTIVE not in seen[-1]


@pytest.mark.parametrize("sync_ms", [0.5, 1.0, 4.0])
def test_demand_equals_epos2_pvt_at_every_sync(bench: Bench, sync_ms: float) -> None:
    drive, node = make(bench, 24, sync_period_ms=sync_ms)
    bench.sync(3)
    with pytest.raises(SdoAbortedError):  # 0x20C1 is write-only
        _ = node.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw
    push(node, PROGRAM)
    node.sdo[od.CONTROLWORD].raw = 0x001F  # by SDO: starts at the next SYNC
    bench.sync(int(70 / sync_ms))
    assert drive.ip_active_sync == 4  # t = 0 at 1.5 ms of the motion clock when the SYNC is 0.5 ms
    assert drive.faults == [] and drive.ended_by_time_zero == 1
    assert demand_error(drive, PROGRAM, sync_ms) < 1e-6
    assert drive.min_level_active == 0


def test_underflow_when_a_segment_ends_with_an_empty_fifo(bench: Bench) -> None:
    drive, node = make(bench, 25)
    push(node, PROGRAM[:3])  # no more records: the third segment has no successor
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(40)
    assert drive.state == "FAULT" and not drive.ip_active
    assert drive.faults[0].check == "buffer underflow"
    assert drive.faults[0].sync == 1 + 3 + 10 + 15  # at the end of the last segment
    assert BufferStatus.UNDERFLOW_ERROR in status(node)
    assert drive.statusword() & 0x4F == 0x08


def test_underflow_when_started_with_fewer_than_two_records(bench: Bench) -> None:
    drive, node = make(bench, 26)
    push(node, PROGRAM[:1])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    assert drive.state == "FAULT" and drive.faults[0].check.startswith("buffer underflow at start")


def test_time_zero_record_ends_without_error(bench: Bench) -> None:
    drive, node = make(bench, 27)
    push(node, [[0, 0, 2], [100, 0, 10], [100, 0, 0], [900, 0, 10]])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(30)
    assert drive.state == "OPERATION ENABLED" and drive.faults == []
    assert not drive.ip_active and drive.demand == 100.0
    assert drive.level == 1  # what follows the end marker stays for the next start
    assert node.sdo[od.STATUSWORD].raw & (1 << 12) == 0


def velocity_program(peak_rpm: float) -> np.ndarray:
    """Rest to rest over 40 ms through a mid point at ``peak_rpm``."""
    mid_v = peak_rpm
    dist = int(mid_v * FACTOR * 20 * 0.75)
    return np.array([[0, 0, 1], [dist, int(mid_v), 20], [2 * dist, 0, 20], [2 * dist, 0, 0]])


@pytest.mark.parametrize(("peak_rpm", "faults"), [(2500, False), (3500, True)])
def test_velocity_objects_are_in_the_drives_velocity_unit(bench: Bench, peak_rpm: float, faults: bool) -> None:
    """With a velocity unit of 0.1 rpm, 0x607F is commissioned and judged in 0.1 rpm, as the master
    writes it: 3000 rpm is 30000 units, and a move at 2500 rpm (its record velocities in 0.1 rpm) runs."""
    scaling = AxisScaling(2000.0, 1.0, velocity_unit_rpm=0.1)
    drive = bench.add(Epos2Drive(30, scaling=scaling, limits=DriveLimits(3000, 10**6, -(10**7), 10**7)))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    assert drive.read(od.MAX_PROFILE_VELOCITY) == 30000
    dist = int(peak_rpm * FACTOR * 20 * 0.75)  # FACTOR: qc/ms per rpm
    push(node, [[0, 0, 1], [dist, int(peak_rpm / 0.1), 20], [2 * dist, 0, 20], [2 * dist, 0, 0]])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(50)
    assert (drive.state == "FAULT") is faults
    assert [f.check for f in drive.faults] == (["max profile velocity 0x607F"] if faults else [])


def test_velocity_and_acceleration_errors_fault_the_drive(bench: Bench) -> None:
    limits = DriveLimits(3000, 10**6, -(10**7), 10**7)
    drive, node = make(bench, 28, limits=limits)
    push(node, velocity_program(3500))
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(50)
    assert drive.state == "FAULT"
    assert drive.faults[0].check == "max profile velocity 0x607F"
    assert BufferStatus.VELOCITY_ERROR in status(node)
    emcy = bench.log.wait_for(0x80 + 28)[0]
    assert BufferStatus.VELOCITY_ERROR in BufferStatus(int.from_bytes(emcy.data[3:5], "little"))
    # and the acceleration limit: the same move within 0x607F but above 0x60C5
    node.sdo[od.CONTROLWORD].raw = 0x0080
    assert BufferStatus.VELOCITY_ERROR not in status(node)
    node.sdo[od.MAX_ACCELERATION].raw = 50000
    node.sdo[od.MAX_PROFILE_VELOCITY].raw = 10000
    for cw in (0x0006, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    start = drive.demand
    program = velocity_program(3500)
    program[:, 0] += round(start)
    push(node, program)
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(50)
    assert drive.faults[-1].check == "max acceleration 0x60C5"
    assert BufferStatus.ACCELERATION_ERROR in status(node)


def test_violation_between_syncs_is_caught_by_the_1khz_samples(bench: Bench) -> None:
    """With a 10 ms SYNC the peak velocity (at 20.x ms) falls between SYNCs: the 1 ms samples see it."""
    limits = DriveLimits(3000, 10**6, -(10**7), 10**7)
    drive, node = make(bench, 29, limits=limits, sync_period_ms=10.0)
    push(node, velocity_program(3200))
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(6)
    assert drive.state == "FAULT" and drive.faults[0].check == "max profile velocity 0x607F"
    assert drive.faults[0].time_ms % 10 != 0  # found between two SYNC instants


def test_profile_velocity_and_acceleration_only_warn(bench: Bench) -> None:
    limits = DriveLimits(5000, 10**6, -(10**7), 10**7, profile_velocity_rpm=1000, profile_acceleration_rpm_s=1000)
    drive, node = make(bench, 30, limits=limits)
    push(node, velocity_program(2000))
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(50)
    assert drive.faults == [] and drive.ended_by_time_zero == 1
    s = status(node)
    assert BufferStatus.VELOCITY_WARNING in s and BufferStatus.ACCELERATION_WARNING in s
    assert not s & od.BUFFER_ERRORS
    assert node.sdo[od.STATUSWORD].raw & (1 << 7)  # warning bit


def test_software_position_limit_faults(bench: Bench) -> None:
    limits = DriveLimits(5000, 10**6, -1000, 1000)
    drive, node = make(bench, 31, limits=limits)
    push(node, [[0, 0, 1], [2000, 0, 20], [2000, 0, 0]])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(25)
    assert drive.state == "FAULT" and drive.faults[0].code == od.EMCY_SOFTWARE_POSITION_LIMIT
    assert abs(drive.demand) <= 1000  # the demand outside was not taken


def test_halt_brakes_to_standstill(bench: Bench) -> None:
    drive, node = make(bench, 32)
    node.sdo[od.PROFILE_DECELERATION].raw = 20000  # rpm/s
    push(node, [[0, 0, 1], [3000, 1500, 30], [6000, 1500, 30], [9000, 0, 30], [9000, 0, 0]])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(35)
    v0 = drive.velocity
    assert v0 > 0
    node.sdo[od.CONTROLWORD].raw = 0x011F  # halt
    assert not drive.ip_active
    assert node.sdo[od.STATUSWORD].raw & (1 << 10) == 0  # braking
    stop_ms = v0 / SCALING.rpm_s_to_qc_per_ms2(20000)
    bench.sync(int(stop_ms) + 2)
    assert drive.velocity == 0.0 and drive.faults == []
    assert node.sdo[od.STATUSWORD].raw & (1 << 10)  # halted: velocity 0
    assert drive.demand == pytest.approx(drive.history[-1].demand)


def test_time_stamps_are_kept(bench: Bench) -> None:
    drive, node = make(bench, 33)
    for us in (1000, 2001, 3002):
        node.sdo[od.HIGH_RESOLUTION_TIME_STAMP].raw = us
    assert list(drive.time_stamps) == [1000, 2001, 3002]


def test_quick_stop_brakes_with_0x6085_then_switches_on_disabled(bench: Bench) -> None:
    drive, node = make(bench, 34)
    node.sdo[0x6085].raw = 50000  # quick stop deceleration, rpm/s
    node.sdo[od.PROFILE_DECELERATION].raw = 1000  # profile deceleration: not the one used
    push(node, [[0, 0, 1], [3000, 1500, 30], [6000, 1500, 30], [9000, 0, 30], [9000, 0, 0]])
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(35)
    v0 = drive.velocity
    node.sdo[od.CONTROLWORD].raw = 0x000B  # quick stop
    assert drive.state == "QUICK STOP ACTIVE" and node.sdo[od.STATUSWORD].raw & 0x6F == 0x07
    stop_ms = v0 / SCALING.rpm_s_to_qc_per_ms2(50000)
    bench.sync(int(stop_ms) + 2)
    assert drive.state == "SWITCH ON DISABLED" and drive.faults == []
    travelled = drive.demand - drive.history[-int(stop_ms) - 3].demand
    assert travelled == pytest.approx(v0 * stop_ms / 2, rel=0.05)


def test_nmt_stopped_drive_ignores_pdos(bench: Bench) -> None:
    drive, node = make(bench, 35)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    node.nmt.state = "OPERATIONAL"
    node.nmt.state = "STOPPED"
    assert drive.wait_until(lambda: drive.nmt_state == "STOPPED")
    bench.send(0x200 + 35, Record(0, 0, 1).to_bytes())
    bench.sync(3)
    assert drive.level == 0 and bench.log.of(0x280 + 35) == []
