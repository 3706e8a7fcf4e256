"""AxisGroup: one program on one cell: configure, enable, preload, start on one SYNC, feed, halt, recover.

The group is the only place that decides about the motion as a whole. It is event driven: the SYNC
answers (``SyncClock`` listeners) step the feeders and check the drives, the status TPDOs feed the
buffers, the bus reports EMCY, heartbeat loss and lost SYNC. Any fault, or ``stop()``, sends the
halt controlword (0x011F) to every axis through the synchronous RPDO before the next SYNC, so all
axes halt on the same SYNC, within one period of the event; a drive without a ramp of its own
(``Profile.ramps_by_itself``) gets the master's braking setpoints from that SYNC on instead
(``axes.drive.stop_ramp``), and the run ends once they are run and every axis is at rest. The outcome
is one ``RunResult`` with a ``Result`` enum (ruckig style) that names the axis and the reason.

``AxisGroup`` is one object with one lock and one run's state; its parts are written by concept
and mixed into it: configuration and recovery (``axes.master.group.configure``), the start
(``axes.master.group.start``), halting (``axes.master.group.halt``), results and status (``axes.master.group.status``);
this module keeps the run itself: the SYNC events that feed the drives and watch them, the bus's
fault reports, the end. What a run reports lives in ``axes.master.group.outcome``; the cleanup after a run that
readies every axis for the next start, in ``axes.master.group.readiness``; what a run shares with a homing of the
cell (the links, homed since boot, one activity at a time), in ``axes.master.group.run_state``; homing a cell, in
``axes.master.homing``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import can

from pvtflow.axes.drive.cia402 import Statusword, decode_state
from pvtflow.axes.drive.config import AxisConfig, Wiring
from pvtflow.axes.drive.objects import BUFFER_ERRORS
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.master.budget import bus_budget
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.bus.quick_stop import QuickStop
from pvtflow.axes.master.bus.sync import below_sync
from pvtflow.axes.master.group.configure import Configured, GroupConfiguration
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, RecordAllowance, top_up_by_need
from pvtflow.axes.master.group.halt import GroupHalt
from pvtflow.axes.master.group.outcome import (
    Event,
    EventCallback,
    EventKind,
    GroupError,
    ProgressCallback,
    Result,
    RunResult,
)
from pvtflow.axes.master.group.readiness import Readiness
from pvtflow.axes.master.group.run_state import CellRunState
from pvtflow.axes.master.group.start import GroupStart
from pvtflow.axes.master.group.status import GroupReports
from pvtflow.axes.master.link import AxisLink
from pvtflow.axes.master.profiles import profile_for
from pvtflow.axes.master.profiles.base import Profile
from pvtflow.axes.master.run_queue import OnStart, QueuedProgram, RunQueue

_IP_MODE_ACTIVE = int(Statusword.IP_MODE_ACTIVE)
_FAULT_BITS = int(Statusword.FAULT)  # set in FAULT and FAULT REACTION ACTIVE
_BUFFER_ERRORS = int(BUFFER_ERRORS)
START_CHECK_SYNCS = 2  # SYNCs after the start SYNC by which every axis must report ip mode active


class AxisGroup(GroupConfiguration, GroupStart, GroupHalt, GroupReports):
    """All axes of one cell on one bus.

    ``AxisGroup(bus, axes, on_progress=..., on_event=..., progress_every=10)``: ``bus`` is an open
    ``CellBus``, ``axes`` the cell's ``AxisConfig``s (``cell.ordered_axes()``).

    - ``run(program, timeout_s=None) -> RunResult``: configure (first time), check, enable, preload,
      start, feed, wait for the outcome. ``start(program)`` (None, or a RunResult when refused at
      once) and ``wait(timeout_s)`` are the same in two steps. After a run that finished (and after
      ``recover``) every axis is enabled for the next start in the background, so that start only
      checks statusword and position, from the drives' answers to one check SYNC (no SDO), and
      starts on the SYNC after it.
    - ``stop(reason)``: any thread; every axis halts on the next SYNC; the run ends STOPPED.
    - ``recover() -> RunResult``: fault reset and re-enable every axis (FINISHED when all enabled).
    - ``status(refresh=False) -> GroupStatus``; ``last_result``; ``running``; ``feeders``.
    - ``on_progress(Progress)`` every ``progress_every`` SYNCs and ``on_event(Event)`` run in the bus's
      receive thread: keep them short (hand over to a queue).
    """

    def __init__(
        self,
        bus: CellBus,
        axes: Sequence[AxisConfig],
        *,
        on_progress: ProgressCallback | None = None,
        on_event: EventCallback | None = None,
        progress_every: int = 10,
        start_tolerance_qc: int = 100,
        halt_timeout_ms: float = 3000.0,
    ) -> None:
        self.bus = bus
        self.links = [AxisLink(bus, a) for a in axes]
        self.profiles: list[Profile] = [profile_for(link) for link in self.links]
        self.on_progress = on_progress
        self.on_event = on_event
        self.progress_every = max(1, progress_every)
        self.start_tolerance_qc = start_tolerance_qc
        self.halt_timeout_ms = halt_timeout_ms
        self.configuration = Configured()
        self.last_result: RunResult | None = None
        self._done = threading.Event()
        self._done.set()
        self._feeders: list[Feeder] = []
        self._programs: list[AxisProgram] = []
        self._start_sync: int | None = None
        self._start_sent: float | None = None  # time.monotonic() once the start SYNC was out (wall clock)
        self._ip_start: list[int | None] = []
        self._ending: RunResult | None = None  # set once the run is halting / ending
        self._halt_deadline: int | None = None
        self._end_words_sent = [False] * len(self.links)
        self._running = False
        self._halted_at: float | None = None
        self._starting = False
        self._stop_request: str | None = None
        self._pool = ThreadPoolExecutor(max_workers=max(1, len(self.links)), thread_name_prefix="axis-sdo")
        self._bus_faults = 0  # how many the bus has reported
        self.readiness = Readiness(self.links, self.profiles, self._pool, lambda: self._bus_faults)
        self.state = CellRunState(bus, self.links, self.readiness)  # shared with the cell's homing
        self._lock = self.state.lock
        self.last_quick_stop: QuickStop | None = None  # the last halt that did not wait for SYNC
        # the records the bus has room for in one SYNC period, shared by the buffered axes; never less
        # than one per buffered axis (a cell file whose bus has no room for that is refused at load)
        budget = bus_budget(Wiring(bus.config, tuple(axes)))
        self.allowance = RecordAllowance(budget.record_allowance)
        for link in self.links:
            link.status_listeners.append(self._on_status)
        self._status_lag = max((p.sync_answer_every for p in self.profiles), default=1) - 1
        self.queue = RunQueue(bus.config)  # the programs queued after the running one
        bus.on_fault(self._on_bus_fault)
        bus.sync.add_sender(self._after_sync)  # the fixed-period setpoints; the start SYNC's time

    def _event(self, kind: EventKind, message: str, link: AxisLink | None = None) -> None:
        if self.on_event is not None:
            self.on_event(Event(kind, message, link.joint if link else None, link.node_id if link else None))

    # --- running ---------------------------------------------------------------------------------
    def run(self, program: PvtProgram, timeout_s: float | None = None) -> RunResult:
        """Configure (once), enable, preload, start on one SYNC, feed to the end: the outcome."""
        with below_sync(self.bus.sync):  # SYNC starts under it: no GIL held from it meanwhile (axes.master.bus.sync)
            early = self.start(program)
            if early is not None:
                return early
            return self.wait(timeout_s)

    def append(
        self,
        program: PvtProgram,
        on_start: OnStart | None = None,
        before_records: Callable[[], object] | None = None,
    ) -> QueuedProgram:
        """Queue ``program`` after the running one, on the same time line (``axes.master.run_queue``);
        ``on_start`` is told when its t = 0 is passed. GroupError, nothing changed, when it cannot follow.
        ``before_records``: called once the checks passed, before any record changes (a service journals
        the motion there); what it raises ends the append with nothing changed, and is raised from here."""
        reason = self.check_program(program)
        if reason is not None:
            raise GroupError(f"the queued program does not fit the cell: {reason}")
        by_node = {a.node_id: a for a in program.axes}
        programs = [by_node[link.node_id] for link in self.links]
        with self._lock:
            self._queue_refusal(programs)
            feeders = list(self._feeders)
        if before_records is not None:
            before_records()
        # joined and packed here, so that the SYNC lock is held only to put them in place
        extensions = [f.extension(p.records) for f, p in zip(feeders, programs, strict=True)]
        with self.bus.sync.lock, self._lock:  # the setpoints go out under the SYNC lock: none while they grow
            elapsed_ms = self._queue_refusal(programs)
            return self.queue.append(programs, program, self._feeders, extensions, elapsed_ms, on_start)

    def _queue_refusal(self, programs: list[AxisProgram]) -> float:
        """The run's time now (ms), if ``programs`` (axis order) can be queued now (else GroupError)."""
        sync = self.bus.sync
        if not self._running or self._ending is not None or self._start_sync is None:
            raise GroupError("no program runs on this cell to queue after")
        if sync.cyclic_producing:
            raise GroupError("a cell whose SYNC comes from its cyclic process takes no queued program")
        elapsed_ms = (sync.count - self._start_sync) * self.bus.config.sync_period_ms
        if self._start_sent is not None and not sync.lockstep:  # the buffered drives' own clock
            elapsed_ms = max(elapsed_ms, (time.monotonic() - self._start_sent) * 1000.0)
        why = self.queue.refusal(programs, self._feeders, elapsed_ms)
        if why is not None:
            raise GroupError(why)
        return elapsed_ms

    @property
    def halt_budget_s(self) -> float:
        """How long a halt may take to end the run: the drives' braking (``halt_timeout_ms``) and a
        silence of the drives as long as lost SYNC allows, twice (the one home of the halt's time)."""
        return self.halt_timeout_ms / 1000.0 + 2.0 * self.bus.lost_sync_timeout_s

    def wait(self, timeout_s: float | None = None) -> RunResult:
        """Block until the run ends. The timeouts only detect a cell that stopped answering: the run
        is then halted, and if no drive answers the halt SYNCs either, ended with what is known."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        halt_grace = self.halt_budget_s
        with below_sync(self.bus.sync):  # its wakes hold no GIL from SYNC (axes.master.bus.sync)
            while not self._done.wait(0.05):
                now = time.monotonic()
                if deadline is not None and now > deadline and self._ending is None:
                    self.stop("timeout waiting for the program to end")
                if self._ending is not None and self._halted_at is not None and now - self._halted_at > halt_grace:
                    self._end(self._ending)  # nobody answers the halt SYNCs any more
        assert self.last_result is not None
        return self.last_result

    @property
    def running(self) -> bool:
        return self._running

    @property
    def feeders(self) -> tuple[Feeder, ...]:
        """The feeders of the present (or last) run, in axis order."""
        return tuple(self._feeders)

    @property
    def programs(self) -> tuple[AxisProgram, ...]:
        """The axis programs of the present (or last) run, in axis order (a recording samples what
        each drive was told from them)."""
        return tuple(self._programs)

    def elapsed_syncs(self) -> int | None:
        return None if self._start_sync is None else self.bus.sync.answered - self._start_sync

    # --- events ----------------------------------------------------------------------------------
    def _after_sync(self, n: int) -> None:
        """SYNC ``n`` is on the bus (the sending thread, SYNC lock held): the frames that must precede
        SYNC n + 1 go out now, unpaced by the drives' answers. No group lock: a halt disables the
        feeders under the SYNC lock, so none sends after it."""
        start = self._start_sync
        if not self._running or start is None or n < start:
            return
        if n == start:
            self._start_sent = time.monotonic()  # t = 0 of the buffered drives' records
        if self.bus.sync.cyclic_producing:
            return  # the cyclic process sent them (axes.master.cyclic.process)
        for feeder in self._feeders:  # halting: only the stop ramps of drives without a ramp (_halt)
            feeder.after_sync(n - start)

    def _on_sync(self, n: int) -> None:
        """After every answered SYNC (notifier thread; before the next SYNC in lockstep)."""
        with self._lock:
            if not self._running or self._start_sync is None:
                return
            elapsed = n - self._start_sync
            for i, link in enumerate(self.links):
                if self._ip_start[i] is None and link.statusword & _IP_MODE_ACTIVE:
                    self._ip_start[i] = n
            if self._ending is None:
                self._check_drives()
            # a status TPDO every n SYNCs reports ip mode up to n - 1 SYNCs later (axes.master.tpdo_rates)
            if self._ending is None and elapsed >= START_CHECK_SYNCS + self._status_lag:
                self._check_started()
            if self._ending is None:
                for feeder in self._feeders:
                    feeder.on_sync(elapsed)
                self._feed()
                self.queue.at_sync(elapsed)
                self._check_finished(elapsed)
            else:
                self._check_halted(n)
            if self.on_progress is not None and n % self.progress_every == 0:
                self.on_progress(self._progress(n))

    def _check_drives(self) -> None:
        for link in self.links:
            if not (link.statusword & _FAULT_BITS or link.buffer_status & _BUFFER_ERRORS):
                continue
            state = decode_state(link.statusword)
            if state.is_fault or link.buffer_status & _BUFFER_ERRORS:
                why = f"statusword 0x{link.statusword:04X} ({state.value})"
                if link.buffer_status & BUFFER_ERRORS:
                    why += f", buffer: {link.describe_buffer()}"
                if link.last_emcy is not None:
                    why += f", last EMCY 0x{link.last_emcy[0]:04X} {link.last_emcy[1]}"
                self._halt(Result.DRIVE_FAULT, f"axis {link.joint} (node {link.node_id}) faulted: {why}", link)
                return

    def _check_started(self) -> None:
        for i, link in enumerate(self.links):
            if self._ip_start[i] is None:
                self._halt(
                    Result.DRIVE_FAULT,
                    f"axis {link.joint} (node {link.node_id}) did not enter ip mode "
                    f"(statusword 0x{link.statusword:04X})",
                    link,
                )
                return

    def _check_finished(self, elapsed: int) -> None:
        done = True
        for i, (link, profile, feeder) in enumerate(zip(self.links, self.profiles, self._feeders, strict=True)):
            ip_active = bool(link.statusword & _IP_MODE_ACTIVE)
            if feeder.finished(elapsed, ip_active and profile.name.buffered):
                if not profile.name.buffered and not self._end_words_sent[i]:
                    link.send_controlword(profile.end_controlword())  # the fixed-period end: bit 4 off
                    self._end_words_sent[i] = True
                    done = False
            else:
                done = False
        if done:
            self.bus.sync.stop()
            self._end(self._result(Result.FINISHED, "every axis reached its end record"))

    def _feed(self) -> None:
        """Top the buffered axes up from the allowance of the period of the last SYNC sent (group lock
        held). On the wall clock their drives' clock is the time since the start SYNC went out
        (``axes.master.group.feeder``), not the SYNCs every drive has answered: one drive's late answers must not
        stop another drive's feed while that one runs its records on its own clock."""
        sync = self.bus.sync
        if sync.cyclic_producing:
            return  # the cyclic process tops up; the feeders here mirror it (axes.master.cyclic.process)
        self.allowance.at_sync(sync.count)
        if not sync.lockstep and self._start_sent is not None:
            elapsed_ms = (time.monotonic() - self._start_sent) * 1000.0
            for feeder in self._feeders:
                if isinstance(feeder, BufferFeeder):
                    feeder.run_to(elapsed_ms)
        top_up_by_need(self._feeders, self.allowance)

    def _on_status(self, link: AxisLink) -> None:
        """A TPDO arrived (notifier thread): buffered feeders react to the buffer status at once; on
        the wall clock a buffered drive's own answer tops it up too, whatever the others' answers do."""
        if not self._running:
            return
        i = self.links.index(link)
        if not self._feeders:
            return
        feeder = self._feeders[i]
        if link.buffer_status:
            feeder.on_status(link.buffer_status)
        if isinstance(feeder, BufferFeeder) and not self.bus.sync.lockstep:
            # one try per record: a full transmit queue keeps its room for SYNC and the setpoints, and
            # a record refused waits for the next top-up (the FIFO's depth covers it)
            with self._lock, self.bus.network.patient(0), contextlib.suppress(can.CanError):
                if self._running and self._ending is None and self._start_sent is not None:
                    self._feed()

    def _on_bus_fault(self, fault: BusFault) -> None:
        link = next((lk for lk in self.links if lk.node_id == fault.node_id), None)
        if link is not None and fault.kind is FaultKind.EMCY:
            link.last_emcy = (fault.code, fault.message)
        self._bus_faults += 1
        if link is not None:  # whatever it was, that drive is enabled again at the next start
            self.readiness.forget(self.links.index(link))
        # SYNC failed mid-run: the quick stop requests go out before the event says why (an event
        # may print or publish: ``_quick_stop``); any other fault is told first
        told = fault.kind.sync_failed and self._running and not fault.kind.warning
        if not told:
            self._event(EventKind(fault.kind.value), fault.message, link)
        if not self._running or fault.kind.warning:
            return
        kind = {
            FaultKind.EMCY: Result.EMCY,
            FaultKind.HEARTBEAT: Result.HEARTBEAT_LOST,
            FaultKind.NMT: Result.HEARTBEAT_LOST,
            FaultKind.LOST_SYNC: Result.LOST_SYNC,
        }.get(fault.kind, Result.BUS_ERROR)
        sync = self.bus.sync
        with sync.lock, self._lock:
            if self._ending is not None and self._running and fault.kind.sync_failed and self._halt_deadline:
                self._quick_stop_too(fault.message, link, fault)  # the halt word waits for a SYNC that will not come
                return
            if self._ending is not None or not self._running:
                if told:
                    self._event(EventKind(fault.kind.value), fault.message, link)
                return
            if fault.kind.sync_failed:
                self._quick_stop(kind, fault.message, link, fault)
                return
            gone = kind in (Result.HEARTBEAT_LOST, Result.LOST_SYNC)
            stalled = bool(sync.behind())
            if gone:
                self.configuration.forget()  # the node may come back reset: recover() configures again
            if gone and link is not None:
                # stop waiting for a drive that is gone, so the others still get their halt SYNC
                sync.expect(
                    {
                        p.sync_answer_cob_id: p.sync_answer_every
                        for p, lk in zip(self.profiles, self.links, strict=True)
                        if lk is not link
                    }
                )
            self._halt(kind, fault.message, link)
            if gone and stalled and sync.lockstep:
                sync.step()

    def _end(self, result: RunResult) -> None:
        with self.bus.sync.lock, self._lock:
            if not self._running:
                return
            self.bus.sync.remove_listener(self._on_sync)
            self.bus.watch.watch_sync = False
            result.end_sync = self.bus.sync.answered
            result.axes = self._reports()
            self.last_result = result
            self._running = False
            self.state.release(self)
            self.readiness.prepare()
            self._event(
                EventKind(result.result.value),
                result.message,
                next((lk for lk in self.links if lk.node_id == result.node_id), None),
            )
            self._done.set()

    def _finish_early(self, result: Result, message: str, link: AxisLink | None = None) -> RunResult:
        res = self._result(result, message, link)
        res.axes = self._reports()
        self.last_result = res
        self._event(EventKind(result.value), message, link)
        return res

    def close(self) -> None:
        """Release the drives (at rest, each is shut down, then stops watching the master's heartbeat:
        an orderly close is not a lost master, ``Profile.release_master``) and let go of the bus. A
        close during a run leaves them watching: the heartbeat stops with the bus and every drive
        stops by itself; so does a close after the bus's (nothing can be said on a closed bus)."""
        if self.configured and not self._running and self.bus.is_open:
            for profile in self.profiles:
                profile.release_master()
            self.configuration.forget()  # a group used again arms the consumers again
        self.bus.sync.remove_sender(self._after_sync)
        self._pool.shutdown(wait=True)
        for link in self.links:
            link.unsubscribe()
            if self._on_status in link.status_listeners:
                link.status_listeners.remove(self._on_status)
        self.bus.remove_fault_callback(self._on_bus_fault)
