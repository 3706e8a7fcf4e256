"""The cyclic process's loop (``axes.master.cyclic.loop``) in this process, on a virtual bus that can refuse frames:
what goes out after a SYNC, in which order, and what a full transmit queue does to the records.

No timing is asserted: each SYNC is sent by hand (``_transmit``), and the drive's clock is moved by
setting the start SYNC's time back.
"""

from __future__ import annotations

import itertools
import multiprocessing
import time
import uuid
from collections.abc import Callable

import can
import numpy as np
import pytest

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.objects import SYNC_COB_ID, Record
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.master.cyclic.loop import (
    PROGRESS_COUNT,
    PROGRESS_FEEDERS,
    CycleSpec,
    CyclicLoop,
    FeedSpec,
    schedule_periods,
)
from pvtflow.axes.master.group.feeder import (
    MIN_HELD,
    BufferFeeder,
    RecordAllowance,
    RecordRefusedError,
    top_up_by_need,
)
from pvtflow.axes.master.profiles.cia402_ip_linear import target_frame
from pvtflow.axes.master.profiles.epos2_pvt import record_frame
from pvtflow.axes.sim.wire import SimWireBus

PERIOD_MS = 10.0
STAMP = 0x0FF


class RefusingBus(can.BusABC):
    """A virtual bus whose transmit queue refuses what ``refuse(cob_id)`` says (ENOBUFS, as socketcan)."""

    def __init__(self, channel: str) -> None:
        self.inner = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
        self.refuse = lambda cob_id: False
        self.sent: list[can.Message] = []
        super().__init__(channel=channel)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.refuse(msg.arbitration_id):
            raise can.CanOperationError("No buffer space available", 105)
        self.sent.append(msg)
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None):
        return self.inner.recv(timeout), False

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


def loop_on(bus: RefusingBus) -> tuple[CyclicLoop, object]:
    ours, theirs = multiprocessing.Pipe()
    return CyclicLoop(bus, theirs, [0] * 8, 0, 0.002, 0.01), ours


def epos2_feed(node_id: int, n: int, next_record: int) -> FeedSpec:
    rec = np.array([[100 * k, 10, 10] for k in range(n)] + [[100 * (n - 1), 0, 0]], dtype=np.int64)
    return FeedSpec(
        node_id,
        rec,
        lambda r, cob=0x200 + node_id: record_frame(cob, r),
        next_record,
        buffer=BufferConfig(underflow_warning=4, overflow_warning=12),
        capacity=64,
    )


def test_after_each_sync_the_setpoints_go_first_and_the_records_after() -> None:
    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, _ = loop_on(bus)
        setpoints = np.array([[1000 * k, 0, 10] for k in range(6)], dtype=np.int64)
        spec = CycleSpec(
            1,
            PERIOD_MS,
            start_count=5,
            stamp_cob_id=STAMP,
            max_gap_s=0.02,
            records_per_sync=3,
            feeds=[
                FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), next=1, lead=1),
                epos2_feed(11, 40, next_record=6),
            ],
        )
        loop.prepare(spec)
        loop._transmit()  # the start SYNC
        ids = [m.arbitration_id for m in bus.sent]
        assert ids[0] == SYNC_COB_ID and ids[1] == 0x20C  # setpoint 1 for the SYNC after the start
        assert ids[2:] == [0x20B] * 3  # then the records, this period's allowance of them
        assert Record.from_bytes(bytes(bus.sent[2].data)).position == 600  # going on where the master stood
        assert loop.count == 5 and loop.progress[PROGRESS_COUNT] == 5
        assert loop.progress[PROGRESS_FEEDERS : PROGRESS_FEEDERS + 2] == [2, 9]
    finally:
        bus.shutdown()


def test_a_full_queue_delays_a_record_and_the_run_goes_on() -> None:
    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, conn = loop_on(bus)
        loop.prepare(CycleSpec(1, PERIOD_MS, 1, None, 0.05, 2, feeds=[epos2_feed(11, 60, 8)]))
        loop._transmit()
        bus.refuse = lambda cob: cob == 0x20B  # records refused for two periods, the FIFO above its reserve
        for _ in range(2):
            loop.start_sent -= PERIOD_MS / 1000.0
            loop._transmit()
        feeder = loop.feeders[0]
        assert isinstance(feeder, BufferFeeder)
        waiting = feeder.next
        bus.refuse = lambda cob: False
        loop.start_sent -= PERIOD_MS / 1000.0
        loop._transmit()
        assert feeder.next > waiting  # the refused record went at the next top-up, none lost
        positions = [Record.from_bytes(bytes(m.data)).position for m in bus.sent if m.arbitration_id == 0x20B]
        assert positions == sorted(set(positions)) and positions[0] == 800  # in order, none twice
        assert not conn.poll()  # no fault told to the master
    finally:
        bus.shutdown()


def test_records_refused_below_the_reserve_end_the_run_with_every_drive_quick_stopped() -> None:
    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, conn = loop_on(bus)
        loop.prepare(CycleSpec(1, PERIOD_MS, 1, None, 0.05, 2, feeds=[epos2_feed(11, 60, 8)]))
        loop._transmit()
        bus.refuse = lambda cob: cob == 0x20B
        feeder = loop.feeders[0]
        failed = periods_until_failed(loop, 20)
        assert failed is not None and "below its reserve 4" in str(failed)
        assert feeder.level < feeder.low  # judged by the estimate, before the drive could run dry
        assert feeder.level >= 1
        loop._failed(*(_fault(failed)))
        kinds = []
        while conn.poll(0.5):
            kinds.append(conn.recv())
        assert kinds[-1][:3] == ("fault", "tx_failed", 11)
        quick = [m for m in bus.sent if m.arbitration_id == 0x600 + 11]
        assert quick and bytes(quick[0].data[:3]) == bytes([0x2B, 0x40, 0x60])  # 0x6040 = quick stop, by SDO
    finally:
        bus.shutdown()


def test_under_a_look_ahead_bound_the_fifo_at_its_least_is_not_below_the_reserve() -> None:
    """The look-ahead bound gives the FIFO's depth below the underflow warning up: at MIN_HELD records a
    refused record waits for a later top-up; one fewer, and the drive would soon run dry: the run ends."""
    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, conn = loop_on(bus)
        feed = epos2_feed(11, 60, 8)
        feed.records[:, 2] = 100  # 100 ms records: 3 of them reach 200-300 ms ahead, short of the bound
        feed.lookahead_ms = 250.0
        loop.prepare(CycleSpec(1, PERIOD_MS, 1, None, 0.05, 2, feeds=[feed]))
        loop._transmit()
        feeder = loop.feeders[0]
        assert isinstance(feeder, BufferFeeder)
        assert feeder.reserve == MIN_HELD < feeder.low
        refused_at: list[int] = []
        bus.refuse = lambda cob: cob == 0x20B and not refused_at.append(feeder.level)
        levels: list[int] = []
        failed = periods_until_failed(loop, 100, lambda: levels.append(feeder.level))  # 8 records of 100 ms held
        assert min(levels) == MIN_HELD  # no fault while the FIFO stood at its least
        assert MIN_HELD in refused_at  # refused at the least the bound keeps, and the run went on
        assert failed is not None and f"below its reserve {MIN_HELD}" in str(failed)
        assert feeder.level == MIN_HELD - 1
        assert not conn.poll()
    finally:
        bus.shutdown()


def periods_until_failed(loop: CyclicLoop, most: int, each: Callable[[], None] = lambda: None) -> Exception | None:
    """One period at a time on the loop's clock, ``most`` of them, until one raises what ends the SYNC thread
    (``_produce``); ``each`` after every period that did not."""
    for _ in range(most):
        loop.start_sent -= PERIOD_MS / 1000.0
        try:
            loop._transmit()
        except Exception as exc:
            return exc
        each()
    return None


def _fault(exc: Exception):
    from pvtflow.axes.master.bus.faults import FaultKind

    return FaultKind.TX_FAILED, str(exc), getattr(exc, "node_id", None)


def test_top_up_gives_a_refused_record_back_to_the_allowance() -> None:
    sent: list[bytes] = []
    refuse = [True]

    def offer(cob: int, data: bytes) -> None:
        if refuse[0]:
            raise RecordRefusedError("full")
        sent.append(data)

    allowance = RecordAllowance(3)
    feed = epos2_feed(11, 30, 0)
    feeder = BufferFeeder(feed.records, feed.packer, offer, PERIOD_MS, feed.buffer, allowance=allowance)
    assert top_up_by_need([feeder], allowance) is feeder
    assert feeder.next == 0 and allowance.left == 3  # nothing lost, nothing spent
    refuse[0] = False
    assert top_up_by_need([feeder], allowance) is None
    assert feeder.next == 3 and len(sent) == 3


def test_a_halt_brakes_a_drive_without_a_ramp_from_its_last_setpoint() -> None:
    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, _ = loop_on(bus)
        scaling = AxisScaling(4096.0, 1.0)
        limits = DriveLimits(6000, 5_000, -(10**9), 10**9)
        setpoints = np.array([[400 * k, 0, 10] for k in range(50)], dtype=np.int64)  # 40 qc/ms
        ramp = FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), next=1, lead=1, braking=(limits, scaling))
        held = FeedSpec(13, setpoints, lambda r: target_frame(0x20D, r), next=1, lead=1)
        loop.prepare(CycleSpec(1, PERIOD_MS, 1, None, 0.05, 1, feeds=[ramp, held]))
        for _ in range(5):
            loop._transmit()
        loop.halt(quick=False)
        before = len(bus.sent)
        for _ in range(40):
            loop._transmit()
        braking = [
            int.from_bytes(m.data, "little", signed=True) for m in bus.sent[before:] if m.arbitration_id == 0x20C
        ]
        steps = np.diff([2000, *braking])
        assert len(braking) > 1 and np.all(steps >= 0) and np.all(np.diff(steps) <= 0)  # slowing, never back
        assert steps[-1] < steps[0] and braking[-1] > 2000
        assert not [m for m in bus.sent[before:] if m.arbitration_id == 0x20D]  # a drive with a ramp: nothing more
    finally:
        bus.shutdown()


def test_a_sync_the_queue_refuses_sends_nothing_after_it_and_is_tried_again() -> None:
    from pvtflow.axes.master.cyclic.loop import _SyncRefusedError

    bus = RefusingBus(f"cyc-{uuid.uuid4().hex[:8]}")
    try:
        loop, conn = loop_on(bus)
        setpoints = np.array([[1000 * k, 0, 10] for k in range(6)], dtype=np.int64)
        spec = CycleSpec(
            1,
            PERIOD_MS,
            1,
            STAMP,
            0.02,
            2,
            feeds=[FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), 1, lead=1)],
        )
        loop.prepare(spec)
        bus.refuse = lambda cob: cob == SYNC_COB_ID
        with pytest.raises(_SyncRefusedError):
            loop._transmit()
        assert bus.sent == [] and loop.count == 0  # no setpoint without its SYNC, no SYNC counted
        bus.refuse = lambda cob: False
        loop._transmit()
        assert [m.arbitration_id for m in bus.sent] == [SYNC_COB_ID, 0x20C] and loop.count == 1
        assert not conn.poll()
    finally:
        bus.shutdown()


def test_a_mirrored_feeder_sends_nothing_whatever_its_drive_says() -> None:
    """Once handed to the cyclic process, the master's feeders mirror the child's: an underflow warning,
    a top-up or a SYNC makes them send nothing (the child sends; two senders would duplicate records)."""
    from pvtflow.axes.drive.objects import BufferStatus
    from pvtflow.axes.master.group.feeder import SetpointFeeder

    sent: list[bytes] = []
    feed = epos2_feed(11, 30, 0)
    allowance = RecordAllowance(4)
    buffered = BufferFeeder(
        feed.records, feed.packer, lambda c, d: sent.append(d), PERIOD_MS, feed.buffer, allowance=allowance
    )
    setpoints = SetpointFeeder(
        np.array([[k, 0, 10] for k in range(5)]),
        lambda r: target_frame(0x20C, r),
        lambda c, d: sent.append(d),
        PERIOD_MS,
        1,
    )
    buffered.mirrored = setpoints.mirrored = True
    buffered.on_status(int(BufferStatus.UNDERFLOW_WARNING | BufferStatus.IP_MODE_ACTIVE))
    top_up_by_need([buffered, setpoints], allowance)
    setpoints.after_sync(0)
    assert sent == [] and buffered.next == 0 and setpoints.next == 0


def follow_for(loop: CyclicLoop, listener: can.BusABC, stamp: int | None, syncs: int) -> list[can.Message]:
    """One fixed-period axis (setpoint k = 1000 k) following the interface's SYNC for ``syncs`` SYNCs: what
    the listener heard until the loop stopped."""
    setpoints = np.array([[1000 * k, 0, 10] for k in range(40)], dtype=np.int64)
    feeds = [FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), next=1, lead=1)]
    loop.begin(CycleSpec(1, PERIOD_MS, 1, stamp, 0.5, 1, interface_sync=True, feeds=feeds))
    heard: list[can.Message] = []
    while sum(m.arbitration_id == SYNC_COB_ID for m in heard) < syncs:
        msg = listener.recv(2.0)
        assert msg is not None, "the interface stopped sending SYNC"
        heard.append(msg)
    loop.stop()
    return heard


@pytest.mark.wall
def test_following_the_interfaces_sync_each_sync_gets_the_next_setpoint_and_its_wire_time_stamp() -> None:
    """``interface_sync``: the interface (here the wall-clock medium, as socketcan's broadcast manager)
    sends SYNC; the loop follows each SYNC it hears with the next setpoint and the time stamp of that
    SYNC's wire time, never two setpoints before one SYNC, and after ``stop`` no SYNC comes any more."""
    from pvtflow.axes.sim.wire import SimWireBus

    channel = f"cycw-{uuid.uuid4().hex[:8]}"
    bus = SimWireBus(channel, clock="wall", receive_own_messages=True, node_name="cyclic")
    listener = SimWireBus(channel, node_name="listener")
    try:
        loop, _ = loop_on(bus)
        heard = follow_for(loop, listener, STAMP, 8)
        while (msg := listener.recv(0.1)) is not None:  # what was on its way as it stopped
            heard.append(msg)
        assert listener.recv(3 * PERIOD_MS / 1000.0) is None  # stopped: no SYNC any more

        syncs = [i for i, m in enumerate(heard) if m.arbitration_id == SYNC_COB_ID]
        assert loop.timing.late_us == [] and loop.timing.followed_us  # the loop timed no SYNC: it followed
        targets = [int.from_bytes(m.data, "little", signed=True) for m in heard if m.arbitration_id == 0x20C]
        assert targets == [1000 * k for k in range(1, len(targets) + 1)]  # the next in the program, no jump
        for before, after in itertools.pairwise(syncs):
            between = heard[before + 1 : after]
            assert sum(m.arbitration_id == 0x20C for m in between) <= 1  # never two before one SYNC
            stamps = [m for m in between if m.arbitration_id == STAMP]
            for stamp in stamps:  # the time stamp says when that SYNC left the wire
                assert int.from_bytes(stamp.data, "little") == round(heard[before].timestamp * 1e6) & 0xFFFFFFFF
        assert len(targets) >= 5 and len(targets) <= loop.count <= len(syncs)  # one per SYNC followed
        assert loop.progress[PROGRESS_COUNT] == loop.count
    finally:
        bus.shutdown()
        listener.shutdown()


class _HeldOnce(CyclicLoop):
    """A follower whose thread is held for three SYNC periods once, in the fourth period (as this host's
    scheduler holds it beside CPU-bound processes, bench/RESULTS.md)."""

    held = False

    def _write_progress(self) -> None:
        super()._write_progress()
        spec = self.spec
        if spec is not None and not self.held and self.count >= spec.start_count + 3:
            self.held = True
            time.sleep(3 * spec.period_ms / 1000.0)


class _NoSchedule(SimWireBus):
    """simwire without its transmit schedule: the follower posts each setpoint when it wakes (socketcan)."""

    @property
    def timed_transmit(self) -> bool:
        return False


@pytest.mark.wall
def test_a_follower_held_three_periods_misses_no_sync_where_the_interface_keeps_a_schedule() -> None:
    """The setpoints go into the interface's transmit schedule ``schedule_periods`` SYNCs ahead (2 ms: 4),
    so a follower held for three periods still has one setpoint on the wire before every SYNC (none held,
    the program's setpoints in order); posted when it wakes (no schedule), the same hold leaves SYNCs
    without one."""
    period_ms = 2.0
    assert schedule_periods(period_ms, 200.0) == 4
    setpoints = np.array([[1000 * k, 0, 2] for k in range(60)], dtype=np.int64)
    for bus_class, scheduled in ((SimWireBus, True), (_NoSchedule, False)):
        channel = f"cych-{uuid.uuid4().hex[:8]}"
        bus = bus_class(channel, clock="wall", receive_own_messages=True, node_name="cyclic")
        listener = SimWireBus(channel, node_name="listener")
        try:
            _ours, theirs = multiprocessing.Pipe()
            loop = _HeldOnce(bus, theirs, [0] * 8, 0, 0.002, 0.01)
            feeds = [FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), next=1, lead=1)]
            loop.begin(CycleSpec(1, period_ms, 1, None, 0.5, 1, interface_sync=True, feeds=feeds))
            heard: list[can.Message] = []
            while sum(m.arbitration_id == SYNC_COB_ID for m in heard) < 16:
                msg = listener.recv(2.0)
                assert msg is not None, "the interface stopped sending SYNC"
                heard.append(msg)
            loop.stop()
            assert loop.held
            syncs = [i for i, m in enumerate(heard) if m.arbitration_id == SYNC_COB_ID]
            fed = [any(m.arbitration_id == 0x20C for m in heard[a + 1 : b]) for a, b in itertools.pairwise(syncs)]
            targets = [int.from_bytes(m.data, "little", signed=True) for m in heard if m.arbitration_id == 0x20C]
            assert targets == [1000 * k for k in range(1, len(targets) + 1)]  # in order, none twice, no jump
            if scheduled:
                assert all(fed) and loop.timing.held == 0, (fed, loop.timing.held)
            else:
                assert not all(fed) and loop.timing.held >= 1  # the same hold without the schedule
        finally:
            bus.shutdown()
            listener.shutdown()


@pytest.mark.wall
def test_a_change_begins_after_the_setpoints_the_schedule_holds() -> None:
    """What the transmit schedule holds is committed, as an EPOS2's FIFO records are: ``hold`` (a path stop,
    a pause, an override) moves its t0 past the last setpoint scheduled, which is ``schedule_periods`` SYNCs
    ahead of the last SYNC, and nothing ending after t0 is scheduled or reaches the wire until ``splice``."""
    period_ms = 2.0
    setpoints = np.array([[1000 * k, 0, 2] for k in range(200)], dtype=np.int64)
    channel = f"cyco-{uuid.uuid4().hex[:8]}"
    bus = SimWireBus(channel, clock="wall", receive_own_messages=True, node_name="cyclic")
    listener = SimWireBus(channel, node_name="listener")
    try:
        _ours, theirs = multiprocessing.Pipe()
        loop = CyclicLoop(bus, theirs, [0] * 8, 0, 0.002, 0.01)
        feeds = [FeedSpec(12, setpoints, lambda r: target_frame(0x20C, r), next=1, lead=1)]
        loop.begin(CycleSpec(1, period_ms, 1, None, 0.5, 1, interface_sync=True, feeds=feeds))
        time.sleep(0.03)
        t0, nexts = loop.hold(0.0, 2)
        with loop.lock:
            elapsed = loop.count - 1  # SYNCs since the start SYNC
        feeder = loop.feeders[0]
        assert nexts == [feeder.next] and feeder.next >= elapsed + schedule_periods(period_ms, None)
        assert t0 == float(setpoints[: feeder.next, 2].sum())  # the change begins where the scheduled ones end
        time.sleep(0.03)
        assert feeder.next == nexts[0]  # nothing more scheduled while the change is made
        loop.stop()
        heard = []
        while (msg := listener.recv(0.05)) is not None:
            heard.append(msg)
        targets = [int.from_bytes(m.data, "little", signed=True) for m in heard if m.arbitration_id == 0x20C]
        assert targets and max(targets) <= 1000 * (nexts[0] - 1)  # none past t0 on the wire
    finally:
        bus.shutdown()
        listener.shutdown()
