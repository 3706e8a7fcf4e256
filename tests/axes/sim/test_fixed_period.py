"""The fixed-period simulated drives: delays and interpolation against axes/drive/interpolation.py."""

from __future__ import annotations

import numpy as np
import pytest
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.interpolation import PiecewiseCubic, cubic_p, cubic_pv, linear
from pvtflow.axes.drive.objects import PARKER_RPDOS, PARKER_TPDOS, SETPOINT_RPDOS, SETPOINT_TPDOS
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.sim import IpLinearDrive, ParkerDrive, SyncSetpointDrive
from pvtflow.axes.sim.drive import SimulatedDrive

from .conftest import Bench, configure_pdos, enable

SCALING = AxisScaling(4096.0, 1.0)
LIMITS = DriveLimits(6000, 10**7, -(10**6), 10**6)
FACTOR = SCALING.qc_per_ms_per_velocity_unit


def program(period_ms: int, n: int = 24, distance: float = 3000.0) -> np.ndarray:
    """A rest-to-rest cosine move sampled once per period: [position_qc, velocity_rpm, period]."""
    k = np.arange(n)
    s = np.pi * k / (n - 1)
    pos = np.round(distance * (1 - np.cos(s)) / 2).astype(np.int64)
    vel_qc_ms = distance * np.sin(s) / 2 * np.pi / ((n - 1) * period_ms)
    vel = np.round(SCALING.qc_per_ms_to_rpm(vel_qc_ms)).astype(np.int64)
    return np.stack([pos, vel, np.full(n, period_ms)], axis=1)


def start_operational(bench: Bench, drive: SimulatedDrive, rpdos, tpdos) -> object:
    node = bench.remote(drive)
    configure_pdos(node, rpdos, tpdos)
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational)
    return node


def stream(bench: Bench, cob_id: int, frames: list[bytes], tail: int = 5) -> None:
    """One setpoint frame before each SYNC (the synchronous RPDO), then a few SYNCs without."""
    for frame in frames:
        bench.send(cob_id, frame)
        bench.sync(1)
    bench.sync(tail)


def demand_error(drive: SimulatedDrive, reconstruction: PiecewiseCubic, t0_sync: int, period_ms: float) -> float:
    samples = [s for s in drive.history if s.sync >= t0_sync]
    t = np.array([(s.sync - t0_sync) * period_ms for s in samples])
    d = np.array([s.demand for s in samples])
    assert t[-1] >= reconstruction.end_time, "the run did not cover the whole reconstruction"
    return float(np.max(np.abs(d - reconstruction.position(t))))


def position_frames(records: np.ndarray) -> list[bytes]:
    return [int(p).to_bytes(4, "little", signed=True) for p in records[:, 0]]


def test_ip_linear_needs_buffer_enable_then_reaches_each_target_one_period_later(bench: Bench) -> None:
    period = 2
    drive = bench.add(IpLinearDrive(41, scaling=SCALING, limits=LIMITS, sync_period_ms=period))
    node = start_operational(bench, drive, SETPOINT_RPDOS, SETPOINT_TPDOS)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = period
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 10
    assert err.value.code == 0x08000022
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    bench.send(0x300 + 41, (0x001F).to_bytes(2, "little"))
    active = bench.sync(1)
    assert drive.ip_active_sync == active and drive.statusword() & (1 << 12)
    records = program(period)
    stream(bench, 0x200 + 41, position_frames(records))
    assert drive.faults == []
    assert drive.delay_periods == 1
    # record k, validated by SYNC first + k, is reached one period later: linear() on the program timeline
    assert demand_error(drive, linear(records, period), drive.first_setpoint_sync, period) < 1e-6
    v0 = drive.first_setpoint_sync
    by_sync = {s.sync: s.demand for s in drive.history}
    assert by_sync[v0 + 5] == records[4, 0]  # exactly one period of delay
    assert drive.statusword() & (1 << 10)


def test_sync_setpoint_reaches_each_setpoint_by_the_end_of_the_next_period(bench: Bench) -> None:
    period = 4
    drive = bench.add(SyncSetpointDrive(42, scaling=SCALING, limits=LIMITS, sync_period_ms=period))
    node = start_operational(bench, drive, SETPOINT_RPDOS, SETPOINT_TPDOS)
    assert not drive.has(od.INTERPOLATION_DATA_CONFIGURATION)  # no buffer on this drive
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = period
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    records = program(period)
    stream(bench, 0x200 + 42, position_frames(records))
    assert drive.faults == [] and drive.delay_periods == 2
    v0 = drive.first_setpoint_sync
    by_sync = {s.sync: s.demand for s in drive.history}
    assert by_sync[v0 + 6] == records[4, 0]  # setpoint(K) reached at SYNC K + 2
    assert by_sync[v0 + 5] != records[4, 0]
    assert demand_error(drive, linear(records, period), v0 + 1, period) < 1e-6


def test_sync_setpoint_period_outside_1_to_100_ms_faults(bench: Bench) -> None:
    drive = bench.add(SyncSetpointDrive(43, scaling=SCALING, limits=LIMITS))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = 200
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    assert drive.state == "FAULT" and drive.faults[0].code == od.EMCY_PARAMETER_ERROR
    emcy = bench.log.wait_for(0x80 + 43)
    assert int.from_bytes(emcy[0].data[:2], "little") == od.EMCY_PARAMETER_ERROR


def test_sync_setpoint_velocity_sanity_and_position_limit(bench: Bench) -> None:
    limits = DriveLimits(600, 10**7, -5000, 5000)
    drive = bench.add(SyncSetpointDrive(44, scaling=SCALING, limits=limits))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 100  # 100 qc/ms = 1465 rpm > 600
    bench.sync(3)
    assert drive.state == "FAULT" and drive.faults[0].code == od.EMCY_VELOCITY_LIMIT
    node.sdo[od.CONTROLWORD].raw = 0x0080
    assert drive.demand == 100  # the fault came at the end of the ramp
    drive.apply_limits(DriveLimits(6000, 10**7, -150, 150))
    for cw in (0x0006, 0x000F, 0x001F):
        node.sdo[od.CONTROLWORD].raw = cw
    bench.sync(1)
    node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 200
    bench.sync(3)
    assert drive.faults[-1].code == od.EMCY_SOFTWARE_POSITION_LIMIT
    assert drive.demand <= 150  # the demand beyond 0x607D was not taken


def parker(bench: Bench, node_id: int, cycle_us: int, submode: int) -> tuple[ParkerDrive, object]:
    drive = bench.add(ParkerDrive(node_id, scaling=SCALING, limits=LIMITS, sync_period_ms=cycle_us / 1000))
    node = start_operational(bench, drive, PARKER_RPDOS, PARKER_TPDOS)
    node.sdo[od.COMMUNICATION_CYCLE_PERIOD].raw = cycle_us
    node.sdo[od.INTERPOLATION_SUBMODE].raw = submode
    node.sdo[od.PARKER_OPERATIVE_MODE].raw = od.PARKER_IP_MODE
    for cw in (0x0006, 0x0007, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw
    bench.sync(1)
    assert drive.ip_active
    return drive, node


def pv_frames(records: np.ndarray) -> list[bytes]:
    return [
        int(p).to_bytes(4, "little", signed=True) + int(v).to_bytes(4, "little", signed=True) for p, v, _ in records
    ]


def test_parker_direct_below_2500_us_takes_the_reference_on_the_sync(bench: Bench) -> None:
    drive, _ = parker(bench, 45, 2000, -1)
    records = program(2)
    stream(bench, 0x500 + 45, pv_frames(records))
    assert drive.interpolation == "direct" and drive.delay_periods == 0
    v0 = drive.first_setpoint_sync
    by_sync = {s.sync: s.demand for s in drive.history}
    assert all(by_sync[v0 + k] == records[k, 0] for k in range(len(records)))
    assert demand_error(drive, linear(records, 2), v0 - 1, 2.0) < 1e-6


@pytest.mark.parametrize(
    ("submode", "reconstruct", "delay"),
    [
        (0, lambda r, T: linear(r, T), 1),
        (-1, lambda r, T: cubic_pv(r, T, FACTOR), 1),
        (-2, lambda r, T: cubic_p(r, T), 2),
    ],
)
def test_parker_interpolated_from_2500_us_matches_the_planner(bench: Bench, submode, reconstruct, delay) -> None:
    period = 4
    drive, _ = parker(bench, 46, period * 1000, submode)
    records = program(period)
    stream(bench, 0x500 + 46, pv_frames(records))
    assert drive.faults == [] and drive.delay_periods == delay
    v0 = drive.first_setpoint_sync
    # linear and -1 reconstructions start at the SYNC validating record 0; cubic_p carries its
    # extra cycle itself (its first segment starts one period in)
    t0 = v0 + delay - 1 if submode != -2 else v0
    assert demand_error(drive, reconstruct(records, float(period)), t0, period) < 1e-6
    by_sync = {s.sync: s.demand for s in drive.history}
    assert by_sync[v0 + 7 + delay] == pytest.approx(records[7, 0])  # record 7 reached `delay` cycles on


def test_parker_without_cycle_period_faults_when_enabled(bench: Bench) -> None:
    drive = bench.add(ParkerDrive(47, scaling=SCALING, limits=LIMITS))
    node = bench.remote(drive)
    node.sdo[od.PARKER_OPERATIVE_MODE].raw = od.PARKER_IP_MODE
    for cw in (0x0006, 0x0007, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw
    bench.sync(1)
    assert drive.state == "FAULT" and drive.faults[0].code == od.EMCY_PARAMETER_ERROR
    with pytest.raises(SdoAbortedError):
        node.sdo[od.INTERPOLATION_SUBMODE].raw = -3


def test_ip_linear_period_of_several_syncs(bench: Bench) -> None:
    """0x60C2 = 4 ms on a 1 ms SYNC: one target every 4 SYNCs, each ramp spans the 4 ms period."""
    drive = bench.add(IpLinearDrive(48, scaling=SCALING, limits=LIMITS, sync_period_ms=1.0))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = 4
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    records = program(4, n=12)
    for p in records[:, 0]:
        node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = int(p)
        bench.sync(4)
    bench.sync(6)
    assert drive.faults == [] and len(drive.setpoints) == len(records)
    assert demand_error(drive, linear(records, 4), drive.first_setpoint_sync, 1.0) < 1e-6


def test_halt_brakes_a_fixed_period_drive(bench: Bench) -> None:
    drive = bench.add(SyncSetpointDrive(49, scaling=SCALING, limits=LIMITS))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.PROFILE_DECELERATION].raw = 100000
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    for k in range(1, 6):
        node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 20 * k
        bench.sync(1)
    assert drive.velocity > 0
    node.sdo[od.CONTROLWORD].raw = 0x011F
    assert not drive.ip_active
    node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 5000  # ignored while halted
    bench.sync(10)
    assert drive.velocity == 0.0 and drive.demand < 200 and drive.faults == []
    assert node.sdo[od.STATUSWORD].raw & (1 << 10)
