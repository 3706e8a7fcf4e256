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
a SYNC gap is (``FaultKind.SYNC_GAP``, "no setpoint for ... ms"), and the motion halts. Where every
drive is buffered (``SyncClock.setpoints_per_sync`` false: the EPOS2 runs its records on its own
clock), those SYNCs went without a time stamp, and the feed waited (its allowance is per SYNC
followed): counted, not a gap by itself. What the drive holds decides: its FIFO is usually far
above the reserve that bounds a gap of SYNC, and one that runs dry is the drive's own buffer
underflow, which halts the motion as what it is. Which SYNC
took a setpoint is judged by time: a SYNC's own time stamp (brought to this host's clock by the
offset of the fastest echo) against when the setpoint went out, since echoes can reach this process
late, in a batch: a SYNC stamped before the last setpoint went out took none, and no second setpoint
follows it (two before one SYNC, the drive would take the later: a jump).

One thread follows (not two on two CPUs, as ``axes.master.bus.sync`` produces SYNC): measured on the
simulated wire (bench/RESULTS.md, "Issue 23: SYNC under load"), the follower's multi-ms gaps are
the SYNC echoes reaching the process late, in a batch (the receive path, the medium's delivery),
not the follower waking late; a second follower only took the GIL.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol

import can
import canopen

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.objects import SYNC_COB_ID

OFFSET_CREEP_S = 10e-6  # how fast the time stamps' offset may drift up, per SYNC heard (``_on_echo``)


class FollowedClock(Protocol):
    """What the follower needs of the SYNC clock it follows for (``axes.master.bus.sync.SyncClock``):
    named here so that the follower does not import the clock that holds it."""

    count: int
    skipped: int
    max_gap_s: float
    setpoints_per_sync: bool
    period_ms: float
    sent_at: float | None
    hold: Callable[[], None] | None

    @property
    def network(self) -> canopen.Network: ...

    @property
    def lock(self) -> threading.RLock: ...

    def producing(self, production: int) -> bool: ...

    def transmit(self, sync_frame: bool = True) -> None: ...

    def report_gap(self, gap_s: float, what: str = "no SYNC") -> None: ...


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


class TransmitSchedule:
    """Frames the interface puts in its transmit queue at a given instant, timed by itself, not by this
    process (``transmit_schedule``): a follower of SYNC can hand over the setpoints for several SYNCs ahead
    and a late wake of its thread no longer makes them late. Instants on ``time.monotonic()``."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self._epoch = float(bus.bus_epoch)  # the interface's time = epoch + CLOCK_MONOTONIC (one clock per host)

    def post(self, msgs: list[can.Message], due: float) -> None:
        """``msgs`` into the transmit queue at ``due``, in this order (a full queue then drops them)."""
        self.bus.send_at(msgs, self._epoch + due)

    def cancel(self) -> None:
        """The frames not yet due are taken back."""
        self.bus.cancel_scheduled()


def transmit_schedule(bus: can.BusABC) -> TransmitSchedule | None:
    """The interface's transmit schedule, None where it has none.

    simwire on the wall clock has one (``SimWireBus.send_at``: the medium queues the frames at their due
    bus time, as it queues a cyclic SYNC). Real interfaces keep one in hardware or in the kernel: IXXAT
    VCI's delayed transmit, esd NTCAN's scheduled transmit objects, and SocketCAN's broadcast manager.
    SocketCAN is not used for it here (python-can's socketcan bus offers periodic sends only, and this
    kernel has no CAN to test one): the broadcast manager would do it with one TX_SETUP per RPDO COB-ID
    (its operations are keyed by identifier) holding the next setpoints as its ``nframes`` frames, with
    SETTIMER|STARTTIMER|TX_COUNTEVT, ``count`` = the frames, ``ival1`` = the SYNC period, frame i going at
    the i-th expiry; its timer starts at the syscall, so the op is set up in the period before the SYNC it
    follows and updated (TX_SETUP without SETTIMER replaces the frames, the timer kept) once per period
    with the next setpoint; TX_DELETE takes it back. Until then socketcan keeps the follower's posts."""
    if not getattr(bus, "timed_transmit", False):
        return None
    return TransmitSchedule(bus)


class SyncFollower:
    """Follows the SYNCs the interface sends (``SyncClock.native``) for one ``SyncClock``."""

    def __init__(self, clock: FollowedClock) -> None:
        self.clock = clock
        self.task: can.broadcastmanager.CyclicTask | None = None  # the interface's own cyclic SYNC
        self._echo = threading.Condition(threading.Lock())
        self._heard: deque[float] = deque()  # SYNCs heard and not yet followed: their time stamps, here
        self._stamp: float | None = None  # the last SYNC echo's time stamp (bus time)
        self._gap_s = 0.0  # the longest gap between SYNC echoes not yet judged
        self._offset = math.inf  # this host's wall time less the bus's time stamps, at the fastest echo
        self._pending: float | None = -math.inf  # when the setpoint no SYNC has taken yet went out
        self._unfed = 0  # SYNCs in a row that took no new setpoint
        self._unfed_reported = False

    def reset(self) -> None:
        """A new production: no gap is judged across the SYNCs of the one before, and its first SYNC
        takes what was sent before it (the start's setpoints). Called under the clock's lock."""
        with self._echo:
            self._stamp, self._gap_s = None, 0.0
            self._heard.clear()
        self._pending, self._unfed, self._unfed_reported = -math.inf, 0, False

    def _on_echo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        arrived = time.time()
        with self._echo:
            if timestamp == self._stamp:
                return  # the same frame through a winding-down production's subscriber
            if self._stamp is not None:  # the bus's own time stamps: the gap the drives saw
                self._gap_s = max(self._gap_s, timestamp - self._stamp)
            self._stamp = timestamp
            # the time stamps' clock against this host's (socketcan and simwire stamp on the wall
            # clock; any other is offset): the fastest echo's, let creep up 10 us per echo to follow drift
            self._offset = min(self._offset + OFFSET_CREEP_S, arrived - timestamp)
            self._heard.append(timestamp + self._offset)
            self._echo.notify_all()

    def _take(self, heard: list[float], period_s: float) -> tuple[bool, float | None]:
        """Judge the SYNCs heard since the last follow (called under the clock's lock): the first that
        came after the pending setpoint took it, any other took none. Whether to send the next
        setpoint now (none is pending), and the gap between setpoints to report (None: none)."""
        clock = self.clock
        report = None
        for at in heard:
            clock.count += 1
            if self._pending is not None and self._pending <= at:
                self._pending, self._unfed, self._unfed_reported = None, 0, False
                continue
            self._unfed += 1  # a SYNC that went out before the setpoint sent for it: the drives held
            clock.skipped += 1
            between = (self._unfed + 1) * period_s  # from the last SYNC that took a setpoint to the next
            if between > clock.max_gap_s and not self._unfed_reported and clock.setpoints_per_sync:
                self._unfed_reported, report = True, between
        return self._pending is None, report

    def follow(self, production: int) -> None:
        """The interface sends SYNC: this thread follows the SYNCs the bus hears with the time stamp
        and the setpoints, one for the SYNC after the last heard, none while the one it sent has not
        been taken (module docstring)."""
        clock = self.clock
        network = clock.network
        period_s = clock.period_ms / 1000.0
        silent = False

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
                    heard = self._echo.wait_for(lambda: bool(self._heard), clock.max_gap_s)
                if not heard:  # a held process wakes this thread first: let the receive thread catch up
                    with self._echo:
                        self._echo.wait_for(lambda: bool(self._heard), period_s)
                if clock.hold is not None:
                    clock.hold()
                now = time.monotonic()
                gap = unfed_gap = None
                with clock.lock:
                    if not clock.producing(production):
                        return
                    with self._echo:  # taken once the lock is held: a wait for it is a hold too
                        taken = list(self._heard)
                        self._heard.clear()
                        if taken:
                            # the interface times SYNC: a gap is between the SYNCs on the bus, not in
                            # this thread's wakes (a held process delays the time stamp, not the SYNC)
                            gap, self._gap_s = self._gap_s, 0.0
                    if taken:
                        silent = False
                        send, unfed_gap = self._take(taken, period_s)
                        if send:  # the SYNC it stands for is counted in ``transmit``
                            clock.count -= 1
                            clock.transmit(sync_frame=False)
                            # once sent (a hold inside counts as before it: a SYNC meanwhile took none,
                            # the safe side: a setpoint missed, never two before one SYNC)
                            self._pending = time.time()
                    elif not silent:  # no SYNC heard for the whole gap the drives ride out: once
                        silent = True
                        gap = now - (clock.sent_at if clock.sent_at is not None else now)
                if gap is not None:
                    clock.report_gap(gap)
                if unfed_gap is not None:
                    clock.report_gap(unfed_gap, "no setpoint")
        finally:
            unsubscribe(network, SYNC_COB_ID, on_echo)
