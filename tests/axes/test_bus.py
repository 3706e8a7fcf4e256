"""CellBus on raw frames: lockstep and real-time SYNC, 0x1013, NMT, heartbeat/EMCY consumers, traffic log."""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

import can
import pytest
from axes_rig import unique_channel

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.drive.objects import TIME_STAMP_COB_ID, NmtCommand
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.bus.network import FrameLog


class Responder(can.Listener):
    """Raw-frame drives: answer every SYNC with one frame per node on 0x280 + id."""

    def __init__(self, channel: str, nodes: tuple[int, ...] = (1, 2)) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.nodes = list(nodes)
        self.frames: list[can.Message] = []
        self.syncs = 0
        self.cond = threading.Condition()
        self.notifier = can.Notifier(self.bus, [self], 0.05)

    def on_message_received(self, msg: can.Message) -> None:
        with self.cond:
            self.frames.append(msg)
            if msg.arbitration_id == 0x80:
                self.syncs += 1
                for nid in self.nodes:
                    self.bus.send(
                        can.Message(
                            arbitration_id=0x280 + nid,
                            data=struct.pack("<Hi", 0x1637, self.syncs),
                            is_extended_id=False,
                        )
                    )
            self.cond.notify_all()

    def wait(self, predicate, timeout: float = 5.0) -> bool:
        with self.cond:
            return self.cond.wait_for(predicate, timeout)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


@pytest.fixture
def channel() -> str:
    return unique_channel("bus")


def test_lockstep_sync_waits_for_every_answer_and_runs_listeners_in_between(channel):
    responder = Responder(channel)
    bus = CellBus(BusConfig(channel=channel, time_stamp=True), clock=Clock.LOCKSTEP).open()
    try:
        seen: list[tuple[int, int]] = []
        done = threading.Event()

        def on_sync(n: int) -> None:
            seen.append((n, bus.sync.count))
            if n == 200:
                bus.sync.stop()
                done.set()

        bus.sync.expect([0x281, 0x282])
        bus.sync.add_listener(on_sync)
        bus.sync.start()
        assert done.wait(10)
        # every SYNC answered by both nodes before the next one went out
        assert seen == [(n, n) for n in range(1, 201)]
        assert bus.sync.count == bus.sync.answered == 200
        assert responder.wait(lambda: responder.syncs == 200)
        ids = [m.arbitration_id for m in responder.frames]
        # each SYNC is followed by its 0x1013 high-resolution time stamp (us, u32)
        for k, cob in enumerate(ids):
            if cob == 0x80:
                assert ids[k + 1] == TIME_STAMP_COB_ID
        stamps = [struct.unpack("<I", m.data)[0] for m in responder.frames if m.arbitration_id == TIME_STAMP_COB_ID]
        assert len(stamps) == 200 and stamps == sorted(stamps)
    finally:
        bus.close()
        responder.close()


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_can_log_records_sent_and_received_frames(channel, tmp_path: Path, suffix):
    responder = Responder(channel, nodes=(5,))
    path = tmp_path / f"traffic{suffix}"
    bus = CellBus(BusConfig(channel=channel, time_stamp=False), can_log=path).open()
    try:
        bus.nmt_broadcast(NmtCommand.PRE_OPERATIONAL)
        bus.sync.expect([0x285])
        done = threading.Event()
        bus.sync.add_listener(lambda n: (bus.sync.stop(), done.set()) if n == 10 else None)
        bus.sync.start()
        assert done.wait(5)
        assert responder.wait(lambda: len([m for m in responder.frames if m.arbitration_id == 0x80]) == 10)
    finally:
        bus.close()
        responder.close()
    logged = [m.arbitration_id for m in can.LogReader(str(path))]
    assert logged.count(0x80) == 10  # the master's own SYNCs
    assert logged.count(0x285) == 10  # the drive's answers
    assert 0x000 in logged  # NMT
    assert bus.recorder.frames == len(logged)


@pytest.mark.wall
def test_real_time_sync_is_produced_periodically(channel):
    responder = Responder(channel, nodes=(3,))
    for can_log in (None, "x"):
        bus = CellBus(BusConfig(channel=channel, sync_period_ms=2.0, time_stamp=False), clock=Clock.WALL).open()
        if can_log:
            bus.recorder.taps.append(lambda msg: None)  # a tap selects the master's own SYNC thread
        try:
            start = responder.syncs
            bus.sync.expect([0x283])
            bus.sync.start()
            assert responder.wait(lambda s=start: responder.syncs >= s + 20)
            # the answers reach the master on its receive thread: wait for them, do not race them
            deadline = time.monotonic() + 5.0
            while bus.sync.answered < 19 and time.monotonic() < deadline:
                time.sleep(0.001)
            bus.sync.stop()
            assert bus.sync.answered >= 19
        finally:
            bus.close()
    responder.close()


def test_a_sync_sent_by_hand_is_waited_for_and_the_next_keeps_the_period(channel):
    """``step`` (the start's check SYNC): ``wait_answered`` returns once every expected node has
    answered it, or names the one that did not; in real time the next produced SYNC comes at least
    one period after it (``keep_period``)."""
    responder = Responder(channel, nodes=(3, 4))
    for lockstep in (True, False):
        responder.frames.clear()
        responder.syncs = 0
        config = BusConfig(channel=channel, sync_period_ms=20.0, time_stamp=False)
        bus = CellBus(config, clock=Clock.of(lockstep)).open()
        try:
            bus.sync.expect([0x283, 0x284])
            assert bus.sync.wait_answered(bus.sync.step(), 5.0) == []
            syncs = [m.timestamp for m in responder.frames if m.arbitration_id == 0x80]
            before = len(syncs)
            bus.sync.keep_period()
            bus.sync.start()
            assert responder.wait(lambda n=before: responder.syncs >= n + 1)
            bus.sync.stop()
            produced = [m.timestamp for m in responder.frames if m.arbitration_id == 0x80][len(syncs)]
            if not lockstep:
                assert produced - syncs[-1] >= 0.95 * config.sync_period_ms / 1000.0
            bus.sync.expect([0x283, 0x285])  # node 5 is not there: its answer is missing
            assert bus.sync.wait_answered(bus.sync.step(), 0.2) == [0x285]
        finally:
            bus.close()
    responder.close()


def test_heartbeat_emcy_and_lost_sync_are_reported(channel):
    responder = Responder(channel, nodes=(7, 8))
    # heartbeats every 5 ms, lost after 150 ms: room for a busy host, and still quick
    config = BusConfig(channel=channel, heartbeat_ms=50, heartbeat_timeout_factor=3.0)
    bus = CellBus(config, lost_sync_timeout_s=0.2).open()
    faults: list[BusFault] = []
    got = threading.Condition()

    def on_fault(f: BusFault) -> None:
        with got:
            faults.append(f)
            got.notify_all()

    bus.on_fault(on_fault)
    try:
        bus.add_node(7)
        bus.add_node(8)
        heartbeat7 = responder.bus.send_periodic(
            can.Message(arbitration_id=0x707, data=[5], is_extended_id=False), 0.005
        )
        heartbeat8 = responder.bus.send_periodic(
            can.Message(arbitration_id=0x708, data=[5], is_extended_id=False), 0.005
        )
        bus.watch.watch_heartbeat([7, 8])
        # EMCY 0x8612 from node 8
        responder.bus.send(can.Message(arbitration_id=0x88, data=b"\x12\x86\x01\0\0\0\0\0", is_extended_id=False))
        with got:
            assert got.wait_for(lambda: any(f.kind is FaultKind.EMCY for f in faults), 5)
        emcy = next(f for f in faults if f.kind is FaultKind.EMCY)
        assert emcy.node_id == 8 and emcy.code == 0x8612
        heartbeat7.stop()
        with got:
            assert got.wait_for(lambda: any(f.kind is FaultKind.HEARTBEAT for f in faults), 5)
        lost = next(f for f in faults if f.kind is FaultKind.HEARTBEAT)
        assert lost.node_id == 7 and "heartbeat" in lost.message
        assert not any(f.kind is FaultKind.HEARTBEAT and f.node_id == 8 for f in faults)
        # node 8 stops answering SYNC: lost SYNC names it
        bus.sync.expect([0x287, 0x288])
        responder.nodes = [7]
        bus.watch.arm_sync_watch()
        bus.sync.start()
        with got:
            assert got.wait_for(lambda: any(f.kind is FaultKind.LOST_SYNC for f in faults), 5)
        lost_sync = next(f for f in faults if f.kind is FaultKind.LOST_SYNC)
        assert lost_sync.node_id == 8 and "[8]" in lost_sync.message
        heartbeat8.stop()
    finally:
        bus.close()
        responder.close()


def test_unknown_interface_is_one_clear_error():
    from pvtflow.axes.master.bus.faults import BusError

    with pytest.raises(BusError, match="cannot open CAN bus"):
        CellBus(BusConfig(interface="socketcan", channel="pvtflow-does-not-exist")).open()


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_can_log_with_a_channel_name_that_is_no_channel_number(tmp_path: Path, suffix):
    """BLF and ASC keep a channel number; a name ending in many digits must not break the log."""
    path = tmp_path / f"traffic{suffix}"
    recorder = FrameLog(path)
    recorder.on_message_received(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False, channel="t-98765432"))
    recorder.on_message_received(can.Message(arbitration_id=0x185, data=b"\x01", is_extended_id=False, channel="can1"))
    recorder.stop()
    logged = list(can.LogReader(str(path)))
    assert [m.arbitration_id for m in logged] == [0x80, 0x185]
