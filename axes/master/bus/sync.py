"""SYNC: the master's production of it and its count of the drives' answers.

SYNC has two modes (``CellBus(clock=Clock.LOCKSTEP | Clock.WALL)``, ``axes.canbus.clock``):

- real time: SYNC every ``sync_period_ms`` of wall-clock time, followed by the 0x1013 time stamp and
  the frames that must follow every SYNC (a fixed-period drive's setpoints: ``add_sender``), so a
  setpoint is on the bus a whole period before the SYNC that validates it. Where the interface sends
  SYNC cyclically by itself, it does, and a master thread follows each SYNC the bus hears
  (``axes.master.bus.sync_follower``). Elsewhere (virtual, pcan) a master thread sends SYNC on absolute
  deadlines. A SYNC more than half a period late goes out at once and the deadlines after it keep the
  period from it (the whole periods lost are counted: ``skipped``): a fixed-period drive holds
  through the delay (a gap of one period plus the delay, not the two periods that waiting for the
  next deadline would make), and never takes two setpoints in one period, as it would from a
  catch-up burst. No SYNC goes out within half a period of the one before. The thread asks for
  SCHED_FIFO (``BusConfig.sync_priority``; not permitted: one warning, normal priority); granted, the
  bus's other threads (``CellBus.threads``) are lifted to SCHED_FIFO one below it (``lift``), since
  any of them preempted by another process while it holds the GIL would hold SYNC up for a
  scheduler slice (priority inversion through the GIL; measured in bench/sync_jitter.py).
  On a host of two or more CPUs, two threads produce SYNC (``SyncClock.backup``), each pinned to a
  CPU of its own: the second wakes ``BACKUP_AFTER`` of a period after each deadline and sends the
  SYNC the first has not sent by then (the deadlines, the skip rule and the gap judgement are
  shared, under the SYNC lock: one SYNC per deadline whoever sends it). Measured
  (bench/RESULTS.md, "Issue 23: SYNC under load"): the host stalls the timer wake-up of one
  CPU at a time for about 4 ms (a bare SCHED_FIFO sleep loop in a process of its own shows it), and
  a second thread on the other CPU covers it. What no thread of this process can cover is a
  normal-priority thread of the same interpreter preempted while it holds the GIL (the SYNC thread
  waits for it a scheduler slice): the thread that starts a motion and waits on it runs just below
  SYNC meanwhile (``below_sync``); other Python work of this process beside a motion (planning,
  zenoh's callbacks) is not covered: only SYNC in a process, or an interface, of its own would be.
  A gap longer than the drives ride out is reported (``FaultKind.SYNC_GAP``, the gap in ms), before
  the thread sends the SYNC after it (the halt the report causes comes first): the
  rule is ``BusConfig.max_sync_gap_periods`` when the cell sets it, else the profiles' (``Profile.
  max_sync_gap_ms``): 2 periods for a drive that takes one setpoint per SYNC (one SYNC skipped
  makes it hold one period, more would be a jump), and for the EPOS2, which runs its records on
  its own clock and only loses its feed in a gap, the time of its program's shortest run of
  ``underflow_warning`` records (the FIFO reserve its feeder keeps). The SYNC thread never ends
  silently: a frame the interface refuses past ``tx_retry_ms`` of retries (``TX_FAILED``) or any
  other error (``SYNC_STOPPED``) is reported, and the group then quick stops every axis by SDO
  (``axes.master.bus.quick_stop``), which does not need SYNC.
- lockstep (simulation): the next SYNC goes out once every drive has answered the previous one with
  its synchronous TPDO and the SYNC listeners (the feeders) have run (a drive whose status TPDO goes
  out every n SYNCs is waited for on the SYNCs it owes an answer for: ``SyncClock.expect``). Drive
  time advances one period per SYNC, so a simulated cell runs as fast as the bus and the CPU allow,
  and nothing depends on a sleep. The same answer counting runs in real time and gives the SYNC count there too.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import struct
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import can

from pvtflow.axes.canbus import collector
from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.axes.master.bus.faults import BusFault, FaultCallback, FaultKind
from pvtflow.axes.master.bus.sync_follower import SyncFollower, native_cyclic_task

if TYPE_CHECKING:
    from pvtflow.axes.master.bus.network import LoggingNetwork

SyncCallback = Callable[[int], None]


class CyclicPath(Protocol):
    """The cyclic path in a process of its own as the clock drives it (``axes.master.cyclic.process``)."""

    producing: bool

    @property
    def handed_over(self) -> bool: ...

    def produce(self, clock: SyncClock, production: int) -> None: ...

    def quick_stop(self, reason: str, node_ids: Sequence[int]) -> None: ...

    def hold(self, t0_ms: float, grid_ms: int, timeout_s: float) -> tuple[float, list[int]]: ...

    def splice(self, changes: Sequence[tuple[int, Any]] | None) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


BACKUP_AFTER = 0.25  # the second SYNC thread sends what the first has not this far past a deadline (periods)
DEFAULT_MAX_GAP_PERIODS = 2.0  # a fixed-period drive misses a setpoint in a longer gap (module docstring)

log = logging.getLogger("pvtflow.bus")


_realtime_warned = False


def ask_realtime(priority: int) -> bool:
    """SCHED_FIFO at ``priority`` for the calling thread (Linux applies it to the thread, not the
    process). Not permitted (EPERM), or no such call on this OS: one warning per process, and the
    thread runs at normal priority. ``priority`` 0: not asked."""
    global _realtime_warned
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (AttributeError, OSError) as exc:  # AttributeError: no SCHED_FIFO on this OS
        if not _realtime_warned:
            _realtime_warned = True
            log.warning(
                "SYNC runs at normal priority: SCHED_FIFO %d not granted (%s); permit it with root, "
                "CAP_SYS_NICE or an rtprio limit (docs/wall-clock.md), or set sync_priority: 0",
                priority,
                exc,
            )
        return False


def lift(threads: Iterable[threading.Thread], priority: int) -> list[str]:
    """SCHED_FIFO at ``priority`` for these threads, those this process did not start for SYNC too (the
    notifier's reader): Linux schedules threads, not processes, by their native id. The names of the
    threads lifted; one not permitted, or gone, is left as it is (no warning: ``ask_realtime`` gave it)."""
    lifted = []
    for thread in threads:
        if priority <= 0 or not thread.is_alive() or thread.native_id is None:
            continue
        try:
            os.sched_setscheduler(thread.native_id, os.SCHED_FIFO, os.sched_param(priority))
        except (AttributeError, OSError):
            continue
        lifted.append(thread.name)
    return lifted


def producer_cpus() -> list[int]:
    """The CPUs the SYNC threads are pinned to, one each: two of those this process may run on
    (empty on a host of one CPU, or an OS without affinity: then one thread, unpinned)."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []
    return cpus[:2] if len(cpus) >= 2 else []


def pin(cpu: int | None) -> None:
    """The calling thread to ``cpu`` (None, or not permitted: left where it is)."""
    if cpu is None:
        return
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {cpu})


class below_sync:  # noqa: N801  (a context manager, used as ``with below_sync(clock):``)
    """The calling thread at SCHED_FIFO just below the bus's threads while it starts a motion and
    waits on it, when SYNC runs on the wall clock with SCHED_FIFO (or may yet get it) and the bus's
    threads are lifted (``SyncClock.lift_bus_threads``); its own policy again after. A thread
    of normal priority of this interpreter that runs (the start, a poll, a timeout) takes the GIL,
    and preempted by another process while it holds it, holds SYNC up for a scheduler slice:
    measured 3-7 ms (bench/RESULTS.md, "Issue 23: SYNC under load"). At real time, it runs through
    and gives the GIL back. Keep it to starting and waiting: planning at SCHED_FIFO would starve the host.
    A thread started meanwhile inherits the policy (Linux: the group's SDO pool threads, when a start
    is the first to use them), and keeps it: they serve the bus."""

    def __init__(self, sync: SyncClock) -> None:
        self.sync = sync
        self._before: tuple[int, os.sched_param] | None = None

    def __enter__(self) -> below_sync:
        sync = self.sync
        priority = sync.priority - 2
        # realtime None: not known yet, asked (refused: no harm). Lockstep has no SYNC thread to keep;
        # where the bus's threads stay at normal priority (the drives in this interpreter), so does it
        if sync.clock.lockstep or not sync.lift_bus_threads or sync.realtime is False or priority <= 0:
            return self
        try:
            before = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (AttributeError, OSError):
            return self
        self._before = before
        return self

    def __exit__(self, *exc: object) -> None:
        if self._before is not None:
            policy, param = self._before
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, policy, param)
            self._before = None


class SyncClock:
    """SYNC producer and counter of the drives' answers (see the module docstring for the modes).

    ``count`` is the number of SYNCs sent, ``answered`` the number every expected node has answered.
    Listeners get the number of the SYNC just answered; in lockstep they run before the next SYNC.
    On the wall clock: ``skipped`` whole periods lost to late SYNCs (never caught up; where the
    interface sends SYNC, the SYNCs that went out without a setpoint: ``axes.master.bus.sync_follower``),
    ``longest_gap_s``
    the longest time between two SYNCs, ``max_gap_s`` the gap that is reported (``FaultKind.SYNC_GAP``),
    ``realtime`` whether the sending thread got SCHED_FIFO, ``native`` whether the interface sends SYNC.
    """

    def __init__(
        self,
        network: LoggingNetwork,
        report: FaultCallback,
        period_ms: float,
        clock: Clock,
        time_stamp_cob_id: int | None = None,
        priority: int = 0,
        max_gap_periods: float = DEFAULT_MAX_GAP_PERIODS,
        threads: Callable[[], list[threading.Thread]] = list,
    ):
        # what the clock needs of the bus, handed in (python-canopen's parts hold the network, not the node)
        self.network = network
        self.report = report
        self.bus_threads = threads  # the bus's other threads, lifted below SYNC (``CellBus.threads``)
        self.period_ms = period_ms
        self.clock = clock
        self.time_stamp_cob_id = time_stamp_cob_id
        self.priority = priority
        self.bus_max_gap_s = max_gap_periods * period_ms / 1000.0  # the bus's own (BusConfig.max_sync_gap_periods)
        # this production's: each ``start`` sets it (a gap judged as a production stops keeps the threshold it ran on)
        self.max_gap_s = self.bus_max_gap_s
        self.count = 0
        self.answered = 0
        self.skipped = 0
        # some drive takes a setpoint per SYNC (a fixed-period profile): SYNCs the follower did not
        # follow are a gap it rides out or not; buffered drives only miss a time stamp (``AxisGroup``)
        self.setpoints_per_sync = True
        self.longest_gap_s = 0.0
        self.realtime: bool | None = None  # None: no SYNC thread has run yet
        self.native = False
        self.last_progress = time.monotonic()
        self._answers: dict[int, int] = {}  # cob id -> the last SYNC its answers stand for
        self._every: dict[int, int] = {}  # cob id -> the SYNCs one answer stands for (transmission type n)
        self._completing = False  # _complete is running (it sends the next lockstep SYNC itself)
        self._listeners: list[SyncCallback] = []
        self._senders: list[SyncCallback] = []  # run right after each SYNC goes out, by whoever sends it
        self.lock = threading.RLock()  # held while SYNC listeners run and while a SYNC goes out
        self._answered_changed = threading.Condition(self.lock)
        self.last_sent = time.monotonic()  # when the last SYNC went out
        self.sent_at: float | None = None  # when this production's last SYNC went out (gaps)
        self._running = False
        self._production = 0  # which start() the producing thread serves: a stale one stops by itself
        self._collector_held = False  # this clock holds the cyclic collector off (wall clock, running)
        self._t0_us = time.monotonic_ns() // 1000
        self.follower = SyncFollower(self)  # where the interface sends SYNC (``native``)
        # benchmarks and tests: called before each wall-clock SYNC, and before the follower follows
        self.hold: Callable[[], None] | None = None
        self.lift_bus_threads = True  # the bus's threads follow SYNC to SCHED_FIFO (BusConfig.lift_bus_threads)
        self.lifted: list[str] = []  # the threads lifted below SYNC's priority (``CellBus.threads``)
        self.backup = True  # a second SYNC thread on another CPU (module docstring; one CPU: never)
        self._deadline = 0.0  # the next SYNC's deadline, shared by the producing threads
        self._judged: float | None = None  # the SYNC whose gap was reported before the next went out
        # the wall clock's cyclic path in a process of its own (``axes.master.cyclic.process``;
        # None: this one's threads)
        self.cyclic: CyclicPath | None = None

    # --- answers ---------------------------------------------------------------------------------
    def expect(self, answers: Iterable[int] | Mapping[int, int]) -> None:
        """The synchronous TPDOs that answer SYNC (one per drive): COB-IDs, or COB-ID -> n for a TPDO
        of transmission type n (``axes.master.tpdo_rates``), which answers once in every n SYNCs. The master
        takes an answer as standing for the SYNC it arrived after and the n - 1 after that, and, not
        knowing where a drive's SYNC counter stands, a new expectation as standing for the next n - 1:
        never less than the drive's answers cover, so lockstep never waits for an answer a drive does
        not owe (it waits at the latest on the n-th SYNC, which every drive has answered by then).
        Call it after the links have subscribed their TPDO decoders: an answer is then decoded
        before it is counted, so whoever waits for a SYNC's answers (``wait_answered``) reads what
        the drives said on it."""
        every = dict(answers) if isinstance(answers, Mapping) else dict.fromkeys(answers, 1)
        with self.lock:
            for cob in self._answers:
                unsubscribe(self.network, cob, self._on_answer)
            self._every = every
            self._answers = {cob: self.count + n - 1 for cob, n in every.items()}
            self.answered = self.count
            for cob in self._answers:
                subscribe(self.network, cob, self._on_answer)

    def _done(self) -> int:
        """The last SYNC every drive has answered or owes no answer for (never past the SYNCs sent)."""
        return min(min(v, self.count) if self._every.get(c, 1) > 1 else v for c, v in self._answers.items())

    def add_listener(self, callback: SyncCallback) -> None:
        self._listeners.append(callback)

    def remove_listener(self, callback: SyncCallback) -> None:
        if callback in self._listeners:
            self._listeners.remove(callback)

    def add_sender(self, callback: SyncCallback) -> None:
        """``callback(n)`` right after SYNC number ``n`` is on the bus, in the thread that sent it and
        before the next SYNC can go out: what must be on the bus before SYNC n + 1 (a fixed-period
        drive's next setpoint) is sent there, never paced by the drives' answers, so the wall clock
        cannot make it late. Keep it to sending precomputed frames."""
        with self.lock:
            self._senders.append(callback)

    def remove_sender(self, callback: SyncCallback) -> None:
        with self.lock:
            if callback in self._senders:
                self._senders.remove(callback)

    def behind(self) -> list[int]:
        """COB-IDs of the answers still missing for the last SYNC sent."""
        with self.lock:
            return [cob for cob, n in self._answers.items() if n < self.count]

    def _on_answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            n = self._answers.get(can_id)
            every = self._every.get(can_id, 1)
            if n is None or (self.clock.lockstep and every == 1 and n >= self.count):
                return  # an answer without a SYNC (or a duplicate): nothing to count
            # an answer of type n stands for the last SYNC sent and the n - 1 after it
            self._answers[can_id] = n + 1 if every == 1 else max(n, self.count + every - 1)
            self._answered_changed.notify_all()
            failed = self._complete()
        if failed is not None:
            self.report(failed)

    def _complete(self) -> BusFault | None:
        """Advance ``answered`` to every SYNC answered or owed no answer, run the listeners on it and,
        in lockstep, send the next SYNC (again while no drive owes an answer for it). Called with the
        lock held; a fault to report (after the lock is released) or None."""
        if self._completing:
            return None
        self._completing = True
        done = self.answered
        try:  # a frame a listener cannot send must not end the bus's receive thread
            while True:
                done = self._done()
                if done <= self.answered:
                    return None
                self.answered = done
                self.count = max(self.count, done)
                self.last_progress = time.monotonic()
                for cb in list(self._listeners):
                    cb(done)
                if not (self.clock.lockstep and self._running and self.answered == self.count):
                    return None
                self.transmit()
        except (can.CanError, OSError) as exc:
            self._running = False
            self._production += 1
            return BusFault(FaultKind.TX_FAILED, None, f"after SYNC {done}: {exc}")
        except Exception as exc:
            log.exception("a SYNC listener failed")
            self._running = False
            self._production += 1
            return BusFault(FaultKind.SYNC_STOPPED, None, f"SYNC ended after SYNC {done}: {exc!r}")
        finally:
            self._completing = False

    # --- production ------------------------------------------------------------------------------
    def transmit(self, sync_frame: bool = True) -> None:
        """SYNC (unless the interface sent it: ``sync_frame`` False), the time stamp, the senders."""
        with self.lock:
            self.count += 1
            with self.network.together():  # one write where the interface takes a run of frames
                if sync_frame:
                    self.network.send_message(SYNC_COB_ID, b"")
                # taken once the SYNC is sent (the senders below see this SYNC's time): a thread preempted
                # between the decision and the send would otherwise let the next SYNC follow this one
                # within half a period on the bus
                self._went_out(time.monotonic())
                if self.time_stamp_cob_id is not None:
                    stamp = (time.monotonic_ns() // 1000 - self._t0_us) & 0xFFFFFFFF
                    self.network.send_message(self.time_stamp_cob_id, struct.pack("<I", stamp))
                for send in self._senders:
                    send(self.count)
            if not self._completing and any(n > 1 for n in self._every.values()):
                # drives whose status TPDO goes out every n SYNCs may owe no answer for this one: its
                # listeners run now, in the sending thread, as no answer will bring them
                failed = self._complete()
                if failed is not None:
                    self.report(failed)

    def _went_out(self, now: float) -> None:
        """A SYNC left at ``now``: the gap since the last one counts (lock held)."""
        self.last_sent = now
        if self.sent_at is not None:
            self.longest_gap_s = max(self.longest_gap_s, now - self.sent_at)
        self.sent_at = now

    def heard(self, production: int) -> None:
        """A SYNC the cyclic process sent, heard on the bus (``axes.master.cyclic.process``): counted as
        ``transmit`` counts one, and the senders told (they send nothing then: the child did)."""
        failed = None
        with self.lock:
            if not self.producing(production):
                return
            self.count += 1
            self._went_out(time.monotonic())
            for send in self._senders:
                send(self.count)
            if not self._completing and any(n > 1 for n in self._every.values()):
                failed = self._complete()
        if failed is not None:
            self.report(failed)

    @property
    def cyclic_producing(self) -> bool:
        """SYNC and what follows it come from the cyclic process (the master's feeders only mirror it)."""
        return self.cyclic is not None and self.cyclic.producing

    def progressed(self) -> None:
        """The drives' answers count as progress from now (``BusWatch`` arms its watch on it)."""
        self.last_progress = time.monotonic()

    def start(self, max_gap_s: float | None = None, *, setpoints_per_sync: bool | None = None) -> None:
        """Send the first SYNC now and keep producing (lockstep: on answers; real time: periodic).
        ``max_gap_s``: the gap this production reports (a run's profiles ride out less than the bus's
        default, ``Profile.max_sync_gap_ms``); None: the bus's own (homing, a run on a bus that sets one).
        ``setpoints_per_sync``: whether some drive of this production takes a setpoint per SYNC (None: as
        the last production said)."""
        with self.lock:
            if setpoints_per_sync is not None:
                self.setpoints_per_sync = setpoints_per_sync
            self.max_gap_s = self.bus_max_gap_s if max_gap_s is None else max_gap_s
            if self._running:
                return
            self._running = True
            self.sent_at = None
            self.follower.reset()
            self.last_progress = time.monotonic()
            if self.clock.lockstep:
                try:
                    self.transmit()
                except (can.CanError, OSError):
                    self._running = False
                    raise
                if not self._answers:  # nobody to wait for: a single SYNC
                    self._running = False
                return
            production = self._production
            if not self._collector_held:
                collector.hold()  # no collection pause while SYNC runs on the wall clock (axes/canbus/collector.py)
                self._collector_held = True
            if self.cyclic is not None and self.cyclic.handed_over:
                self.native = False
                # the child sends SYNC; this process still answers the drives, watches their heartbeats, sends
                # its own and mirrors the feeders: its bus threads run as they do below a SYNC thread of its own
                if self.lift_bus_threads and self.priority > 0:
                    self.lifted = lift(self.bus_threads(), self.priority - 1)
                self.cyclic.produce(self, production)  # each SYNC heard: ``heard``
                return
            msg = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
            assert self.network.bus is not None
            self.follower.task = native_cyclic_task(self.network.bus, msg, self.period_ms / 1000.0)
            self.native = self.follower.task is not None
            self._deadline, self._judged = time.monotonic(), None
        cpus = producer_cpus() if self.backup else []
        if (
            self.native
        ):  # one follower: a second one, measured, only took the GIL from the first (axes.master.bus.sync_follower)
            threads = [("pvtflow-sync-follow", self.follower.follow, None)]
        else:
            threads = [("pvtflow-sync", self._produce, cpus[0] if cpus else None)]
            if cpus:
                threads.append(("pvtflow-sync-backup", self._produce_backup, cpus[1]))
        for name, target, cpu in threads:
            threading.Thread(target=self._guarded, args=(target, production, cpu), name=name, daemon=True).start()

    def producing(self, production: int) -> bool:
        """Still the production this thread was started for (called with the lock held)."""
        return self._running and self._production == production

    def _guarded(self, target: Callable[[int], None], production: int, cpu: int | None = None) -> None:
        """The SYNC thread never ends silently: a send that fails past its retries, or any error,
        ends the production and is reported (the motion halts without SYNC: ``axes.master.bus.quick_stop``)."""
        pin(cpu)
        self.realtime = ask_realtime(self.priority)
        if self.realtime and self.lift_bus_threads:
            self.lifted = lift(self.bus_threads(), self.priority - 1)
        try:
            target(production)
        except (can.CanError, OSError) as exc:
            self._fail(production, BusFault(FaultKind.TX_FAILED, None, f"SYNC {self.count + 1} not sent: {exc}"))
        except Exception as exc:
            # reported first: the halt it causes does not wait for the traceback to be written
            self._fail(production, BusFault(FaultKind.SYNC_STOPPED, None, f"the SYNC thread ended: {exc!r}"))
            log.exception("the SYNC thread failed")

    def _fail(self, production: int, fault: BusFault) -> None:
        with self.lock:
            if not self.producing(production):
                return  # stopped meanwhile: nothing of this production is wanted any more
            self._running = False
            self._production += 1
        self.report(fault)

    def report_gap(self, gap_s: float, what: str = "no SYNC") -> None:
        """Report a gap the drives do not ride out (called without the lock): between two SYNCs, or
        (``what`` "no setpoint") between two setpoints, where SYNCs went out without one
        (``axes.master.bus.sync_follower``)."""
        if gap_s > self.max_gap_s:
            self.report(
                BusFault(
                    FaultKind.SYNC_GAP,
                    None,
                    f"{what} for {gap_s * 1000:.1f} ms (the drives ride out {self.max_gap_s * 1000:.1f} ms)",
                    round(gap_s * 1000),
                )
            )

    def _produce_backup(self, production: int) -> None:
        """The second SYNC thread: wakes ``BACKUP_AFTER`` of a period past each deadline."""
        self._produce(production, BACKUP_AFTER * self.period_ms / 1000.0)

    def _produce(self, production: int, after_s: float = 0.0) -> None:
        """SYNC on absolute deadlines; one more than half a period late goes out at once and moves them.
        The deadlines are shared with the other producing thread (``after_s`` past them: the backup)."""
        period = self.period_ms / 1000.0
        while True:
            if self.hold is not None:
                self.hold()
            with self.lock:  # never a SYNC after stop(): it is judged under the lock stop() takes
                if not self.producing(production):
                    return
                now = time.monotonic()
                # a gap beyond what the drives ride out is reported before another SYNC goes out, so
                # that the halt it causes comes first (a stalled master: the process was held)
                overdue = None
                if self.sent_at is not None and self.sent_at != self._judged and now - self.sent_at > self.max_gap_s:
                    overdue, self._judged = now - self.sent_at, self.sent_at
            if overdue is not None:
                self.report_gap(overdue)
                continue
            with self.lock:
                if not self.producing(production):
                    return
                now = time.monotonic()
                late = now - self._deadline
                if self.sent_at is None:
                    self._deadline = now  # the first SYNC: when a producing thread first runs
                elif late > period / 2:
                    # more than half a period late: this SYNC goes out now and the deadlines after it
                    # keep the period from it (never late in a burst); the whole periods lost are
                    # counted. Waiting for the next deadline instead would make every such delay a
                    # gap of two periods, all a fixed-period drive rides out.
                    self.skipped += math.floor(late / period)
                    self._deadline = now
                gap = None
                # not before its deadline, nor within half a period of the last SYNC (one sent late)
                due = self._deadline if self.sent_at is None else max(self._deadline, self.sent_at + period / 2)
                if now >= due:
                    gap = None if self.sent_at is None or self.sent_at == self._judged else now - self.sent_at
                    self.transmit()
                    self._deadline += period
                    due = self._deadline
            if gap is not None:
                self.report_gap(gap)
            delay = due + after_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def step(self) -> dict[int, int]:
        """Send one SYNC by hand, outside production (e.g. the start's check: every drive answers it
        with its synchronous TPDO); what each drive's answer count will be once it has answered,
        for ``wait_answered`` (in real time ``count`` is a wall-clock estimate, not a SYNC's number)."""
        with self.lock:
            sent = self.count + 1
            # a drive of type n > 1 owes an answer only on its every n-th SYNC
            owed = {cob: n + 1 if self._every.get(cob, 1) == 1 else sent for cob, n in self._answers.items()}
            self.transmit()
            return owed

    def wait_answered(self, owed: dict[int, int], timeout_s: float) -> list[int]:
        """Wait until every drive has answered the SYNC ``step`` sent; the COB-IDs of the answers
        still missing then (empty: every drive answered in time)."""

        def missing() -> list[int]:
            return [cob for cob, n in owed.items() if self._answers.get(cob, 0) < n]

        with self.lock:
            self._answered_changed.wait_for(lambda: not missing(), timeout_s)
            return missing()

    def keep_period(self) -> None:
        """Real time: wait until one period after the last SYNC sent, so that the next one (``start``)
        keeps the cell's SYNC period after a SYNC sent by hand. Lockstep: nothing to wait for."""
        if not self.clock.lockstep:
            delay = self.last_sent + self.period_ms / 1000.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def stop(self) -> None:
        """No SYNC after this returns. The producing thread is not joined: stop() is called from SYNC
        listeners, which hold the lock that thread needs to see it must end (joining there blocked
        the bus's receive thread, and every SDO answer with it, for the join's whole timeout)."""
        with self.lock:
            self._running = False
            self._production += 1
            task, self.follower.task = self.follower.task, None
            held, self._collector_held = self._collector_held, False
            if self.cyclic is not None:
                self.cyclic.stop()
        if task is not None:
            task.stop()
        if held:
            collector.release()

    @property
    def running(self) -> bool:
        return self._running
