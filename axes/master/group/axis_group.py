"""AxisGroup: one program on one cell: configure, enable, preload, start on one SYNC, feed, halt, recover.

The group is the only place that decides about the motion as a whole. It is event driven: the SYNC
answers (``SyncClock`` listeners) step the feeders and check the drives, the status TPDOs feed the
buffers, the bus reports EMCY, heartbeat loss and lost SYNC. Any fault, or ``stop()``, sends the
halt controlword (0x011F) to every axis through the synchronous RPDO before the next SYNC, so all
axes halt on the same SYNC, within one period of the event; a drive without a ramp of its own
(``Profile.ramps_by_itself``) gets the master's braking setpoints from that SYNC on instead
(``axes.drive.stop_ramp``), and the run ends once they are run and every axis is at rest. The outcome
is one ``RunResult`` with a ``Result`` enum (ruckig style) that names the axis and the reason.

``AxisGroup`` holds the cell's lasting parts, each owning its state: the links and profiles, the
configuration and program check (``CellSetup``, axes.master.group.configure), the start's checks and
preload (``StartChecks``, axes.master.group.start), the reports (``GroupReports``, axes.master.group.status),
the cleanup that readies every axis for the next start (``Readiness``), what a run shares with a homing
of the cell (``CellRunState``, axes.master.group.run_state: the links, homed since boot, one activity
at a time, the cell's lock). Every start makes a ``Run`` (axes.master.group.run) that owns that start's
feeders, SYNC numbers and SYNC-time work, and its ``Halting`` (axes.master.group.halt); homing a cell
is ``axes.master.homing``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import can

from pvtflow.axes.drive.config import AxisConfig, Wiring
from pvtflow.axes.drive.objects import NmtCommand
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.master.budget import bus_budget
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.bus.quick_stop import QuickStop
from pvtflow.axes.master.bus.sync import below_sync
from pvtflow.axes.master.group.configure import SETUP_PATIENCE_S, CellSetup, Configured
from pvtflow.axes.master.group.feeder import BufferFeeder, Extension, Feeder, RecordAllowance
from pvtflow.axes.master.group.outcome import (
    Event,
    EventCallback,
    EventKind,
    GroupError,
    GroupStatus,
    ProgressCallback,
    Result,
    RunResult,
)
from pvtflow.axes.master.group.readiness import Readiness
from pvtflow.axes.master.group.run import Run
from pvtflow.axes.master.group.run_state import CellRunState, RunParts
from pvtflow.axes.master.group.start import PRELOAD_PATIENCE_S, StartChecks
from pvtflow.axes.master.group.status import GroupReports, RunView
from pvtflow.axes.master.link import AxisLink, DriveError
from pvtflow.axes.master.profiles import profile_for
from pvtflow.axes.master.profiles.base import Profile
from pvtflow.axes.master.run_queue import OnStart, QueuedProgram, RunQueue
from pvtflow.axes.master.splice import HOLD_ANSWER_S, Make, SpliceAt, SpliceRefusedError, splice_run

if TYPE_CHECKING:
    from pvtflow.axes.master.cyclic.process import CyclicProcess


class AxisGroup:
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
        self.on_event = on_event
        self.on_progress = on_progress
        self.progress_every = max(1, progress_every)
        self.halt_timeout_ms = halt_timeout_ms
        self.last_result: RunResult | None = None
        self._done = threading.Event()
        self._done.set()
        self._run: Run | None = None  # the present run, or the last
        self._starting = False
        self._stop_request: str | None = None
        self._pool = ThreadPoolExecutor(max_workers=max(1, len(self.links)), thread_name_prefix="axis-sdo")
        self._bus_faults = 0  # how many the bus has reported
        self.readiness = Readiness(self.links, self.profiles, self._pool, lambda: self._bus_faults)
        self.state = CellRunState(bus, self.links, self.readiness)  # shared with the cell's homing
        self._lock = self.state.lock
        # the records the bus has room for in one SYNC period, shared by the buffered axes; never less
        # than one per buffered axis (a cell file whose bus has no room for that is refused at load)
        budget = bus_budget(Wiring(bus.config, tuple(axes)))
        self.allowance = RecordAllowance(budget.record_allowance)
        self.setup = CellSetup(bus, self.links, self.profiles, self.readiness, self.allowance)
        self.checks = StartChecks(
            bus, self.links, self.profiles, self._pool, self.allowance, self.setup.configuration, start_tolerance_qc
        )
        self.reports = GroupReports(bus, self.links, lambda: self.state.homed)
        self._parts = RunParts(
            bus=bus,
            links=self.links,
            profiles=self.profiles,
            allowance=self.allowance,
            reports=self.reports,
            readiness=self.readiness,
            configuration=self.setup.configuration,
            lock=self._lock,
            event=self._event,
            progress=self._progress,
            halt_timeout_ms=halt_timeout_ms,
        )
        for link in self.links:
            link.status_listeners.append(self._on_status)
        bus.on_fault(self._on_bus_fault)
        bus.sync.add_sender(self._after_sync)  # the fixed-period setpoints; the start SYNC's time

    def _event(self, kind: EventKind, message: str, link: AxisLink | None = None) -> None:
        if self.on_event is not None:
            self.on_event(Event(kind, message, link.joint if link else None, link.node_id if link else None))

    def _progress(self, n: int, run: RunView) -> None:
        if self.on_progress is not None and n % self.progress_every == 0:
            self.on_progress(self.reports.progress(run, n))

    # --- what the group is and holds ------------------------------------------------------------------
    @property
    def configuration(self) -> Configured:
        return self.setup.configuration

    @property
    def configured(self) -> bool:
        return self.setup.configured

    def configure(self) -> None:
        self.setup.configure()

    def configure_if_needed(self) -> None:
        self.setup.configure_if_needed()

    def check_program(self, program: PvtProgram) -> str | None:
        """Why this program cannot run on this cell (None: it can)."""
        return self.setup.check_program(program)

    @property
    def start_tolerance_qc(self) -> int:
        return self.checks.tolerance_qc

    @property
    def running(self) -> bool:
        return self._run is not None and self._run.live

    @property
    def feeders(self) -> tuple[Feeder, ...]:
        """The feeders of the present (or last) run, in axis order."""
        return self._run.feeders if self._run is not None else ()

    @property
    def programs(self) -> tuple[AxisProgram, ...]:
        """The axis programs of the present (or last) run, in axis order (a recording samples what
        each drive was told from them)."""
        return self._run.programs if self._run is not None else ()

    @property
    def start_sync(self) -> int | None:
        """The SYNC the present (or last) run started on."""
        return self._run.start_sync if self._run is not None else None

    @property
    def last_quick_stop(self) -> QuickStop | None:
        """The quick stop by SDO of the present (or last) run, if it needed one."""
        return self._run.halting.quick_stop if self._run is not None else None

    def elapsed_syncs(self) -> int | None:
        start = self.start_sync
        return None if start is None else self.bus.sync.answered - start

    @property
    def halt_budget_s(self) -> float:
        """How long a halt may take to end the run: the drives' braking (``halt_timeout_ms``) and a
        silence of the drives as long as lost SYNC allows, twice (the one home of the halt's time)."""
        return self.halt_timeout_ms / 1000.0 + 2.0 * self.bus.lost_sync_timeout_s

    def status(self, refresh: bool = False) -> GroupStatus:
        """What the drives say: from their TPDOs while running; ``refresh`` reads statusword and
        position by SDO first when idle (no SYNC, so no TPDO, flows between runs in lockstep)."""
        return self.reports.status(self._run, self.last_result.result if self.last_result else None, refresh)

    def refresh(self) -> None:
        """Read every statusword and position by SDO (when no TPDO flows, e.g. between runs)."""
        self.reports.refresh()

    def settle(self, timeout_s: float | None = None) -> bool:
        """Wait until the end of the last run has been cleaned up in every drive (buffers empty,
        interpolation ended: ``axes.master.group.readiness``). False: not within ``timeout_s``."""
        return self.readiness.settle(timeout_s)

    # --- running ---------------------------------------------------------------------------------
    def run(self, program: PvtProgram, timeout_s: float | None = None) -> RunResult:
        """Configure (once), enable, preload, start on one SYNC, feed to the end: the outcome."""
        with below_sync(self.bus.sync):  # SYNC starts under it: no GIL held from it meanwhile (axes.master.bus.sync)
            early = self.start(program)
            if early is not None:
                return early
            return self.wait(timeout_s)

    def start(self, program: PvtProgram, before_records: Callable[[], object] | None = None) -> RunResult | None:
        """Start a run; returns a result at once only when the program is refused or a drive fails.

        ``before_records``: called once the start's checks are asked, before the first record goes
        out (a service journals the motion there, while the drives answer); what it raises ends
        the start with nothing sent, and is raised from here.

        A ``stop`` from any thread while this runs is never lost: before the motion is begun it ends
        the start with nothing moving; once begun (under the SYNC lock, which ``stop`` waits for) the
        run halts on its first SYNCs."""
        try:
            return self._start(program, before_records)
        finally:
            self._starting = False

    def _start(self, program: PvtProgram, before_records: Callable[[], object] | None) -> RunResult | None:
        with self._lock:
            if self.running:
                raise GroupError("a program is already running on this cell")
            if self.state.holder is not None:
                raise GroupError("the cell is homing: one motion at a time")
            reason = self.check_program(program)
            if reason is not None:
                return self._finish_early(Result.REJECTED, reason)
            feeders: list[Feeder | None] = [None] * len(self.links)
            try:
                self.setup.configure_if_needed()
                by_node = {a.node_id: a for a in program.axes}
                run = self._run = Run(self._parts, [by_node[link.node_id] for link in self.links], self._ended)
                self._stop_request = None
                self._starting = True
                self.readiness.wait()  # the last run's cleanup, if still going
                ready = self.readiness.take()
                if all(ready):
                    feeders, refusal = self.checks.by_sync(run.programs, before_records)
                else:
                    refusal = self.checks.by_sdo(run.programs, ready, before_records)
                if refusal is not None:
                    return self._finish_early(*refusal)
            except DriveError as exc:
                link = next((lk for lk in self.links if lk.node_id == exc.node_id), None)
                return self._finish_early(Result.CONFIGURATION_ERROR, str(exc), link)
            except can.CanError as exc:  # no start word went out: nothing moves (before_records' errors are raised)
                # the SYNC count and the drives' answers agree again from here (a check SYNC not sent
                # was counted); the next start asks every drive by SDO (its readiness was taken)
                self.setup.expect_answers()
                return self._finish_early(Result.BUS_ERROR, f"the start's check could not be sent: {exc}")
            if self._stop_request is not None:
                return self._finish_early(Result.STOPPED, self._stop_request)
            run.take_feeders(
                f if f is not None else p.feeder(prog, self.allowance)
                for f, p, prog in zip(feeders, self.profiles, run.programs, strict=True)
            )
            try:
                refusal = self.checks.preload(run.feeders, checked=any(f is not None for f in feeders))
            except can.CanError as exc:  # records without a start word move nothing
                self.setup.expect_answers()
                return self._finish_early(Result.BUS_ERROR, f"the records could not be sent before the start: {exc}")
            if refusal is not None:
                return self._finish_early(*refusal)
        sync = self.bus.sync
        # the caller holds the SYNC lock while SYNC starts: at normal priority, preempted there, it would
        # hold the start SYNC up for a scheduler slice (axes.master.bus.sync.below_sync)
        with below_sync(sync):
            sync.keep_period()  # real time: the start SYNC one period after the check SYNC
            with sync.lock, self._lock:
                self.state.claim(self, "the cell is homing: one motion at a time")
                self._done.clear()
                run.begin(sync.count + 1)
                run_gap_s = None  # the bus's own, set in its config
                if self.bus.config.max_sync_gap_periods is None:  # the profiles say (axes.master.bus.sync)
                    gaps = (p.max_sync_gap_ms(prog) for p, prog in zip(self.profiles, run.programs, strict=True))
                    run_gap_s = min(gaps) / 1000.0
                # before the start SYNC nothing waits on these frames: a full transmit queue only delays
                # them by the wire time of what is ahead (as the preload's)
                try:
                    with self.bus.network.patient(PRELOAD_PATIENCE_S):
                        for feeder in run.feeders:  # the fixed-period setpoints the start SYNC validates
                            if not isinstance(feeder, BufferFeeder):
                                feeder.preload()
                        for link, profile in zip(self.links, self.profiles, strict=True):
                            link.send_controlword(profile.start_controlword())
                except (can.CanError, OSError) as exc:
                    # the drives that got their start word would start alone at the next SYNC, whoever
                    # sends it: every axis is quick stopped by SDO instead, and that ends the run
                    run.halting.quick(Result.BUS_ERROR, f"the start could not be sent: {exc}", None)
                    return None
                if sync.cyclic is not None:  # the run's feeders go on in the cyclic process from here
                    sync.cyclic.hand_over(list(run.feeders), self.profiles, self.allowance, sync.max_gap_s)
                sync.add_listener(run.on_sync)
                self.bus.watch.arm_sync_watch()
                self._event(EventKind.STARTED, f"program of {program.duration_ms} ms started on SYNC {run.start_sync}")
                # the start SYNC (and its time stamp) wait for room as the start words do: nothing runs
                # before it, so a full queue only delays the start by the wire time of what is ahead
                with self.bus.network.patient(PRELOAD_PATIENCE_S):
                    sync.start(max_gap_s=run_gap_s, setpoints_per_sync=any(not p.name.buffered for p in self.profiles))
                if self._stop_request is not None:  # asked while the start went on: it found no run to halt
                    self._halt(run, self._stop_request)
        return None

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
            run = self._run
            if run is None:
                raise GroupError("no program runs on this cell to queue after")
            run.queue_refusal(programs)
            feeders = run.feeders
        if before_records is not None:
            before_records()
        # joined and packed here, so that the SYNC lock is held only to put them in place
        extensions = [f.extension(p.records) for f, p in zip(feeders, programs, strict=True)]
        sync = self.bus.sync
        cyclic = sync.cyclic if sync.cyclic_producing else None
        if cyclic is not None:
            return self._append_through(cyclic, run, programs, program, extensions, on_start)
        with sync.lock, self._lock:  # the setpoints go out under the SYNC lock: none while they grow
            elapsed_ms = run.queue_refusal(programs)
            return run.queue.append(programs, program, run.feeders, extensions, elapsed_ms, on_start)

    def _append_through(
        self,
        cyclic: CyclicProcess,
        run: Run,
        programs: list[AxisProgram],
        program: PvtProgram,
        extensions: list[Extension],
        on_start: OnStart | None,
    ) -> QueuedProgram:
        """``append`` where the cyclic process sends the records: it joins them to its feeders first (one pipe
        message each way, at most ``HOLD_ANSWER_S`` as a change's hold), then this process's mirrors follow.
        The group lock is held throughout (taken under the SYNC lock, as everywhere), the SYNC lock not while
        the child answers."""
        with self.bus.sync.lock:
            self._lock.acquire()
        try:
            elapsed_ms = run.queue_refusal(programs)
            try:
                joined = cyclic.extend([p.records for p in programs], HOLD_ANSWER_S)
            except TimeoutError as exc:
                raise GroupError(str(exc)) from None
            if not joined:
                raise GroupError("the run ends before the queued program could be joined: its last records are out")
            queue = run.queue
            return queue.append(programs, program, run.feeders, extensions, elapsed_ms, on_start, joined_elsewhere=True)
        finally:
            self._lock.release()

    @property
    def queue(self) -> RunQueue | None:
        """The programs queued on the present (or last) run."""
        return self._run.queue if self._run is not None else None

    def splice(self, make: Make, lead_ms: float | None = None) -> SpliceAt:
        """Change the running program from a moment on (``axes.master.splice``: the records not yet sent
        replaced by ``make(at)``); SpliceRefusedError, nothing changed, when no motion runs."""
        run = self._run
        if run is None:
            raise SpliceRefusedError("no motion runs")
        return splice_run(run, make, lead_ms)

    def ends_as(self, outcome: tuple[Result, str] | None) -> None:
        """The running program, changed to end early (an on-path stop), ends with ``outcome`` (None: FINISHED)."""
        if self._run is not None:
            self._run.ends_as(outcome)

    def wait(self, timeout_s: float | None = None) -> RunResult:
        """Block until the run ends. The timeouts only detect a cell that stopped answering: the run
        is then halted, and if no drive answers the halt SYNCs either, ended with what is known."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        halt_grace = self.halt_budget_s
        with below_sync(self.bus.sync):  # its wakes hold no GIL from SYNC (axes.master.bus.sync)
            while not self._done.wait(0.05):
                now = time.monotonic()
                run = self._run
                if run is None:
                    continue
                halting = run.halting
                if deadline is not None and now > deadline and halting.ending is None:
                    self.stop("timeout waiting for the program to end")
                if (
                    halting.ending is not None
                    and halting.halted_at is not None
                    and now - halting.halted_at > halt_grace
                ):
                    run.end(halting.ending)  # nobody answers the halt SYNCs any more
        assert self.last_result is not None
        return self.last_result

    def stop(self, reason: str = "stop requested") -> None:
        """Halt all axes on the next SYNC (any thread). The run then ends with Result.STOPPED; a
        start still configuring the drives does not start the motion."""
        if self._starting:
            self._stop_request = reason
        if self.state.holder is not self:  # a homing holds the cell
            self.state.stop(reason)
        with self.bus.sync.lock, self._lock:
            run = self._run
            if run is not None:
                self._halt(run, reason)

    def _halt(self, run: Run, reason: str) -> None:
        """Halt a live run that is not ending yet (SYNC lock and group lock held)."""
        if not run.live or run.ending is not None:
            return
        sync = self.bus.sync
        if not sync.running and not sync.clock.lockstep:  # no SYNC to carry the halt word
            run.halting.quick(Result.STOPPED, reason, None)
        else:
            run.halting.halt(Result.STOPPED, reason, None)

    def recover(self) -> RunResult:
        """Fault reset and re-enable every axis (by SDO), and put lost nodes back to OPERATIONAL."""
        with self._lock, self.bus.network.patient(SETUP_PATIENCE_S):  # nothing moves: frames may wait for room
            if self.running:
                raise GroupError("cannot recover while a program is running: stop it first")
            self.readiness.wait()  # not two enables of one drive at once
            self.bus.sync.stop()
            try:
                self.setup.configure_if_needed()
            except DriveError as exc:
                return self._finish_early(Result.CONFIGURATION_ERROR, str(exc))
            for link in self.links:
                self.bus.nmt(link.node_id, NmtCommand.START)
            self.setup.expect_answers()
            for link, profile in zip(self.links, self.profiles, strict=True):
                try:
                    profile.enable()
                except DriveError as exc:
                    return self._finish_early(Result.CONFIGURATION_ERROR, f"recover failed: {exc}", link)
                link.forget_faults()
            self.readiness.mark_all()  # enabled just now: ready
            self.bus.watch.watch_heartbeat(link.node_id for link in self.links)
            self._event(EventKind.RECOVERED, "all axes fault-free and enabled")
            res = self.reports.result(self._run, Result.FINISHED, "recovered: every axis is enabled")
            res.axes = self.reports.axis_reports(self._run)
            return res

    # --- events ----------------------------------------------------------------------------------
    def _after_sync(self, n: int) -> None:
        run = self._run
        if run is not None:
            run.after_sync(n)

    def _on_status(self, link: AxisLink) -> None:
        run = self._run
        if run is not None:
            run.on_status(link)

    def _on_bus_fault(self, fault: BusFault) -> None:
        link = next((lk for lk in self.links if lk.node_id == fault.node_id), None)
        if link is not None and fault.kind is FaultKind.EMCY:
            link.note_emcy(fault.code, fault.message)
        self._bus_faults += 1
        if link is not None:  # whatever it was, that drive is enabled again at the next start
            self.readiness.forget(self.links.index(link))
        # SYNC failed mid-run: the quick stop requests go out before the event says why (an event
        # may print or publish: ``Halting.quick``); any other fault is told first
        running = self.running
        told = fault.kind.sync_failed and running and not fault.kind.warning
        if not told:
            self._event(EventKind(fault.kind.value), fault.message, link)
        if not running or fault.kind.warning:
            return
        kind = {
            FaultKind.EMCY: Result.EMCY,
            FaultKind.HEARTBEAT: Result.HEARTBEAT_LOST,
            FaultKind.NMT: Result.HEARTBEAT_LOST,
            FaultKind.LOST_SYNC: Result.LOST_SYNC,
        }.get(fault.kind, Result.BUS_ERROR)
        sync = self.bus.sync
        with sync.lock, self._lock:
            run = self._run
            if run is None:
                return
            halting = run.halting
            if halting.ending is not None and run.live and fault.kind.sync_failed and halting.deadline:
                halting.quick_too(fault.message, link, fault)  # the halt word waits for a SYNC that will not come
                return
            if halting.ending is not None or not run.live:
                if told:
                    self._event(EventKind(fault.kind.value), fault.message, link)
                return
            if fault.kind.sync_failed:
                halting.quick(kind, fault.message, link, fault)
                return
            gone = kind in (Result.HEARTBEAT_LOST, Result.LOST_SYNC)
            stalled = bool(sync.behind())
            if gone:
                self.setup.configuration.forget()  # the node may come back reset: recover() configures again
            if gone and link is not None:
                # stop waiting for a drive that is gone, so the others still get their halt SYNC
                sync.expect(
                    {
                        p.sync_answer_cob_id: p.sync_answer_every
                        for p, lk in zip(self.profiles, self.links, strict=True)
                        if lk is not link
                    }
                )
            halting.halt(kind, fault.message, link)
            if gone and stalled and sync.clock.lockstep:
                sync.step()

    def _ended(self, result: RunResult) -> None:
        """The present run ended (``Run.end``: SYNC lock and group lock held)."""
        self.last_result = result
        self.state.release(self)
        self.readiness.prepare()
        self._event(
            EventKind(result.result.value),
            result.message,
            next((lk for lk in self.links if lk.node_id == result.node_id), None),
        )
        self._done.set()

    def _finish_early(self, result: Result, message: str, link: AxisLink | None = None) -> RunResult:
        res = self.reports.result(self._run, result, message, link)
        res.axes = self.reports.axis_reports(self._run)
        self.last_result = res
        self._event(EventKind(result.value), message, link)
        return res

    def close(self) -> None:
        """Release the drives (at rest, each is shut down, then stops watching the master's heartbeat:
        an orderly close is not a lost master, ``Profile.release_master``) and let go of the bus. A
        close during a run leaves them watching: the heartbeat stops with the bus and every drive
        stops by itself; so does a close after the bus's (nothing can be said on a closed bus)."""
        if self.configured and not self.running and self.bus.is_open:
            for profile in self.profiles:
                profile.release_master()
            self.setup.configuration.forget()  # a group used again arms the consumers again
        self.bus.sync.remove_sender(self._after_sync)
        self._pool.shutdown(wait=True)
        for link in self.links:
            link.unsubscribe()
            if self._on_status in link.status_listeners:
                link.status_listeners.remove(self._on_status)
        self.bus.remove_fault_callback(self._on_bus_fault)
