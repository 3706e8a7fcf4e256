"""Fixed-period drives on the wall clock lock their cycle to SYNC (axes/sim/profiles/sync_lock.py).

The test is the drive's bus and its clock: it hands each SYNC to the drive with the instant it
arrived and runs the drive's 1 ms sampling itself (what the cell's ``Ticker`` does), on a timeline
of its own, so a SYNC can be exactly as early or late as the test says, on any host. The frames'
time stamps are the timeline's instants (``arrival`` maps a bus stamp to the drive's clock; here
the test's stamps already are that clock).
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable

import pytest

import pvtflow.axes.sim.cia402.sampling
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.sim import IpLinearDrive, ParkerDrive, SyncSetpointDrive
from pvtflow.axes.sim.clock import MotionClock
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive
from pvtflow.axes.sim.profiles.sync_lock import SYNC_WAIT_BITS, sync_window_us

from .conftest import Bench, enable

SCALING = AxisScaling(4096.0, 1.0)
LIMITS = DriveLimits(3000, 10**6, -(10**8), 10**8)  # 0x607F 3000 rpm, 0x60C5 high: the velocity is judged here
VMAX = float(SCALING.rpm_to_qc_per_ms(LIMITS.max_profile_velocity_rpm))  # qc/ms
PERIOD_MS = 2
WINDOW_US = sync_window_us(1_000_000)


def ip_linear(bench: Bench, drift_ppm: float) -> FixedPeriodDrive:
    drive = bench.add(IpLinearDrive(61, scaling=SCALING, limits=LIMITS, clock="wall", drift_ppm=drift_ppm))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = PERIOD_MS
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    node.sdo[od.CONTROLWORD].raw = 0x001F
    return drive


def sync_setpoint(bench: Bench, drift_ppm: float) -> FixedPeriodDrive:
    drive = bench.add(SyncSetpointDrive(62, scaling=SCALING, limits=LIMITS, clock="wall", drift_ppm=drift_ppm))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = PERIOD_MS
    node.sdo[od.CONTROLWORD].raw = 0x001F
    return drive


def parker(submode: int, cycle_us: int) -> Callable[[Bench, float], FixedPeriodDrive]:
    def make(bench: Bench, drift_ppm: float) -> FixedPeriodDrive:
        drive = bench.add(ParkerDrive(63, scaling=SCALING, limits=LIMITS, clock="wall", drift_ppm=drift_ppm))
        node = bench.remote(drive)
        node.sdo[od.COMMUNICATION_CYCLE_PERIOD].raw = cycle_us
        node.sdo[od.INTERPOLATION_SUBMODE].raw = submode
        node.sdo[od.PARKER_OPERATIVE_MODE].raw = od.PARKER_IP_MODE
        for cw in (0x0006, 0x0007, 0x000F):
            node.sdo[od.CONTROLWORD].raw = cw
        return drive

    make.__name__ = f"parker_{submode}_{cycle_us}us"
    return make


DRIVES = [ip_linear, sync_setpoint, parker(0, 2500), parker(-2, 2500), parker(0, 2000)]
# the drives whose segment a SYNC's instant times (the Parker below 2500 us takes each setpoint at once
# and judges its step over 0x1006, the cubic through positions starts each segment at its own point)
RAMPING = [ip_linear, sync_setpoint, parker(0, 2500)]


def full_speed_setpoints(period_ms: float, n_ramp: int = 20, n_cruise: int = 120) -> list[int]:
    """Rest to rest at 99 % of 0x607F: a linear ramp of the velocity up, a cruise, a ramp down."""
    vmax = 0.99 * VMAX * period_ms  # qc per period
    steps = [vmax * (k + 1) / n_ramp for k in range(n_ramp)] + [vmax] * n_cruise
    steps += [vmax * (n_ramp - 1 - k) / n_ramp for k in range(n_ramp)]
    points, p = [], 0.0
    for s in steps:
        p += s
        points.append(round(p))
    return points


def run(bench: Bench, make, monkeypatch, offsets_us: dict[int, float], missing: frozenset[int] = frozenset()):
    """Stream the full-speed setpoints, SYNC k at its ideal instant + ``offsets_us[k]`` (``missing``:
    not sent); the drive's demand at every whole ms of its clock, its faults, its lock."""
    monkeypatch.setattr(
        pvtflow.axes.sim.cia402.sampling, "arrival", lambda stamp: stamp
    )  # the stamps are the drive's clock
    drive = make(bench, 0.0)
    start = time.monotonic() + 1.0  # the test's timeline; SYNC 0 0.3 ms off the drive's whole ms
    with drive.lock:
        assert drive.time_us == 0 and drive.sync_count == 0
        drive.motion_clock = MotionClock(drive.quartz, 0.0, start)
    samples: list[tuple[float, float, float]] = []
    sample = drive.motion.sample

    def recorded(t: float, full: bool) -> None:
        sample(t, full)
        if full:
            samples.append((t, drive.demand, drive.velocity))

    drive.motion.sample = recorded  # type: ignore[method-assign]
    period_ms = drive.period_ms  # SYNC every interpolation period
    setpoints = full_speed_setpoints(period_ms)
    tail = 4
    events: list[tuple[float, int, int | None]] = []  # (instant, order, SYNC k or None: a tick)
    n_syncs = 1 + len(setpoints) + tail
    for k in range(n_syncs):
        if k not in missing:
            events.append((start + (300.0 + k * period_ms * 1000.0 + offsets_us.get(k, 0.0)) * 1e-6, 1, k))
    for m in range(round((n_syncs + 2) * period_ms)):
        events.append((start + m * 1e-3, 0, None))
    for instant, _, k in sorted(events):
        if k is None:
            drive.run_to(instant)
            continue
        if 1 <= k <= len(setpoints):  # SYNC 0 activates; SYNC k validates setpoint k
            drive.node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = setpoints[k - 1]
        drive.motion.on_sync(0x80, bytearray(), instant)
    return drive, samples


def jitter(n: int, bound_us: float, seed: int) -> dict[int, float]:
    """SYNCs 1.. up to ``bound_us`` early or late (SYNC 0, which the lock starts from, on time)."""
    rng = random.Random(seed)
    return {k: rng.uniform(-bound_us, bound_us) for k in range(1, n)}


def test_the_window_is_one_longest_frame_on_the_wire() -> None:
    assert SYNC_WAIT_BITS == 135 and pytest.approx(135.0) == WINDOW_US
    assert sync_window_us(500_000) == pytest.approx(270.0)


@pytest.mark.parametrize("make", DRIVES, ids=lambda f: f.__name__)
def test_jitter_inside_the_window_leaves_the_demand_as_with_perfect_syncs(make, monkeypatch) -> None:
    ideal_bench, jittered_bench = Bench(), Bench()
    try:
        ideal, ideal_samples = run(ideal_bench, make, monkeypatch, {})
        # up to 90 % of the window off the ideal instant, and its edges back to back (the lock's own
        # phase follows the SYNCs by a few us: the window is around its prediction, not the ideal)
        offsets = jitter(200, 0.9 * WINDOW_US, seed=34)
        offsets.update({10: WINDOW_US - 5.0, 11: -(WINDOW_US - 5.0)})
        jittered, samples = run(jittered_bench, make, monkeypatch, offsets)
    finally:
        ideal_bench.close()
        jittered_bench.close()
    assert ideal.faults == [] and jittered.faults == [], (ideal.faults, jittered.faults)
    assert ideal.internal_errors == [] and jittered.internal_errors == []
    assert jittered.sync_lock.late == jittered.sync_lock.early == 0
    n = min(len(ideal_samples), len(samples))
    assert n > 300
    assert samples[:n] == ideal_samples[:n]  # every sample: time, demand, velocity
    demands = [d for _, d, _ in samples]
    assert max(abs(b - a) for a, b in zip(demands, demands[10:], strict=False)) > 0.95 * VMAX * 10  # full speed
    assert jittered.demand == ideal.demand == full_speed_setpoints(ideal.period_ms)[-1]


@pytest.mark.parametrize("make", RAMPING, ids=lambda f: f.__name__)
@pytest.mark.parametrize("offset_us", [WINDOW_US + 65.0, -(WINDOW_US + 65.0)], ids=["late", "early"])
def test_a_sync_outside_the_window_is_punished_as_before(make, offset_us, monkeypatch) -> None:
    bench = Bench()
    try:
        drive, _ = run(bench, make, monkeypatch, {60: offset_us})  # mid-cruise, at 99 % of 0x607F
    finally:
        bench.close()
    assert drive.sync_lock.late + drive.sync_lock.early >= 1
    assert drive.faults, "a SYNC 200 us off at 99 % of 0x607F asks more than 0x607F"
    assert drive.faults[0].code == od.EMCY_VELOCITY_LIMIT
    assert drive.state == "FAULT"


@pytest.mark.parametrize("make", DRIVES[:2], ids=lambda f: f.__name__)
def test_a_missing_sync_is_punished_as_before(make, monkeypatch) -> None:
    bench = Bench()
    try:
        drive, _ = run(bench, make, monkeypatch, {}, missing=frozenset({60}))
    finally:
        bench.close()
    assert drive.sync_lock.late >= 1
    assert drive.faults and drive.faults[0].code == od.EMCY_VELOCITY_LIMIT


@pytest.mark.wall
def test_the_lock_follows_a_drifting_quartz(monkeypatch) -> None:
    """100 ppm: 0.2 us a period, out of a 135 us window within 700 periods if nothing followed."""
    monkeypatch.setattr(pvtflow.axes.sim.cia402.sampling, "arrival", lambda stamp: stamp)
    bench = Bench()
    try:
        drive = ip_linear(bench, 100.0)
        start = time.monotonic() + 1.0
        with drive.lock:
            drive.motion_clock = MotionClock(drive.quartz, 0.0, start)
        for k in range(3000):
            instant = start + k * PERIOD_MS * 1e-3
            drive.run_to(instant)
            drive.motion.on_sync(0x80, bytearray(), instant)
    finally:
        bench.close()
    lock = drive.sync_lock
    assert lock.late == lock.early == 0 and lock.on_time == 2999
    assert lock.frequency == pytest.approx(100e-6, rel=0.05)  # the loop found the quartz's 100 ppm
