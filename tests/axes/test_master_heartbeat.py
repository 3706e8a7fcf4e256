"""The master's own heartbeat: on 0x700 + its node id while it supervises, silent when it hangs or closes."""

from __future__ import annotations

import dataclasses
import threading
import time

import can
import pytest
from axes_rig import BusObserver, unique_channel

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive import objects as od
from pvtflow.axes.master.bus.cell_bus import CellBus


class Beats:
    """The master's heartbeats as another node on the bus sees them."""

    def __init__(self, channel: str, cob_id: int, interface: str) -> None:
        self.observer = BusObserver(channel, interface)
        self.cob_id = cob_id

    def since(self, t: float) -> int:
        return len(self.observer.on(self.cob_id, since=t))

    @property
    def payloads(self) -> set[bytes]:
        return set(self.observer.on(self.cob_id))

    def close(self) -> None:
        self.observer.close()


@pytest.mark.wall
def test_the_master_beats_while_it_supervises_and_falls_silent_when_it_hangs(arm6, make_rig):
    cell = dataclasses.replace(arm6, bus=dataclasses.replace(arm6.bus, master_node_id=100, master_heartbeat_ms=20))
    rig = make_rig(cell)
    beats = Beats(rig.cell.bus.channel, od.HEARTBEAT_COB_ID_BASE + 100, rig.cell.bus.interface)
    heartbeat = rig.bus.master_heartbeat
    release = threading.Event()
    try:
        rig.group.configure()  # the drives' heartbeats (0x1017) are now due: the receive thread's progress counts
        t0 = time.monotonic()
        time.sleep(0.5)
        assert beats.since(t0) >= 10  # 25 due at 20 ms; a loaded host delays some
        assert beats.payloads == {bytes([od.NMT_STATE_OPERATIONAL])}
        assert heartbeat.withheld is None

        # hang the master's receive thread (a listener that never returns): the beats stop within
        # the drives' heartbeat window (heartbeat_ms x heartbeat_timeout_factor)
        stuck = threading.Event()

        class Stuck(can.Listener):
            def on_message_received(self, msg: can.Message) -> None:
                if not release.is_set():
                    stuck.set()
                    release.wait()

        rig.bus.network.notifier.add_listener(Stuck())
        assert stuck.wait(5.0)
        hung_at = time.monotonic()
        window_s = heartbeat.stall_s
        deadline = hung_at + window_s + 5.0
        while heartbeat.withheld is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert heartbeat.withheld is not None and "receive thread" in heartbeat.withheld
        assert "on_message_received" in heartbeat.withheld  # where it stands: the listener that holds it
        assert heartbeat.last_beat is not None and heartbeat.last_beat - hung_at <= window_s + 0.1
        silent_from = time.monotonic()
        time.sleep(0.3)
        assert beats.since(silent_from + 0.05) == 0

        # the master comes back: so do its beats
        release.set()
        deadline = time.monotonic() + 5.0
        while beats.since(silent_from + 0.3) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert beats.since(silent_from + 0.3) >= 3 and heartbeat.withheld is None

        # closed: no beat after close() returns
        rig.bus.close()
        closed_at = time.monotonic()
        time.sleep(0.2)
        assert beats.since(closed_at + 0.02) == 0 and not heartbeat.running
    finally:
        release.set()
        beats.close()


@pytest.mark.wall
def test_with_sync_on_the_wall_clock_a_stuck_sync_producer_silences_the_master(arm6):
    """Real time: the SYNC count must move. Its lock held (here by the test) blocks the producer;
    no drive is on this bus, so only this rule can withhold the beats."""
    config = dataclasses.replace(
        arm6.bus, channel=unique_channel("hb"), heartbeat_ms=20, master_heartbeat_ms=10, master_node_id=120
    )
    bus = CellBus(config, clock=Clock.WALL).open()
    beats = Beats(config.channel, od.HEARTBEAT_COB_ID_BASE + 120, config.interface)
    heartbeat = bus.master_heartbeat
    try:
        bus.sync.start()
        time.sleep(0.3)
        assert heartbeat.withheld is None and beats.since(0.0) > 0
        with bus.sync.lock:  # the SYNC producer waits for it
            deadline = time.monotonic() + heartbeat.stall_s + 5.0
            while heartbeat.withheld is None and time.monotonic() < deadline:
                time.sleep(0.01)
            why = heartbeat.withheld
        assert why is not None and "SYNC" in why
        deadline = time.monotonic() + 5.0
        while heartbeat.withheld is not None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert heartbeat.withheld is None  # SYNC moves again: so do the beats
    finally:
        bus.close()
        beats.close()
