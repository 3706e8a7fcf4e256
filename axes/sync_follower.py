"""The SYNC the interface sends by itself, and the master thread that follows it.

Where the interface sends SYNC cyclically by itself (python-can's ``send_periodic`` not falling back
on its ``ThreadBasedCyclicSendTask``: socketcan's broadcast manager), the master does not time SYNC:
its thread follows each SYNC the bus hears with the time stamp and the setpoints that must follow
every SYNC (``SyncClock.transmit`` without the SYNC frame). The interface times SYNC, so a gap is
measured between the SYNCs' own time stamps on the bus, not in this thread's wakes: a held process
delays the time stamp, not the SYNC. What a held follower costs is the setpoints: a synchronous
RPDO holds one setpoint, the last written before the SYNC that validates it, so none can be on the
bus more than a period ahead. The SYNCs heard while it was held went out without a new setpoint
(``SyncClock.skipped``): the drives held through them, as through a late SYNC, and the follower
then sends the setpoint next in the program (``SetpointFeeder.after_sync``: the rest of the motion a
period later for each, never a jump); a run of them longer than the drives ride out is reported as
a SYNC gap is (``FaultKind.SYNC_GAP``, "no setpoint for ... ms"), and the motion halts.

One thread follows (not two on two CPUs, as ``axes.sync`` produces SYNC): measured on the
simulated wire (bench/RESULTS.md, "Issue 23: SYNC under load"), the follower's multi-ms gaps are
the SYNC echoes reaching the process late, in a batch (the receive path, the medium's delivery),
not the follower waking late; a second follower only took the GIL.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

import can

from axes.objects import SYNC_COB_ID
from axes.subscriptions import subscribe, unsubscribe

if TYPE_CHECKING:
    from axes.sync import SyncClock


def native_cyclic_task(bus: can.BusABC, msg: can.Message, period_s: float) -> can.broadcastmanager.CyclicTask | None:
    """A cyclic send of ``msg`` that the interface times by itself (socketcan: the kernel's broadcast
    manager), not started yet; None where python-can would fall back on a thread of its own
    (``ThreadBasedCyclicSendTask``: virtual, pcan, ...), which is no better than the SYNC thread."""
    if type(bus)._send_periodic_internal is can.BusABC._send_periodic_internal:
        return None
    try:
        task = bus.send_periodic(msg, period_s, autostart=False)
    except (can.CanError, NotImplementedError, OSError, TypeError):
        return None
    if isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask):
        task.stop()
        return None
    return task


class SyncFollower:
    """Follows the SYNCs the interface sends (``SyncClock.native``) for one ``SyncClock``."""

    def __init__(self, clock: SyncClock) -> None:
        self.clock = clock
        self.task: can.broadcastmanager.CyclicTask | None = None  # the interface's own cyclic SYNC
        self._echo = threading.Condition(threading.Lock())
        self._echoes = 0  # SYNC frames the interface sent and the bus heard
        self._stamp: float | None = None  # the last SYNC echo's time stamp (bus time)
        self._gap_s = 0.0  # the longest gap between SYNC echoes not yet judged

    def reset(self) -> None:
        """A new production: no gap is judged across the SYNCs of the one before."""
        with self._echo:
            self._stamp, self._gap_s = None, 0.0

    def _on_echo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._echo:
            self._echoes += 1
            if self._stamp is not None:  # the bus's own time stamps: the gap the drives saw
                self._gap_s = max(self._gap_s, timestamp - self._stamp)
            self._stamp = timestamp
            self._echo.notify_all()

    def follow(self, production: int) -> None:
        """The interface sends SYNC: this thread follows each one the bus hears with the time stamp
        and the setpoints. SYNCs that came while it was held are counted, one time stamp and one
        setpoint follow the last (the feeder sends the setpoint due after it)."""
        clock = self.clock
        network = clock.bus.network
        with self._echo:
            seen, silent = self._echoes, False  # the SYNCs heard before this production are not its own

        # this production's own subscriber: a follower of the previous production still winding
        # down unsubscribes its own, never this one's
        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            self._on_echo(can_id, data, timestamp)

        subscribe(network, SYNC_COB_ID, on_echo)
        try:
            assert self.task is not None
            if isinstance(self.task, can.broadcastmanager.RestartableCyclicTaskABC):
                self.task.start()
            while True:
                with self._echo:
                    heard = self._echo.wait_for(lambda seen=seen: self._echoes > seen, clock.max_gap_s)
                if not heard:  # a held process wakes this thread first: let the receive thread catch up
                    with self._echo:
                        self._echo.wait_for(lambda seen=seen: self._echoes > seen, clock.period_ms / 1000.0)
                now = time.monotonic()
                gap = unfed_gap = None
                with clock.lock:
                    if not clock.producing(production):
                        return
                    with self._echo:  # counted once the lock is held: a wait for it is a hold too
                        echoes = self._echoes
                    if echoes > seen:
                        unfed = echoes - seen - 1  # heard, but not followed one by one: no setpoint came after them
                        clock.skipped += unfed
                        clock.count += unfed
                        # the interface times SYNC: a gap is between the SYNCs on the bus, not in
                        # this thread's wakes (a held process delays the time stamp, not the SYNC)
                        with self._echo:
                            gap, self._gap_s = self._gap_s, 0.0
                        clock.transmit(sync_frame=False)
                        seen, silent = echoes, False
                        # the setpoint just sent is the first since the SYNC before the unfed ones: the
                        # drives go unfed + 1 periods between two setpoints, as through a SYNC gap
                        unfed_gap = (unfed + 1) * clock.period_ms / 1000.0 if unfed else None
                    elif not silent:  # no SYNC heard for the whole gap the drives ride out: once
                        silent = True
                        gap = now - (clock.sent_at if clock.sent_at is not None else now)
                if gap is not None:
                    clock.report_gap(gap)
                if unfed_gap is not None:
                    clock.report_gap(unfed_gap, "no setpoint")
        finally:
            unsubscribe(network, SYNC_COB_ID, on_echo)
