"""The cyclic path's own process: SYNC, the 0x1013 time stamp, the setpoints, the records, the quick stop.

On the wall clock the master's interpreter also plans, serves zenoh, records and answers SDO: any of
it holding the GIL when a SYNC is due delays the SYNC and the setpoints that must follow it (measured
in bench/RESULTS.md, "Full-speed tours": 1-2 % of SYNCs 210-350 us late at 2 ms, frames refused by a
transmit queue the master's other traffic filled). This process does nothing else: it opens the cell's
interface as a second node (socketcan: a second socket on the channel; simwire: a second client of
the served wire), each with a transmit queue of its own, and runs what the master hands it
(``axes.master.cyclic.process``): the feeders of one run, built from the same classes the master uses
(``axes.master.group.feeder``), so the rules of what goes out after which SYNC have one home.

Per SYNC, in this order: SYNC, the fixed-period setpoints (what must be on the wire before the next
SYNC), the time stamp, then the EPOS2 records from the period's allowance, each offered once
(``RecordRefusedError``: a full queue delays a record to a later top-up, never the SYNC after it); the run
ends on a refused record only where that drive's FIFO, as estimated, is below its reserve
(``BufferFeeder.reserve``), and then every drive is quick stopped from here.

The SYNC deadlines follow ``axes.master.bus.sync``'s rule (absolute deadlines; a SYNC more than half a period late
goes out at once and the deadlines after it keep the period from it; never two within half a period).
A SYNC the transmit queue has no room for is tried again every 0.2 ms, a late SYNC by the same rule (a
gap longer than the drives ride out is reported, and the master halts on it); a setpoint this process
cannot send within ``tx_retry_s``, or a lost master (its pipe closes), quick stops every drive from
here: the SDO requests at once, NMT stop to those that do not confirm within ``quick_stop_confirm_s``
(``axes.master.bus.quick_stop`` for the master's side of the same rule), whatever the master process is doing.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

import can
import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.objects import SYNC_COB_ID, NmtCommand
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.drive.stop_ramp import braking_records
from pvtflow.axes.master.bus.faults import FaultKind
from pvtflow.axes.master.bus.network import TX_RETRY_PAUSE_S, sent_together
from pvtflow.axes.master.bus.quick_stop import (
    SDO_DOWNLOAD_CONFIRMED,
    quick_stop_request,
)
from pvtflow.axes.master.bus.sync import ask_realtime, lift
from pvtflow.axes.master.bus.sync_follower import TransmitSchedule, native_cyclic_task, transmit_schedule
from pvtflow.axes.master.group.feeder import (
    BufferFeeder,
    Feeder,
    FrameOf,
    RecordAllowance,
    RecordRefusedError,
    SetpointFeeder,
    top_up_by_need,
)

# the shared progress array: [SYNCs sent in this run, the run's number, feeders' next record ...]
PROGRESS_COUNT, PROGRESS_RUN, PROGRESS_FEEDERS = 0, 1, 2
MAX_FEEDS = 64
# the SYNC thread wakes this long before a deadline and waits for it awake: on this project's VM a
# SCHED_FIFO sleep woke p50 47 us, p99 120-160 us, max 600-780 us late (awake for the last 0.3 ms: p50 4 us;
# bench/RESULTS.md), and a SYNC more than 135 us off its period is outside the drives' lock
# (axes/sim/profiles/sync_lock.py). It costs 0.3 ms of a CPU per period.
SPIN_BEFORE_S = 0.0003


@dataclass
class FeedSpec:
    """One axis's feeder as the master hands it over (picklable): its records and where it stands."""

    node_id: int
    records: NDArray[np.int64]
    packer: FrameOf  # the profile's frame of a record (``Profile.frame_packer``)
    next: int
    enabled: bool = True
    lead: int | None = None  # a fixed-period axis: its lead in periods (None: a buffered EPOS2)
    braking: tuple[DriveLimits, AxisScaling] | None = None  # no ramp of its own: the master's stop ramp
    buffer: BufferConfig | None = None
    capacity: int = 64
    lookahead_ms: float | None = None  # a buffered axis: the records held at most this far ahead (``BufferFeeder``)
    hold_end_ms: float | None = None  # a buffered axis: its end record held until then (``axes.master.run_queue``)


@dataclass
class CycleSpec:
    """One run's cyclic path: the SYNC period, the start SYNC's number, the feeders."""

    run: int
    period_ms: float
    start_count: int  # the number the start SYNC gets (the master's count of SYNCs)
    stamp_cob_id: int | None
    max_gap_s: float
    records_per_sync: int
    tx_queue_frames: int = 10  # this node's transmit queue (BusConfig.tx_queue_frames: socketcan's txqueuelen)
    interface_sync: bool = False  # the interface sends SYNC and this process follows it (BusConfig.interface_sync)
    max_lookahead_ms: float | None = None  # what a change of the motion leaves the drives (BusConfig.max_lookahead_ms)
    feeds: list[FeedSpec] = field(default_factory=list)


ECHO_POLL_S = 0.00005  # how often the SYNC thread looks for its SYNC's echo
# following the interface's SYNC: the setpoints go this long after their SYNC was due, at least (a frame
# queued after the SYNC is pending goes on the wire after it; the margin is for this host's clock against
# the interface's timer), and at least this fraction of the period
PACE_AFTER_S = 0.0001
PACE_AFTER_PERIODS = 0.05
# following the interface's SYNC, the gaps the drives saw are judged on the SYNCs' wire times when they are
# heard; hearing none at all for this much longer than they ride out means the interface stopped sending
# (hearing them late is the host's delay: measured up to 2-4 ms on this VM, bench/RESULTS.md)
SILENCE_GRACE_S = 0.02
# where the interface keeps a transmit schedule (``transmit_schedule``), the setpoints go into it this far
# ahead at least: a follower held up to this long still has every SYNC's setpoints on the wire (this VM's
# timer wakes measured 0.5-1.5 ms late quiet, 2-4.9 ms beside two CPU-bound processes: bench/RESULTS.md).
# What is scheduled is committed, as an EPOS2's FIFO records are: a stop or a change begins after it
# (``hold``), so it is kept to a few periods and at most half the cell's ``max_lookahead_ms``
SCHEDULE_AHEAD_MS = 8.0
# each SYNC's setpoints enter the queue this long after the SYNC's due instant: after the SYNC the
# interface queued then (a FIFO: never ahead of it, whatever rounding the two clocks' sums carry), and
# well before its frame ends (47 bits, 47 us at 1 Mbit/s), so they are pending when it ends and take the
# next arbitration before the drives' TPDOs, which the SYNC itself produces
SCHEDULE_AFTER_SYNC_S = 5e-6


def schedule_periods(period_ms: float, max_lookahead_ms: float | None) -> int:
    """The SYNCs whose setpoints are in the transmit schedule at once (``SCHEDULE_AHEAD_MS``)."""
    ahead = SCHEDULE_AHEAD_MS if max_lookahead_ms is None else min(SCHEDULE_AHEAD_MS, max_lookahead_ms / 2)
    return max(1, math.ceil(ahead / period_ms - 1e-9))


@dataclass
class CycleTiming:
    """One run's timing as this process saw it (told to the master when the run's SYNC stops)."""

    late_us: list[float] = field(default_factory=list)  # each SYNC's send after its deadline
    echo_us: list[float] = field(default_factory=list)  # each SYNC's echo, heard here, after its send
    unstamped: int = 0  # SYNCs whose echo did not come within half a period (no time stamp for them)
    refused: int = 0  # tries of a SYNC the transmit queue had no room for (each tried again 0.2 ms later)
    # following the interface's SYNC: each SYNC's setpoints sent here after that SYNC was due (its schedule)
    followed_us: list[float] = field(default_factory=list)
    held: int = 0  # SYNCs heard before this process's setpoints for them were on the wire (the drives held)


class CyclicLoop:
    """The child's state: its bus, the present run's feeders, the SYNC production."""

    def __init__(
        self,
        bus: can.BusABC,
        conn: Connection,
        progress: Any,
        priority: int,
        tx_retry_s: float,
        quick_stop_confirm_s: float,
    ) -> None:
        self.bus = bus
        self.conn = conn
        self.progress = progress
        self.priority = priority
        self.tx_retry_s = tx_retry_s
        self.quick_stop_confirm_s = quick_stop_confirm_s
        self.lock = threading.RLock()  # the run's feeders and the bus's sends: the SYNC thread and the commands
        self._conn_lock = threading.Lock()
        self._reading = threading.Lock()  # one reader of the bus at a time (``drain``)
        self.spec: CycleSpec | None = None
        self.feeders: list[Feeder] = []
        self.braking: list[tuple[DriveLimits, AxisScaling] | None] = []
        self.allowance = RecordAllowance(1)
        self.count = 0
        self.start_sent: float | None = None
        self.sent_at: float | None = None
        self._judged: float | None = None
        self.running = False
        self._production = 0
        self._confirmed: set[int] = set()
        # this node's SYNC echoes: the last one's (SYNC number, its time stamp on the wire, when heard here)
        self._echo_of: tuple[int, float, float] | None = None
        self._echoes = 0
        self.timing = CycleTiming()
        self.realtime: bool | None = None
        self._sent_frames = 0  # frames this node sent (``queued``)
        self._own_echoes = 0  # of them, those whose echo came back
        self._own_echo_at: float | None = None  # when the last of them was heard here
        self._reserved = 2  # the queue's room kept for a SYNC and what must follow it (``prepare``)
        # following the interface's SYNC (``_follow``): the SYNCs heard, each (its wire time, whether the
        # setpoints sent for it were on the wire before it), and the frames sent up to those setpoints
        self._heard: list[tuple[float, float, int]] = []  # (wire time, heard here, own echoes before it)
        self._task: can.broadcastmanager.CyclicTask | None = None
        # the interface's transmit schedule (``_schedule``): the setpoints of a SYNC gathered for it, the
        # schedule in use, and what it holds not yet due: (due, frames, the SYNC they are for), in due order
        self._batch: list[can.Message] | None = None
        self._schedule: TransmitSchedule | None = None
        self._timed: deque[tuple[float, int, int]] = deque()
        self._pace: _Pace | None = None

    # --- to the master ---------------------------------------------------------------------------
    def tell(self, *message: object) -> None:
        try:
            with self._conn_lock:
                self.conn.send(message)
        except (OSError, EOFError, BrokenPipeError):
            pass  # the master is gone: the loop on the pipe sees it too

    def fault(self, kind: FaultKind, message: str, node_id: int | None = None, code: int | None = None) -> None:
        self.tell("fault", kind.value, node_id, message, code)

    # --- frames ----------------------------------------------------------------------------------
    def send_now(self, cob_id: int, data: bytes) -> None:
        """A frame that must go before the next SYNC: a refused one is tried again for ``tx_retry_s``."""
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        deadline = time.monotonic() + self.tx_retry_s
        while True:
            try:
                self.bus.send(msg, timeout=0.0)
                self._count_sent()
                return
            except can.CanOperationError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(TX_RETRY_PAUSE_S)

    @property
    def queued(self) -> int:
        """Frames of this node not yet on the wire as far as this process knows: sent less those whose
        echo came back (socketcan's and simwire's echo is the frame as it left the wire); never less."""
        return self._sent_frames - self._own_echoes

    def offer(self, cob_id: int, data: bytes, keep: int | None = None) -> None:
        """A record: one try, and only where it leaves the queue room for the next SYNC and what must
        follow it (a FIFO queue: a SYNC cannot overtake the records before it). Refused either way, it
        stays next for a later top-up (``top_up_by_need``)."""
        spec = self.spec
        assert spec is not None
        if self.queued >= spec.tx_queue_frames - (self._reserved if keep is None else keep):
            raise RecordRefusedError(f"{self.queued} frames queued: the room left is the next SYNC's")
        try:
            self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False), timeout=0.0)
        except can.CanOperationError as exc:
            raise RecordRefusedError(str(exc)) from None
        self._count_sent()

    def _count_sent(self) -> None:
        """A frame posted now: behind the scheduled ones due by now in the queue (``_due_in``)."""
        self._due_in(time.monotonic())
        self._sent_frames += 1

    def _due_in(self, now: float) -> None:
        """The scheduled frames due by ``now`` are in the transmit queue, in order among this node's posts
        (a frame posted later is behind them): counted as sent, each SYNC's mark where its setpoints end."""
        timed, pace = self._timed, self._pace
        while timed and timed[0][0] <= now:
            _, frames, validated_by = timed.popleft()
            self._sent_frames += frames
            if pace is not None:
                pace.marks[validated_by] = self._sent_frames

    def _send_setpoint(self, cob_id: int, data: bytes) -> None:
        """A fixed-period setpoint: into the SYNC's batch for the transmit schedule while one is gathered
        (``_schedule``), else sent now (``send_now``)."""
        batch = self._batch
        if batch is None:
            self.send_now(cob_id, data)
        else:
            batch.append(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))

    def _queue_said(self) -> str:
        """The transmit queue as this process counts it, for a refusal's message."""
        said = f"{self.queued} frames of this node not yet on the wire"
        if self._own_echo_at is not None:
            said += f", the last echo {(time.monotonic() - self._own_echo_at) * 1000.0:.1f} ms ago"
        return said

    def drain(self) -> None:
        """What the bus brought since the last look (this node receives every frame): the SDO answers
        of a quick stop, and this process's own SYNC echoes. Read by the SYNC thread between SYNCs,
        not by a reader thread of its own, which would take the GIL from the SYNC thread at any instant."""
        with self._reading:
            self._due_in(time.monotonic())  # their echoes come after their due time
            while True:
                try:
                    msg = self.bus.recv(0.0)
                except (can.CanError, OSError, ValueError):
                    return
                if msg is None:
                    return
                self._take(msg)

    def _take(self, msg: can.Message) -> None:
        """One frame the bus brought (``drain``)."""
        can_id = msg.arbitration_id
        if not msg.is_rx:
            self._own_echoes += 1
            self._own_echo_at = time.monotonic()
        elif can_id == SYNC_COB_ID:  # a SYNC the interface sent: in bus order after what went before it
            self._heard.append((msg.timestamp, time.monotonic(), self._own_echoes))
        if can_id == SYNC_COB_ID and not msg.is_rx:  # our own SYNC, as it left the wire
            self._echoes += 1
            self._echo_of = (self._echoes, msg.timestamp, time.monotonic())
        elif (
            od.SDO_RESPONSE_COB_ID_BASE < can_id <= od.SDO_RESPONSE_COB_ID_BASE + od.NODE_ID_BITS
            and msg.data[:1] == _CONFIRMED
        ):
            self._confirmed.add(can_id - od.SDO_RESPONSE_COB_ID_BASE)

    # --- a run -----------------------------------------------------------------------------------
    def begin(self, spec: CycleSpec) -> None:
        """The master handed a run over: its feeders where the master's stand, and SYNC from now on."""
        production = self.prepare(spec)
        threading.Thread(target=self._produce, args=(production,), name="pvtflow-cyclic-sync", daemon=True).start()

    def prepare(self, spec: CycleSpec) -> int:
        """Build the run's feeders where the master's stand; the production's number."""
        with self.lock:
            self.spec = spec
            self.allowance = RecordAllowance(spec.records_per_sync)
            self.feeders, self.braking = [], []
            for f in spec.feeds:
                feeder: Feeder
                if f.lead is not None:
                    feeder = SetpointFeeder(f.records, f.packer, self._send_setpoint, spec.period_ms, f.lead)
                else:
                    assert f.buffer is not None
                    feeder = BufferFeeder(
                        f.records, f.packer, self.offer, spec.period_ms, f.buffer, f.capacity, self.allowance,
                        f.lookahead_ms,
                    )  # fmt: skip
                    feeder.hold_end(f.hold_end_ms)
                feeder.resume_at(f.next)
                if not f.enabled:
                    feeder.disable()
                self.feeders.append(feeder)
                self.braking.append(f.braking)
            # a SYNC, one setpoint per fixed-period axis, the time stamp
            self._reserved = 1 + sum(1 for f in spec.feeds if f.lead is not None) + int(spec.stamp_cob_id is not None)
            self.count = spec.start_count - 1
            self.start_sent = self.sent_at = self._judged = None
            self.drain()  # the echoes of SYNCs before this run are not this run's
            self._echoes, self._echo_of = 0, None
            self._heard = []
            self._timed.clear()
            self._sent_frames = self._own_echoes  # between runs the queue has long emptied: none lost is counted on
            self.timing = CycleTiming()
            self.progress[PROGRESS_RUN] = spec.run
            self._write_progress()
            self.running = True
            self._production += 1
            return self._production

    def halt(self, quick: bool) -> None:
        """The master halts the run (its halt controlwords go out from it): an axis without a ramp of its
        own brakes on the master's stop ramp from the last setpoint sent here (``axes.drive.stop_ramp``, as
        ``Profile.stop_records``), every other feeder stops."""
        with self.lock:
            for feeder, braking in zip(self.feeders, self.braking, strict=True):
                if braking is not None and isinstance(feeder, SetpointFeeder):
                    last, previous = feeder.last_commanded()
                    feeder.decelerate(braking_records(last, previous, feeder.period_ms, *braking, quick))
                else:
                    feeder.disable()

    def hold(self, t0_ms: float, grid_ms: int) -> tuple[float, list[int]]:
        """The master changes the run from ``t0_ms`` on (``axes.master.splice``): no record ending after it goes out
        from here until ``splice``; (``t0_ms``, moved past what the drives already hold onto the grid, each
        feeder's next record)."""
        with self.lock:
            held = max((float(f.records[: f.next, 2].sum()) for f in self.feeders), default=0.0)
            t0 = math.ceil(max(t0_ms, held) / grid_ms - 1e-9) * grid_ms
            for feeder in self.feeders:
                feeder.hold_to(float(t0))
            return float(t0), [f.next for f in self.feeders]

    def splice(self, changes: list[tuple[int, NDArray[np.int64]]] | None) -> None:
        """The master's new records for each feeder from its record ``first`` on (as the master's mirrors get
        them); None: the change was not made, the held records go out as they were."""
        with self.lock:
            for i, feeder in enumerate(self.feeders):
                if changes is None:
                    feeder.hold_to(None)
                else:
                    feeder.replace_from(*changes[i])
                    feeder.hold_to(None)

    def extend(self, records: list[NDArray[np.int64]]) -> bool:
        """A queued program's records (axis order) after each feeder's (``Feeder.extension``): joined to every
        feeder, or to none where one can no longer take them (its last setpoint or the EPOS2's end record out)."""
        extensions = [feeder.extension(r) for feeder, r in zip(self.feeders, records, strict=True)]
        with self.lock:
            if not self.running or not all(e.ready() for e in extensions):
                return False
            for extension in extensions:
                extension.apply()
            return True

    def stop(self) -> None:
        with self.lock:
            was, self.running = self.running, False
            self._production += 1
            task, self._task = self._task, None
            schedule, self._schedule = self._schedule, None
            self._timed.clear()
        if task is not None:  # no SYNC from the interface after this returns
            task.stop()
        if schedule is not None:  # nor a setpoint it still held (none after the last SYNC: a stale one)
            with contextlib.suppress(can.CanError, OSError):
                schedule.cancel()
        if was:
            t = self.timing
            self.tell("timing", t.late_us, t.echo_us, t.unstamped, t.refused, t.followed_us, t.held)

    # --- SYNC ------------------------------------------------------------------------------------
    def _produce(self, production: int) -> None:
        self.realtime = ask_realtime(self.priority)
        if self.realtime:  # the interface's reader (its transmit slots free on its reports): at least just below
            lift(
                [t for t in threading.enumerate() if t is not threading.current_thread() and not _fifo(t)],
                self.priority - 1,
            )
        spec = self.spec
        assert spec is not None
        period = spec.period_ms / 1000.0
        if spec.interface_sync:
            sync = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
            task = native_cyclic_task(self.bus, sync, period)
            if task is not None:
                self._follow(production, task)
                return
            self.tell("note", "the interface cannot send SYNC by itself: this process times it")
        spin = min(SPIN_BEFORE_S, period / 4)
        deadline = time.monotonic()
        try:
            while True:
                sent = None
                with self.lock:
                    if not (self.running and self._production == production):
                        return
                    now = time.monotonic()
                    if (
                        self.sent_at is not None
                        and self.sent_at != self._judged
                        and now - self.sent_at > spec.max_gap_s
                    ):
                        self._judged = self.sent_at
                        gap = now - self.sent_at
                        self.fault(
                            FaultKind.SYNC_GAP,
                            f"no SYNC for {gap * 1000:.1f} ms (the drives ride out {spec.max_gap_s * 1000:.1f} ms)",
                            None,
                            round(gap * 1000),
                        )
                    late = now - deadline
                    if self.sent_at is None or late > period / 2:  # axes.master.bus.sync's rule
                        deadline = now
                    due = deadline if self.sent_at is None else max(deadline, self.sent_at + period / 2)
                    if now >= due:
                        try:
                            self._transmit()
                        except _SyncRefusedError:
                            # the queue has no room for the SYNC now (the wire has not taken what is
                            # queued): it goes at the next try, a late SYNC, by the same rule as one
                            # whose thread woke late; a gap past what the drives ride out is reported
                            # above, and the master halts on it
                            self.timing.refused += 1
                            due = now + TX_RETRY_PAUSE_S
                        else:
                            self.timing.late_us.append((now - deadline) * 1e6)
                            sent = self.count
                            deadline += period
                            due = deadline
                if sent is not None:
                    self._follow_up(sent, min(due - spin, (self.sent_at or 0.0) + period / 2))
                self._sleep_until(due, spin)
        except _ReserveError as exc:
            self._failed(FaultKind.TX_FAILED, str(exc), exc.node_id)
        except (can.CanError, OSError) as exc:
            self._failed(FaultKind.TX_FAILED, f"SYNC {self.count + 1} or what follows it not sent: {exc}")
        except Exception as exc:  # never silent: the master halts on it
            self._failed(FaultKind.SYNC_STOPPED, f"the cyclic process's SYNC thread ended: {exc!r}")

    def _follow(self, production: int, task: can.broadcastmanager.CyclicTask) -> None:
        """The interface sends SYNC (socketcan's broadcast manager on a kernel timer; simwire: its medium,
        ``Medium.add_cyclic``), and this thread paces what follows each SYNC on the interface's own
        schedule, not on hearing it: SYNC n is due ``n`` periods after the timer started (the interface
        starts it when asked, ``task.start``), and ``PACE_AFTER_S`` after that due instant this thread
        sends the setpoints SYNC n + 1 validates, then the records. Hearing a SYNC crosses the host's
        receive path (on the served simulated wire: the drives' process and the loopback, p99 1-1.5 ms;
        bench/RESULTS.md), which a setpoint need not wait for: a frame queued after the SYNC is due goes on
        the wire after it (the SYNC's identifier wins every arbitration it is pending in, and the node's
        queue is a FIFO), so it can only be validated by the next SYNC. The SYNCs heard still serve what
        needs them: the schedule's phase follows them (the earliest any was heard, less nothing: never
        early), the time stamp (that SYNC's wire time, sent once it is heard and before the next is due),
        and the gaps.

        A period this thread wakes too late for (the next SYNC is due) sends nothing: the drives hold
        through that SYNC (``CycleTiming.held``), no second setpoint goes before one SYNC (the drive would
        take the later: a jump), and the next one sent is the next in the program
        (``SetpointFeeder.after_sync``); a SYNC heard before the setpoints sent for it were on the wire
        (this node's own echoes, in bus order before it or not) held too. Held SYNCs in a row longer than
        the drives ride out are a gap ("no setpoint"), as are SYNCs more than ``max_gap_s`` apart on the
        wire ("no SYNC")."""
        spec = self.spec
        assert spec is not None
        period = spec.period_ms / 1000.0
        after = max(PACE_AFTER_S, PACE_AFTER_PERIODS * period)
        spin = min(SPIN_BEFORE_S, period / 4)
        buffered = any(isinstance(f, BufferFeeder) for f in self.feeders)
        with self.lock:
            if not (self.running and self._production == production):
                return
            self._task = task
        with self.lock:  # a SYNC heard before the interface's timer starts is not one of its
            self.drain()
            self._heard = []
        asked = time.monotonic()
        if isinstance(task, can.broadcastmanager.RestartableCyclicTaskABC):
            task.start()  # the interface's timer starts when asked: the start SYNC is due then
        # the start SYNC's due time: where the interface says (the served medium's task), else when asked
        started = getattr(task, "started", None)
        pace = _Pace(asked if started is None else started, any(isinstance(f, SetpointFeeder) for f in self.feeders))
        self.start_sent = pace.phase  # t = 0 of the buffered drives' records
        schedule = transmit_schedule(self.bus) if pace.fixed else None
        with self.lock:
            self._pace, self._schedule = pace, schedule
        try:
            if schedule is not None:
                self._pace_scheduled(production, pace, schedule)
                return
            while True:
                self._sleep_until(pace.phase + pace.number * period + after, spin)
                with self.lock:
                    if not (self.running and self._production == production):
                        return
                    self._hear(pace)
                    now = time.monotonic()
                    behind = int((now - pace.phase) // period) - pace.number
                    if behind > 0:  # the next SYNC is due already: its setpoints would come with the one after
                        pace.number += behind
                        continue
                    number = pace.number
                    self.count = spec.start_count + number
                    self.sent_at = now
                    with sent_together(self.bus):  # one write: none stamped but unsent if held between
                        for feeder in self.feeders:
                            feeder.after_sync(number)
                    pace.marks[number + 1] = self._sent_frames
                    pace.sent_after[number + 1] = now - (pace.phase + number * period)
                    self.timing.followed_us.append((now - (pace.phase + number * period)) * 1e6)
                    if buffered:
                        self._top_up(number * spec.period_ms)
                    self._write_progress()
                    pace.number += 1
                if spec.stamp_cob_id is not None:
                    self._stamp(pace, number, pace.phase + (number + 1) * period - spin)
        except _ReserveError as exc:
            self._failed(FaultKind.TX_FAILED, str(exc), exc.node_id)
        except (can.CanError, OSError) as exc:
            self._failed(FaultKind.TX_FAILED, f"what follows SYNC {self.count} not sent: {exc}")
        except Exception as exc:  # never silent: the master halts on it
            self._failed(FaultKind.SYNC_STOPPED, f"the cyclic process's SYNC follower ended: {exc!r}")
        finally:
            with self.lock:
                mine = self._task is task
                if mine:
                    self._task = None
                if self._pace is pace:
                    self._pace = None
            if mine:
                task.stop()

    def _pace_scheduled(self, production: int, pace: _Pace, schedule: TransmitSchedule) -> None:
        """``_follow`` where the interface keeps a transmit schedule: the setpoints SYNC n + 1 validates are
        handed to it up to ``schedule_periods`` SYNCs ahead, timed ``SCHEDULE_AFTER_SYNC_S`` after SYNC n is
        due, and the interface queues them then, whatever this thread is doing (a synchronous RPDO takes the
        last setpoint before the SYNC that validates it, so each must still enter the queue in its own
        period: the schedule, not this thread, times that). This thread wakes once per period for what
        needs the present: the records for the buffered drives' clock, the time stamp of the SYNC heard,
        the gaps. What is scheduled is committed (``hold`` moves a change past it; a halt brakes from the
        last one: ``SetpointFeeder.last_commanded``); a stop takes back what is not yet due. A SYNC whose
        setpoints were not in the schedule before it was due (this thread held longer than the schedule
        reaches) went without them: the drives held, as in ``_follow``, and the marks judge it the same
        way (the setpoints' echoes before the SYNC's)."""
        spec = self.spec
        assert spec is not None
        period = spec.period_ms / 1000.0
        after = max(PACE_AFTER_S, PACE_AFTER_PERIODS * period)
        spin = min(SPIN_BEFORE_S, period / 4)
        ahead = schedule_periods(spec.period_ms, spec.max_lookahead_ms)
        buffered = any(isinstance(f, BufferFeeder) for f in self.feeders)
        current = 0  # the SYNC whose period this is (the last one due)
        first = True  # the start SYNC's period: its setpoints at once, not a wake later
        while True:
            if not first:
                self._sleep_until(pace.phase + current * period + after, spin)
            first = False
            with self.lock:
                if not (self.running and self._production == production):
                    return
                self._hear(pace)
                now = time.monotonic()
                current = max(current, int((now - pace.phase) // period))
                # a batch for a SYNC already due would be validated by the one after it, with that one's
                pace.number = max(pace.number, current)
                while pace.number < current + ahead:
                    self._schedule_setpoints(pace, schedule, pace.number, now)
                    pace.number += 1
                self.count = spec.start_count + current
                self.sent_at = now
                if buffered:
                    self._top_up(current * spec.period_ms)
                self._write_progress()
            if spec.stamp_cob_id is not None:
                self._stamp(pace, current, pace.phase + (current + 1) * period - spin)
            current += 1

    def _schedule_setpoints(self, pace: _Pace, schedule: TransmitSchedule, number: int, now: float) -> None:
        """The setpoints SYNC ``number`` + 1 validates, to the transmit schedule just after SYNC ``number`` is
        due (lock held)."""
        spec = self.spec
        assert spec is not None
        due = pace.phase + number * spec.period_ms / 1000.0
        self._batch = batch = []
        try:
            for feeder in self.feeders:
                feeder.after_sync(number)
        finally:
            self._batch = None
        at = due + SCHEDULE_AFTER_SYNC_S
        if batch:
            schedule.post(batch, at)
        self._timed.append((at, len(batch), number + 1))
        pace.sent_after[number + 1] = now - due
        self.timing.followed_us.append((now - due) * 1e6)

    def _hear(self, pace: _Pace) -> None:
        """The SYNCs the bus brought since the last look, in bus order (lock held): the schedule's phase,
        which SYNCs held, the gaps."""
        spec = self.spec
        assert spec is not None
        period = spec.period_ms / 1000.0
        self.drain()
        heard, self._heard = self._heard, []
        now = time.monotonic()
        for wire, arrived, echoes in heard:
            # its number from its wire time: a SYNC the interface dropped (its queue full) has none
            last = pace.last_wire
            n = 0 if last is None else pace.heard - 1 + max(1, round((wire - last) / period))
            # never early: a SYNC is heard after it was due (the timer runs on this host's clock: the
            # kernel's, the medium's), so no SYNC was due later than its arrival says
            pace.phase = min(pace.phase, arrived - n * period)
            if n:
                if last is not None and wire - last > spec.max_gap_s:
                    self._gap("no SYNC", wire - last)
                after = pace.sent_after.pop(n, None)
                if pace.fixed and echoes < pace.marks.pop(n, _NEVER):  # its setpoints were not on the wire
                    pace.unfed += 1
                    pace.unfed_after.append(after)
                    self.timing.held += 1
                    if (pace.unfed + 1) * period > spec.max_gap_s >= pace.unfed * period:
                        self._gap("no setpoint", (pace.unfed + 1) * period, _sent_after(pace.unfed_after))
                else:
                    pace.unfed = 0
                    pace.unfed_after.clear()
            for skipped in range(pace.heard, n):  # no SYNC came for them
                pace.marks.pop(skipped, None)
                pace.sent_after.pop(skipped, None)
            pace.last_wire = wire
            pace.heard = n + 1
        if heard:
            pace.silent, pace.heard_at = False, now
        elif not pace.silent and now - pace.heard_at > spec.max_gap_s + SILENCE_GRACE_S:
            pace.silent = True
            self._gap("no SYNC heard", now - pace.heard_at)

    @staticmethod
    def _sleep_until(due: float, spin: float) -> None:
        """Asleep until ``spin`` before ``due``, then awake up to it (a timer's wake is that late)."""
        delay = due - time.monotonic() - spin
        if delay > 0:
            time.sleep(delay)
        while time.monotonic() < due:
            pass

    def _stamp(self, pace: _Pace, number: int, until: float) -> None:
        """The time stamp of SYNC ``number`` (0x1013: its wire time), once it is heard and before ``until``
        (the next SYNC's due instant less the wake's margin): the drive latches its clock at each SYNC and
        corrects it by the stamp that follows (app note "Clock synchronization"), so a stamp after the
        next SYNC would be read as that one's. Not heard by then: no stamp for it (counted)."""
        spec = self.spec
        assert spec is not None and spec.stamp_cob_id is not None
        while True:
            with self.lock:
                if not self.running:
                    return
                self._hear(pace)
                if pace.heard > number:
                    if pace.heard == number + 1 and pace.last_wire is not None:
                        stamp = struct.pack("<I", round(pace.last_wire * 1e6) & 0xFFFFFFFF)
                        try:
                            self.offer(spec.stamp_cob_id, stamp, keep=0)
                            return
                        except RecordRefusedError:
                            pass
                    self.timing.unstamped += 1
                    return
            if time.monotonic() >= until:
                self.timing.unstamped += 1
                return
            time.sleep(ECHO_POLL_S)

    def _gap(self, what: str, gap_s: float, detail: str = "") -> None:
        spec = self.spec
        assert spec is not None
        ride_ms = spec.max_gap_s * 1000
        self.fault(
            FaultKind.SYNC_GAP,
            f"{what} for {gap_s * 1000:.1f} ms (the drives ride out {ride_ms:.1f} ms{'; ' + detail if detail else ''})",
            None,
            round(gap_s * 1000),
        )

    def _failed(self, kind: FaultKind, why: str, node_id: int | None = None) -> None:
        """This process cannot go on: no more SYNC, every drive quick stopped from here, the master told."""
        self.stop()
        self.quick_stop_all(why)
        self.fault(kind, why, node_id)

    def _transmit(self) -> None:
        """One SYNC and what follows it (lock held): the setpoints first, then the records."""
        spec = self.spec
        assert spec is not None
        try:
            self.bus.send(can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False), timeout=0.0)
        except can.CanOperationError as exc:
            raise _SyncRefusedError(str(exc)) from None
        self._sent_frames += 1
        now = time.monotonic()
        self.sent_at = now
        self.count += 1
        elapsed = self.count - spec.start_count
        if elapsed == 0:
            self.start_sent = now  # t = 0 of the buffered drives' records
        for feeder in self.feeders:
            feeder.after_sync(elapsed)  # the fixed-period setpoints: before the next SYNC, whatever else
        if self.start_sent is not None and any(isinstance(f, BufferFeeder) for f in self.feeders):
            self.drain()  # the echoes so far: how much of the queue is free for records
            self._top_up((now - self.start_sent) * 1000.0)
        self._write_progress()

    def _top_up(self, elapsed_ms: float) -> None:
        """The buffered drives' records for their clock at ``elapsed_ms`` from the start SYNC, as much as
        this period's allowance has room for; _ReserveError where the queue refuses a drive below its reserve."""
        spec = self.spec
        assert spec is not None
        for feeder in self.feeders:
            if isinstance(feeder, BufferFeeder):
                feeder.run_to(elapsed_ms)
        self.allowance.at_sync(self.count)
        refused = top_up_by_need(self.feeders, self.allowance)
        if refused is not None and refused.level < refused.reserve:
            node = spec.feeds[self.feeders.index(refused)].node_id
            raise _ReserveError(
                node,
                f"records refused by the transmit queue while node {node}'s FIFO is at {refused.level} "
                f"records, below its reserve {refused.reserve} ({self._queue_said()})",
            )

    def _follow_up(self, number: int, until: float) -> None:
        """After SYNC ``number`` and its frames: its echo, then the time stamp (0x1013) that says when it
        left the wire (the echo's time stamp: the end of its frame, where the EPOS2 latches its clock,
        app note "Clock synchronization"), before the next SYNC. No echo by ``until``: no stamp for it
        (the drive keeps its clock's rate; counted)."""
        spec = self.spec
        assert spec is not None
        while True:
            self.drain()
            echo = self._echo_of
            if echo is not None and echo[0] >= number - spec.start_count + 1:
                break
            if time.monotonic() >= until:
                self.timing.unstamped += 1
                return
            time.sleep(ECHO_POLL_S)
        _, left_wire, heard_at = echo
        self.timing.echo_us.append((heard_at - (self.sent_at or heard_at)) * 1e6)
        if spec.stamp_cob_id is not None:
            with self.lock:
                if self.running:  # offered once: a stamp missed leaves the drive's clock rate as it is
                    try:
                        stamp = struct.pack("<I", round(left_wire * 1e6) & 0xFFFFFFFF)
                        self.offer(spec.stamp_cob_id, stamp, keep=self._reserved - 1)  # its own place kept
                    except RecordRefusedError:
                        self.timing.unstamped += 1

    def _write_progress(self) -> None:
        p = self.progress
        p[PROGRESS_COUNT] = self.count
        for i, feeder in enumerate(self.feeders[:MAX_FEEDS]):
            p[PROGRESS_FEEDERS + i] = feeder.next

    # --- the quick stop that needs no SYNC and no master ----------------------------------------
    def quick_stop_all(self, reason: str, node_ids: list[int] | None = None) -> None:
        """The SDO quick stop requests to every drive now, NMT stop to those that do not confirm within
        ``quick_stop_confirm_s`` (``axes.master.bus.quick_stop``'s rule), from this process alone."""
        nodes = node_ids if node_ids is not None else [f.node_id for f in (self.spec.feeds if self.spec else [])]
        self.drain()  # what came before the requests
        self._confirmed.clear()
        request = quick_stop_request()
        for node in nodes:
            with contextlib.suppress(can.CanError, OSError):  # not sent: NMT stop below, or the heartbeat's loss
                self.send_now(od.SDO_REQUEST_COB_ID_BASE + node, request)
        deadline = time.monotonic() + self.quick_stop_confirm_s
        while not all(n in self._confirmed for n in nodes) and time.monotonic() < deadline:
            time.sleep(TX_RETRY_PAUSE_S)
            self.drain()
        missing = [n for n in nodes if n not in self._confirmed]
        for node in missing:
            with contextlib.suppress(can.CanError, OSError):
                self.send_now(0, bytes([NmtCommand.STOP, node]))
        self.tell("quick_stopped", reason, sorted(set(nodes) - set(missing)), missing)


@dataclass
class _Pace:
    """What the follower of the interface's SYNC knows of its schedule (``CyclicLoop._follow``)."""

    started: float  # when the interface's timer was started (``time.monotonic``)
    fixed: bool  # the run has fixed-period axes (setpoints every SYNC)
    phase: float = 0.0  # SYNC 0's due instant on this host's clock, never earlier than the truth
    number: int = 0  # the SYNC whose setpoints (those validated by the SYNC after it) go next
    heard: int = 0  # the number of the last SYNC heard, plus 1 (0: none yet)
    last_wire: float | None = None  # the last heard SYNC's wire time
    heard_at: float = 0.0  # when the last SYNCs were heard here
    silent: bool = False  # a silence of the interface was reported
    unfed: int = 0  # SYNCs in a row heard before their setpoints were on the wire
    marks: dict[int, int] = field(default_factory=dict)  # SYNC n -> frames sent up to the setpoints it validates
    # SYNC n -> how long after SYNC n - 1 was due its setpoints were sent (s); and those of the unfed SYNCs
    sent_after: dict[int, float] = field(default_factory=dict)
    unfed_after: list[float | None] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.phase = self.heard_at = self.started


_NEVER = 1 << 62  # no setpoints were sent for that SYNC


def _sent_after(after: list[float | None]) -> str:
    """When the setpoints of the SYNCs that held were sent, after the SYNC before each was due."""
    said = ", ".join(
        "not sent"
        if a is None
        else f"sent {a * 1000:.2f} ms after the SYNC before was due"
        if a >= 0
        else f"scheduled {-a * 1000:.2f} ms before the SYNC before was due"
        for a in after
    )
    return f"the setpoints for those SYNCs: {said}"


class _SyncRefusedError(Exception):
    """The transmit queue has no room for a SYNC now."""


class _ReserveError(Exception):
    """A record refused while its drive's FIFO is below the reserve: the run cannot go on."""

    def __init__(self, node_id: int, why: str) -> None:
        super().__init__(why)
        self.node_id = node_id


_CONFIRMED = bytes([SDO_DOWNLOAD_CONFIRMED])


def _fifo(thread: threading.Thread) -> bool:
    """Already real time (simwire's reader asks for a priority above SYNC's: axes/sim/wire/priority.py)."""
    try:
        return thread.native_id is not None and os.sched_getscheduler(thread.native_id) == os.SCHED_FIFO
    except (AttributeError, OSError):
        return False


def serve_cyclic(
    conn: Connection,
    bus_kwargs: dict[str, object],
    progress: Any,
    priority: int,
    tx_retry_s: float,
    quick_stop_confirm_s: float,
) -> None:
    """The child process's main: open the bus, say ready, obey the master's commands until it closes."""
    import gc
    import sys

    sys.setswitchinterval(1e-4)  # a waiting thread gets the GIL within 0.1 ms, not CPython's 5 ms (CellBus.open)
    try:
        bus = can.Bus(**bus_kwargs)
    except Exception as exc:  # told to the master, which refuses to open the bus
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    loop = CyclicLoop(bus, conn, progress, priority, tx_retry_s, quick_stop_confirm_s)
    gc.freeze()  # what the start loaded is never collected: no long collection while SYNC runs
    loop.tell("ready")
    try:
        while True:
            try:
                command, *args = conn.recv()
            except (EOFError, OSError):  # the master is gone: nobody halts the drives but this process
                if loop.running:
                    loop.stop()
                    loop.quick_stop_all("the master process is gone")
                return
            if command == "start":
                loop.begin(args[0])
            elif command == "halt":
                loop.halt(bool(args[0]))
            elif command == "hold":  # a change of the run (axes.master.splice): answered at once
                loop.tell("held", args[0], *loop.hold(args[1], args[2]))
            elif command == "splice":
                loop.splice(args[0])
            elif command == "extend":  # a queued program (axes.master.run_queue): answered at once
                loop.tell("extended", args[0], loop.extend(args[1]))
            elif command == "stop":
                loop.stop()
            elif command == "quick_stop":
                loop.stop()
                threading.Thread(target=loop.quick_stop_all, args=(args[0], list(args[1])), daemon=True).start()
            elif command == "close":
                loop.stop()
                return
    finally:
        bus.shutdown()
