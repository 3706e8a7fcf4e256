"""Simulated drives on the wall clock (``clock="wall"``): each keeps its own time, whatever the SYNCs do.

The test is the master: it sends SYNC and setpoints by hand, with its own timing, on python-can's
``virtual`` bus, and one ``Ticker`` runs the drives as a ``SimulatedCell`` does. These are
behavioural tests: the margins are generous and no duration is asserted.
"""

from __future__ import annotations

import itertools
import statistics
import struct
import time
from collections.abc import Callable, Iterator

import can
import pytest

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.objects import (
    EPOS2_RPDOS,
    EPOS2_TIME_STAMP_RPDO,
    EPOS2_TPDOS,
    PARKER_RPDOS,
    PARKER_TPDOS,
    SETPOINT_RPDOS,
    SETPOINT_TPDOS,
    Record,
)
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.sim import Epos2Drive, IpLinearDrive, ParkerDrive, SyncSetpointDrive
from pvtflow.axes.sim.clock import Ticker
from pvtflow.axes.sim.drive import SimulatedDrive
from pvtflow.axes.sim.profiles.epos2 import MAX_SLEW
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive

from .conftest import Bench, configure_pdos, enable

SCALING = AxisScaling(4096.0, 1.0)
LIMITS = DriveLimits(6000, 10**7, -(10**7), 10**7)
VMAX = float(SCALING.rpm_to_qc_per_ms(LIMITS.max_profile_velocity_rpm))  # 0x607F in qc/ms
PERIOD_MS = 10  # the fixed-period drives' 0x60C2 / 0x1006: long next to a sleeping thread's jitter


@pytest.fixture
def ticker(bench: Bench) -> Iterator[Ticker]:
    """The one ticker thread of the drives the test adds (stopped before the bench closes)."""
    t = Ticker()
    yield t.start()
    t.stop()


def add(bench: Bench, ticker: Ticker, drive: SimulatedDrive) -> SimulatedDrive:
    bench.add(drive)
    ticker.drives.append(drive)
    return drive


def operational(bench: Bench, drive: SimulatedDrive, rpdos, tpdos):
    node = bench.remote(drive)
    configure_pdos(node, rpdos, tpdos)
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational)
    return node


# --- the three fixed-period drives, started in interpolation at PERIOD_MS ---------------------------
def ip_linear(bench: Bench, ticker: Ticker, node_id: int) -> tuple[FixedPeriodDrive, Callable[[int], bytes], int]:
    drive = add(bench, ticker, IpLinearDrive(node_id, scaling=SCALING, limits=LIMITS, clock="wall"))
    node = operational(bench, drive, SETPOINT_RPDOS, SETPOINT_TPDOS)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = PERIOD_MS
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    node.sdo[od.CONTROLWORD].raw = 0x001F
    return drive, lambda p: p.to_bytes(4, "little", signed=True), 0x200 + node_id


def sync_setpoint(bench: Bench, ticker: Ticker, node_id: int) -> tuple[FixedPeriodDrive, Callable[[int], bytes], int]:
    drive = add(bench, ticker, SyncSetpointDrive(node_id, scaling=SCALING, limits=LIMITS, clock="wall"))
    node = operational(bench, drive, SETPOINT_RPDOS, SETPOINT_TPDOS)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = PERIOD_MS
    node.sdo[od.CONTROLWORD].raw = 0x001F
    return drive, lambda p: p.to_bytes(4, "little", signed=True), 0x200 + node_id


def parker_linear(bench: Bench, ticker: Ticker, node_id: int) -> tuple[FixedPeriodDrive, Callable[[int], bytes], int]:
    drive = add(bench, ticker, ParkerDrive(node_id, scaling=SCALING, limits=LIMITS, clock="wall"))
    node = operational(bench, drive, PARKER_RPDOS, PARKER_TPDOS)
    node.sdo[od.COMMUNICATION_CYCLE_PERIOD].raw = PERIOD_MS * 1000  # from 2500 us: interpolated
    node.sdo[od.INTERPOLATION_SUBMODE].raw = 0  # linear
    node.sdo[od.PARKER_OPERATIVE_MODE].raw = od.PARKER_IP_MODE
    for cw in (0x0006, 0x0007, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw
    return drive, lambda p: p.to_bytes(4, "little", signed=True) + bytes(4), 0x500 + node_id


FIXED = [ip_linear, sync_setpoint, parker_linear]


def start(bench: Bench, drive: FixedPeriodDrive) -> None:
    bench.sync(1)
    assert drive.ip_active and drive.faults == []


class Master:
    """Setpoint then SYNC, once per period on absolute deadlines; a missed deadline is skipped, never
    caught up (no burst unless the test asks for one)."""

    def __init__(self, bench: Bench, cob_id: int, frame: Callable[[int], bytes]) -> None:
        self.bench, self.cob_id, self.frame = bench, cob_id, frame
        self.due = time.monotonic()
        self.sent: list[int] = []

    def send(self, setpoint: int | None) -> None:
        if setpoint is not None:
            self.bench.send(self.cob_id, self.frame(int(setpoint)))
            self.sent.append(int(setpoint))
        self.bench.sync(1, wait=False)

    def stream(self, setpoints, tail: int = 2) -> None:
        """The setpoints, then ``tail`` SYNCs without (the sync_setpoint drive ramps to its last one
        at the SYNC after the one that validated it)."""
        for p in [*setpoints, *[None] * tail]:
            now = time.monotonic()
            if self.due > now:
                time.sleep(self.due - now)
            else:
                self.due = now
            self.send(p)
            self.due += PERIOD_MS / 1000.0

    def burst(self, setpoints) -> None:
        for p in setpoints:
            self.send(p)

    def settle(self, drive: SimulatedDrive) -> None:
        assert drive.wait_sync(self.bench.syncs, 5.0)


def ramp(first: int, n: int, step: float) -> list[int]:
    return [round(first + step * k) for k in range(1, n + 1)]


@pytest.mark.parametrize("make", FIXED, ids=lambda f: f.__name__)
def test_fixed_period_well_timed_stream_follows_the_setpoints(bench: Bench, ticker: Ticker, make) -> None:
    drive, frame, cob_id = make(bench, ticker, 51)
    start(bench, drive)
    step = 0.05 * VMAX * PERIOD_MS  # 5 % of 0x607F when on time
    setpoints = ramp(0, 40, step)
    master = Master(bench, cob_id, frame)
    master.stream(setpoints)
    master.settle(drive)
    assert drive.wait_until(lambda: drive.demand == setpoints[-1] and drive.velocity == 0.0, 5.0)
    assert drive.faults == [] and drive.ip_active
    # at each SYNC the demand is at (or, with a SYNC a little early, just short of) the setpoint the
    # profile's delay says: record k validated at SYNC v0 + k is reached `delay` periods on (judged
    # where the sample at the SYNC is the SYNC's own: the simulation got to it within 2 ms)
    v0 = drive.first_setpoint_sync
    at_sync = {s.sync: s.demand for s in drive.history if s.behind_us <= 2000}
    errors = [
        abs(at_sync[v0 + k + drive.delay_periods] - p)
        for k, p in enumerate(setpoints)
        if v0 + k + drive.delay_periods in at_sync
    ]
    assert len(errors) >= len(setpoints) // 2, len(errors)
    assert max(errors) <= 3 * step, errors
    demands = [s.demand for s in drive.history if s.sync >= v0]
    assert all(b >= a - 1e-9 for a, b in itertools.pairwise(demands))  # a monotone path stays so


@pytest.mark.wall
@pytest.mark.parametrize("make", FIXED, ids=lambda f: f.__name__)
def test_fixed_period_late_sync_holds_the_last_setpoint(bench: Bench, ticker: Ticker, make) -> None:
    drive, frame, cob_id = make(bench, ticker, 52)
    start(bench, drive)
    step = 0.2 * VMAX * PERIOD_MS
    setpoints = ramp(0, 6, step)
    master = Master(bench, cob_id, frame)
    master.stream(setpoints, tail=0)
    master.settle(drive)
    syncs = drive.sync_count
    # no SYNC for 3 periods: the segment under way ends on time, on the drive's own clock, and the
    # drive holds its end point (in lockstep the demand would stand mid-segment, at the last SYNC)
    reached = setpoints[-drive.delay_periods]
    assert drive.wait_until(lambda: drive.demand == reached and drive.velocity == 0.0, 5.0), drive.demand
    time.sleep(3 * PERIOD_MS / 1000.0)
    assert drive.sync_count == syncs
    assert drive.demand == reached and drive.velocity == 0.0
    assert drive.faults == [] and drive.ip_active and drive.state == "OPERATION ENABLED"
    master.due = time.monotonic()
    more = ramp(setpoints[-1], 6, step)
    master.stream(more)  # the stream goes on from rest
    master.settle(drive)
    assert drive.wait_until(lambda: drive.demand == more[-1], 5.0)
    assert drive.faults == []


@pytest.mark.parametrize("make", FIXED, ids=lambda f: f.__name__)
def test_fixed_period_burst_of_syncs_faults_as_a_too_fast_program(bench: Bench, ticker: Ticker, make) -> None:
    drive, frame, cob_id = make(bench, ticker, 53)
    start(bench, drive)
    step = 0.4 * VMAX * PERIOD_MS  # 40 % of 0x607F when each setpoint gets its period
    setpoints = ramp(0, 4, step)
    master = Master(bench, cob_id, frame)
    master.stream(setpoints, tail=0)
    master.settle(drive)
    assert drive.faults == [] and drive.state == "OPERATION ENABLED"
    # the master catches up: five periods' setpoints and SYNCs back to back; the drive ramps from
    # where its demand is to the latest over one period: a multiple of the planned speed
    master.burst(ramp(setpoints[-1], 5, step))
    assert drive.wait_until(lambda: drive.state == "FAULT", 5.0), (drive.state, drive.velocity)
    fault = drive.faults[0]
    assert fault.code == drive.EMCY_VELOCITY == od.EMCY_VELOCITY_LIMIT and fault.check == "max profile velocity 0x607F"
    emcy = bench.log.wait_for(0x80 + 53, where=lambda m: int.from_bytes(m.data[:2], "little") != 0)
    assert int.from_bytes(emcy[0].data[:2], "little") == od.EMCY_VELOCITY_LIMIT


@pytest.mark.wall
def test_fixed_period_lockstep_is_unmoved_by_wall_time(bench: Bench) -> None:
    """The default clock: the demand moves with SYNCs only, however long the test waits."""
    drive = bench.add(IpLinearDrive(54, scaling=SCALING, limits=LIMITS, sync_period_ms=PERIOD_MS))
    assert drive.clock == "lockstep" and drive.motion_clock is None
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_TIME_PERIOD][1].raw = PERIOD_MS
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    node.sdo[od.INTERPOLATION_DATA_RECORD][1].raw = 1000
    bench.sync(1)
    time.sleep(3 * PERIOD_MS / 1000.0)
    assert drive.demand == 0.0  # the ramp to 1000 runs over the next period of SYNCs only
    bench.sync(1)
    assert drive.demand == 1000.0


@pytest.mark.wall
def test_clock_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="clock must be one of lockstep, wall"):
        IpLinearDrive(55, clock="sometimes")
    with pytest.raises(ValueError, match="drift_ppm"):
        IpLinearDrive(55, clock="wall", drift_ppm=float("nan"))


# --- EPOS2 --------------------------------------------------------------------------------------------
EPOS2_SCALING = AxisScaling(2000.0, 1.0)
EPOS2_LIMITS = DriveLimits(8000, 2_000_000, -(10**7), 10**7, 4000, 400_000)


def cruise(segments: int, segment_ms: int = 50, rpm: int = 300) -> list[tuple[int, int, int]]:
    """Rest, up to ``rpm`` in one segment, ``segments`` at ``rpm``, down to rest, the time-0 end."""
    v = float(EPOS2_SCALING.rpm_to_qc_per_ms(rpm))
    half = round(v * segment_ms / 2)
    full = round(v * segment_ms)
    records = [(0, 0, 3), (half, rpm, segment_ms)]
    for k in range(1, segments + 1):
        records.append((half + k * full, rpm, segment_ms))
    end = records[-1][0] + half
    return [*records, (end, 0, segment_ms), (end, 0, 0)]


def epos2(bench: Bench, ticker: Ticker, node_id: int, records, **kw) -> tuple[Epos2Drive, object]:
    drive = add(bench, ticker, Epos2Drive(node_id, scaling=EPOS2_SCALING, limits=EPOS2_LIMITS, clock="wall", **kw))
    node = operational(bench, drive, EPOS2_RPDOS, EPOS2_TPDOS)
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    for p, v, t in records:
        bench.send(0x200 + node_id, Record(p, v, t).to_bytes())  # the asynchronous RPDO 1
    assert drive.wait_until(lambda: drive.level == len(records))
    return drive, node


@pytest.mark.wall
def test_epos2_runs_its_records_on_its_own_clock_through_a_sync_gap_and_a_burst(bench: Bench, ticker: Ticker) -> None:
    records = cruise(10)
    drive, node = epos2(bench, ticker, 61, records, sync_period_ms=2.0)
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)  # the start SYNC
    assert drive.ip_active
    due = time.monotonic()
    for _ in range(20):  # 40 ms of SYNC at 2 ms
        due += 0.002
        time.sleep(max(due - time.monotonic(), 0.0))
        bench.sync(1, wait=False)
    consumed = len(drive.records_consumed)
    # no SYNC at all: the records go on running on the drive's clock
    assert drive.wait_until(lambda: len(drive.records_consumed) >= consumed + 3, 5.0)
    assert drive.ip_active and drive.faults == []
    bench.sync(10, wait=False)  # a burst, as a catching-up master sends it
    assert drive.wait_until(lambda: drive.ended_by_time_zero == 1, 10.0), drive.records_consumed
    assert drive.faults == [] and drive.state == "OPERATION ENABLED"
    assert drive.demand == records[-1][0]
    checks = list(drive.clock_checks)
    assert checks and all(1.0 - MAX_SLEW - 1e-12 <= c.rate <= 1.0 + MAX_SLEW + 1e-12 for c in checks)


@pytest.mark.wall
def test_epos2_without_the_next_record_underflows_on_its_own_clock(bench: Bench, ticker: Ticker) -> None:
    records = cruise(2)[:-2]  # no way down, no end marker
    drive, node = epos2(bench, ticker, 62, records)
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)  # the start SYNC, then none
    assert drive.wait_until(lambda: drive.state == "FAULT", 5.0)
    assert drive.faults[0].check == "buffer underflow" and drive.faults[0].code == od.EMCY_EPOS2_IPM_ERROR
    emcy = bench.log.wait_for(0x80 + 62, where=lambda m: int.from_bytes(m.data[:2], "little") != 0)
    assert int.from_bytes(emcy[0].data[:2], "little") == od.EMCY_EPOS2_IPM_ERROR


@pytest.mark.wall
def test_epos2_clock_correction_holds_a_drifting_quartz_to_the_sync_schedule(bench: Bench, ticker: Ticker) -> None:
    """A 500 ppm fast quartz; SYNC stamped on the bus at exact 2 ms instants (a master with hardware
    time stamps): the drive slews its clock onto start + n x period and stays there."""
    drift_ppm, period_s = 500.0, 0.002
    records = cruise(40)  # about 2.1 s: 1 ms of uncorrected drift
    drive, node = epos2(bench, ticker, 63, records, sync_period_ms=period_s * 1000, drift_ppm=drift_ppm)
    node.sdo[od.CONTROLWORD].raw = 0x001F
    stamped = can.Bus(interface="virtual", channel=bench.channel, preserve_timestamps=True)
    try:
        wall0 = time.time()
        mono0 = time.monotonic()
        wall0 = (wall0 + time.time()) / 2.0
        n = 0
        while drive.ended_by_time_zero == 0 and n < 5000 and not drive.faults:
            now = time.monotonic()
            n = max(n + 1, int((now - mono0) / period_s))  # a missed instant is skipped, not caught up
            time.sleep(max(mono0 + n * period_s - now, 0.0))
            stamp = wall0 + n * period_s
            stamped.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False, timestamp=stamp))
    finally:
        stamped.shutdown()
    assert drive.faults == [] and drive.ended_by_time_zero == 1
    checks = list(drive.clock_checks)[10:]  # after the first SYNCs
    assert len(checks) > 200
    # each SYNC takes up to MAX_SLEW of a period off the error and the quartz adds its drift over
    # the gap to the next one (a period, or more where the sender missed instants): within 10 us of that
    slew_us = MAX_SLEW * period_s * 1e6
    for before, c in itertools.pairwise(checks):
        gap_us = (c.n - before.n) * period_s * 1e6
        bound = max(abs(before.error_us) - slew_us, 0.0) + drift_ppm * 1e-6 * gap_us + 10.0
        assert abs(c.error_us) <= bound, (before, c)
    assert statistics.median(abs(c.error_us) for c in checks) < 10.0
    # the clock runs slow by the quartz's drift: the correction took it out
    assert statistics.median(c.rate for c in checks) == pytest.approx(1.0 - drift_ppm * 1e-6, abs=200e-6)
    uncorrected_us = drift_ppm * 1e-6 * (checks[-1].n * period_s * 1e6)
    assert uncorrected_us > 500.0  # what the quartz alone would have drifted by the end


def stamped_run(bench: Bench, ticker: Ticker, node_id: int, stamp_clock_ppm: float) -> list[tuple[float, float]]:
    """An EPOS2 on a 500 ppm fast quartz runs a cruise while the test, as master, sends SYNC at 2 ms
    with a jitter of up to 300 us on the wire (alternate SYNCs late), each followed by its 0x1013
    (RPDO3): the SYNC's own time on the wire, read on a master clock ``stamp_clock_ppm`` fast (0: the
    right stamp). Per SYNC of the run: (its true time since the start SYNC, the drive's time of it), us."""
    drift_ppm, period_s, jitter_s = 500.0, 0.002, 0.0003
    records = cruise(30)
    drive = add(
        bench,
        ticker,
        Epos2Drive(
            node_id,
            scaling=EPOS2_SCALING,
            limits=EPOS2_LIMITS,
            clock="wall",
            sync_period_ms=period_s * 1000,
            drift_ppm=drift_ppm,
        ),
    )
    node = operational(bench, drive, (*EPOS2_RPDOS, EPOS2_TIME_STAMP_RPDO), EPOS2_TPDOS)
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    for p, v, t in records:
        bench.send(0x200 + node_id, Record(p, v, t).to_bytes())
    assert drive.wait_until(lambda: drive.level == len(records))
    node.sdo[od.CONTROLWORD].raw = 0x001F
    stamped = can.Bus(interface="virtual", channel=bench.channel, preserve_timestamps=True)
    true_at: dict[int, float] = {}  # the drive's SYNC count -> the SYNC's true time (s, wall)
    try:
        wall0 = time.time()
        mono0 = time.monotonic()
        n = 0
        syncs = drive.sync_count
        while drive.ended_by_time_zero == 0 and n < 3000 and not drive.faults:
            now = time.monotonic()
            n = max(n + 1, int((now - mono0) / period_s))
            time.sleep(max(mono0 + n * period_s - now, 0.0))
            at = wall0 + n * period_s + (jitter_s if n % 2 else 0.0)  # the wire's time of this SYNC
            stamped.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False, timestamp=at))
            syncs += 1
            true_at[syncs] = at
            stamp = round(at * (1.0 + stamp_clock_ppm * 1e-6) * 1e6) & 0xFFFFFFFF
            stamped.send(
                can.Message(arbitration_id=0x400 + node_id, data=struct.pack("<I", stamp), is_extended_id=False)
            )
    finally:
        stamped.shutdown()
    assert drive.faults == [] and drive.ended_by_time_zero == 1
    assert drive.wait_until(lambda: drive.sync_count >= syncs)
    start = drive.ip_active_sync
    samples = {s.sync: s.time_ms * 1000.0 for s in drive.history}
    assert start in samples and start in true_at
    return [
        ((true_at[k] - true_at[start]) * 1e6, samples[k] - samples[start])
        for k in sorted(samples)
        if k > start and k in true_at
    ]


@pytest.mark.wall
@pytest.mark.parametrize("stamp_clock_ppm", [0.0, 2000.0], ids=["right-stamp", "stamp-2000ppm-off"])
def test_epos2_follows_the_masters_time_stamps(bench: Bench, ticker: Ticker, stamp_clock_ppm: float) -> None:
    """App note "Clock synchronization": the drive adjusts its motion clock to the master's time of
    each SYNC (0x1013), not to the SYNC's arrival. With the right stamp its time of every SYNC is the
    SYNC's true time, jitter or no jitter, its quartz's 500 ppm taken out; a stamp read on a clock
    2000 ppm fast is followed too: the path's time then drifts from the true time by that rate."""
    pairs = stamped_run(bench, ticker, 65 if stamp_clock_ppm == 0 else 66, stamp_clock_ppm)
    late = [(t, d) for t, d in pairs if t > 500_000.0]  # past the first 0.5 s: the clock has settled
    assert len(late) > 200
    drift = [d - t for t, d in late]
    if stamp_clock_ppm == 0:
        # each SYNC's time on the drive's clock is its true time: not its jitter (300 us every other
        # SYNC), nor the quartz (500 ppm: 500 us over the run)
        assert statistics.median(abs(x) for x in drift) < 30.0, drift[:20]
        assert max(abs(x) for x in drift) < 100.0
    else:
        # the drive's time runs ahead of the true time at the stamp clock's rate
        t0, d0 = late[0]
        t1, d1 = late[-1]
        rate_ppm = ((d1 - d0) / (t1 - t0) - 1.0) * 1e6
        assert rate_ppm == pytest.approx(stamp_clock_ppm, abs=300.0)
        assert drift[-1] > 1000.0  # over a millisecond off the true time by the end


@pytest.mark.wall
def test_epos2_lockstep_has_no_clock_of_its_own(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(64, scaling=EPOS2_SCALING, limits=EPOS2_LIMITS))
    node = bench.remote(drive)
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    for p, v, t in cruise(2):
        node.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw = Record(p, v, t).pack()
    node.sdo[od.CONTROLWORD].raw = 0x001F
    bench.sync(1)
    time.sleep(0.05)
    assert drive.time_us == 1000 and len(drive.records_consumed) == 1  # the start point only
    assert not drive.clock_checks


@pytest.mark.wall
def test_the_ticker_samples_no_further_than_the_wire_is_heard() -> None:
    """A ``Ticker`` with a horizon (``SimulatedCell`` on an in-process medium: what every drive has heard
    of the wire) moves its drives up to the horizon, never to the present past it: a drive does not
    sample past a SYNC its process has not got to yet."""
    seen: list[float] = []

    class Drive:
        def run_to(self, mono: float) -> None:
            seen.append(mono)

    held = time.monotonic() - 0.05
    ticker = Ticker([Drive()], horizon=lambda: held).start()
    try:
        deadline = time.monotonic() + 2.0
        while len(seen) < 3 and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        ticker.stop()
    assert len(seen) >= 3 and max(seen) == held


@pytest.mark.wall
def test_a_bus_has_heard_the_wire_up_to_the_first_frame_its_reader_has_not_handled() -> None:
    """``SimWireBus.taken_until``: delivered but not read, a frame holds its node's hearing before its end;
    read, until its reader comes back for the next (a canopen Notifier handles it in between)."""
    import uuid

    from pvtflow.axes.sim.wire import SimWireBus

    channel = f"heard-{uuid.uuid4().hex[:8]}"
    sender = SimWireBus(channel, clock="wall", node_name="sender")
    drive = SimWireBus(channel, clock="wall", node_name="drive")
    try:
        sender.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        deadline = time.monotonic() + 2.0
        while drive.medium.delivered_until() < drive.medium.now() and time.monotonic() < deadline:
            time.sleep(0.001)  # the medium's driver delivers it at its end
        delivered = drive.medium.delivered_until()
        assert drive.taken_until(delivered) < delivered  # in its queue, not read
        msg = drive.recv(1.0)
        assert msg is not None and drive.taken_until(delivered) < msg.timestamp  # in its reader's hands
        assert drive.recv(0.0) is None and drive.taken_until(delivered) == delivered  # handled
    finally:
        sender.shutdown()
        drive.shutdown()
