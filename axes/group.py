"""AxisGroup: one program on one cell: configure, enable, preload, start on one SYNC, feed, halt, recover.

The group is the only place that decides about the motion as a whole. It is event driven: the SYNC
answers (``SyncClock`` listeners) step the feeders and check the drives, the status TPDOs feed the
buffers, the bus reports EMCY, heartbeat loss and lost SYNC. Any fault, or ``stop()``, sends the
halt controlword (0x011F) to every axis through the synchronous RPDO before the next SYNC, so all
axes halt on the same SYNC, within one period of the event; a drive without a ramp of its own
(``Profile.ramps_by_itself``) gets the master's braking setpoints from that SYNC on instead
(``axes.stop_ramp``), and the run ends once they are run and every axis is at rest. The outcome
is one ``RunResult`` with a ``Result`` enum (ruckig style) that names the axis and the reason.

What a run reports lives in ``axes.outcome``; the cleanup after a run that readies every axis for
the next start, in ``axes.readiness``; what a run shares with a homing of the cell (the links, homed
since boot, one activity at a time), in ``axes.run_state``; homing a cell, in ``axes.homing``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import can

from axes import objects as od
from axes.budget import bus_budget
from axes.bus import CellBus
from axes.bus_faults import BusFault, FaultKind
from axes.cia402 import PowerState, Statusword, decode_state
from axes.commission import refuse_on_facts
from axes.config import AxisConfig, Wiring
from axes.feed_check import BufferedAxis, feed_shortfall
from axes.feeder import (
    BufferFeeder,
    Feeder,
    FeedStats,
    RecordAllowance,
    SetpointFeeder,
    preload_shared,
    top_up_by_need,
)
from axes.link import AxisLink, DriveError
from axes.objects import BUFFER_ERRORS, BufferStatus
from axes.outcome import (
    AxisReport,
    AxisStatus,
    Event,
    EventCallback,
    EventKind,
    GroupError,
    GroupStatus,
    Progress,
    ProgressCallback,
    Result,
    RunResult,
)
from axes.profiles import profile_for
from axes.profiles.base import Profile
from axes.program import AxisProgram, PvtProgram, program_mismatch
from axes.quick_stop import QuickStop
from axes.readiness import Readiness
from axes.run_state import CellRunState

_T = TypeVar("_T")
_R = TypeVar("_R")

_IP_MODE_ACTIVE = int(Statusword.IP_MODE_ACTIVE)
_TARGET_REACHED = int(Statusword.TARGET_REACHED)
_FAULT_BITS = int(Statusword.FAULT)  # set in FAULT and FAULT REACTION ACTIVE
_BUFFER_ERRORS = int(BUFFER_ERRORS)
START_CHECK_SYNCS = 2  # SYNCs after the start SYNC by which every axis must report ip mode active
NMT_PRE_OPERATIONAL = 0x80
NMT_START = 0x01


_Refusal = tuple[Result, str, "AxisLink | None"]  # why a start does not go ahead, and which axis


# a whole preload before the first SYNC waits this long at most for room in a full transmit queue
# (nothing moves yet; its frames take their wire time, a few ms, and a bus that takes none is broken)
PRELOAD_PATIENCE_S = 0.1


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
        self.on_progress = on_progress
        self.on_event = on_event
        self.progress_every = max(1, progress_every)
        self.start_tolerance_qc = start_tolerance_qc
        self.halt_timeout_ms = halt_timeout_ms
        self.configured = False
        self.last_result: RunResult | None = None
        self._done = threading.Event()
        self._done.set()
        self._feeders: list[Feeder] = []
        self._programs: list[AxisProgram] = []
        self._start_sync: int | None = None
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
        self._configured_boots: dict[int, int] = {}  # every drive's boot count when it was configured
        # the records the bus has room for in one SYNC period, shared by the buffered axes; never less
        # than one per buffered axis (a cell file whose bus has no room for that is refused at load)
        budget = bus_budget(Wiring(bus.config, tuple(axes)))
        self.allowance = RecordAllowance(max(1, budget.records_per_sync, budget.buffered_axes))
        for link in self.links:
            link.status_listeners.append(self._on_status)
        self._status_lag = max((p.sync_answer_every for p in self.profiles), default=1) - 1
        bus.on_fault(self._on_bus_fault)
        if any(p.fixed_period for p in self.profiles):
            bus.sync.add_sender(self._after_sync)

    # --- configuration -----------------------------------------------------------------------
    def configure(self) -> None:
        """Every drive: what it is checked against the cell (axes/commission.py: a drive that is not
        what the cell says is refused, DriveError, before anything is written), then PRE-OPERATIONAL,
        its profile's SDO sequence, then OPERATIONAL and consumers."""
        refuse_on_facts(self.links)
        for link in self.links:  # addressed, not broadcast: other nodes on the bus are not ours
            self.bus.nmt(link.node_id, NMT_PRE_OPERATIONAL)
        self._configured_boots = {link.node_id: self.bus.watch.boot_count(link.node_id) for link in self.links}
        for link, profile in zip(self.links, self.profiles, strict=True):
            profile.configure()
            profile.write_homing()
            link.subscribe_tpdos(profile.tpdos)
        self.bus.sync.expect({p.sync_answer_cob_id: p.sync_answer_every for p in self.profiles})
        for link in self.links:
            self.bus.nmt(link.node_id, NMT_START)
        self.bus.watch.watch_heartbeat(link.node_id for link in self.links)
        self.readiness.forget()
        self.configured = True

    def configure_if_needed(self) -> None:
        """Configure unless configured since every drive last booted (a rebooted drive has its EDS
        defaults again: no PDOs, no mode, no homing settings)."""
        if not self.configured or self.rebooted():
            self.configure()

    def rebooted(self) -> bool:
        """A drive has booted since the group configured it."""
        return any(self.bus.watch.boot_count(lk.node_id) != self._configured_boots.get(lk.node_id) for lk in self.links)

    def _event(self, kind: EventKind, message: str, link: AxisLink | None = None) -> None:
        if self.on_event is not None:
            self.on_event(Event(kind, message, link.joint if link else None, link.node_id if link else None))

    # --- checks before anything moves ------------------------------------------------------------
    def check_program(self, program: PvtProgram) -> str | None:
        """Why this program cannot run on this cell (None: it can)."""
        problems = program_mismatch(program, [link.config for link in self.links], "this cell")
        if problems:
            return "; ".join(problems[:3])
        by_node = {a.node_id: a for a in program.axes}
        buffered = [
            BufferedAxis(link.joint, by_node[link.node_id].records, link.config.buffer)
            for link, profile in zip(self.links, self.profiles, strict=True)
            if profile.name == "epos2_pvt" and link.node_id in by_node
        ]
        return feed_shortfall(buffered, self.allowance.per_sync, self.bus.config.sync_period_ms)

    # --- running ---------------------------------------------------------------------------------
    def run(self, program: PvtProgram, timeout_s: float | None = None) -> RunResult:
        """Configure (once), enable, preload, start on one SYNC, feed to the end: the outcome."""
        early = self.start(program)
        if early is not None:
            return early
        return self.wait(timeout_s)

    def start(self, program: PvtProgram, before_records: Callable[[], object] | None = None) -> RunResult | None:
        """Start a run; returns a result at once only when the program is refused or a drive fails.

        ``before_records``: called once the start's checks are asked, before the first record goes
        out (a service journals the motion there, while the drives answer); what it raises ends
        the start with nothing sent, and is raised from here."""
        with self._lock:
            if self._running:
                raise GroupError("a program is already running on this cell")
            if self.state.holder is not None:
                raise GroupError("the cell is homing: one motion at a time")
            reason = self.check_program(program)
            if reason is not None:
                return self._finish_early(Result.REJECTED, reason)
            feeders: list[Feeder | None] = [None] * len(self.links)
            try:
                self.configure_if_needed()
                by_node = {a.node_id: a for a in program.axes}
                self._programs = [by_node[link.node_id] for link in self.links]
                self._stop_request = None
                self._starting = True
                self.readiness.wait()  # the last run's cleanup, if still going
                ready = self.readiness.take()
                if all(ready):
                    feeders, refusal = self._check_by_sync(before_records)
                else:
                    refusal = self._check_by_sdo(ready, before_records)
                if refusal is not None:
                    result, message, link = refusal
                    return self._finish_early(result, message, link)
            except DriveError as exc:
                link = next((lk for lk in self.links if lk.node_id == exc.node_id), None)
                return self._finish_early(Result.CONFIGURATION_ERROR, str(exc), link)
            finally:
                self._starting = False
            if self._stop_request is not None:
                return self._finish_early(Result.STOPPED, self._stop_request)

            self._feeders = [
                f if f is not None else p.feeder(prog, self.allowance)
                for f, p, prog in zip(feeders, self.profiles, self._programs, strict=True)
            ]
            refusal = self._preload_records(checked=any(f is not None for f in feeders))
            if refusal is not None:
                return self._finish_early(*refusal)
            self._ip_start = [None] * len(self.links)
            self._end_words_sent = [False] * len(self.links)
            self._ending = None
            self._halted_at = None
            self._halt_deadline = None
        sync = self.bus.sync
        sync.keep_period()  # real time: the start SYNC one period after the check SYNC
        with sync.lock, self._lock:
            self.state.claim(self, "the cell is homing: one motion at a time")
            self._done.clear()
            self._running = True
            for feeder in self._feeders:  # the fixed-period setpoints the start SYNC validates
                if not isinstance(feeder, BufferFeeder):
                    feeder.preload()
            self._start_sync = sync.count + 1
            if self.bus.config.max_sync_gap_periods is None:  # the profiles say (axes.sync)
                gaps = (p.max_sync_gap_ms(prog) for p, prog in zip(self.profiles, self._programs, strict=True))
                sync.max_gap_s = min(gaps) / 1000.0
            for link, profile in zip(self.links, self.profiles, strict=True):
                link.send_controlword(profile.start_controlword())
            sync.add_listener(self._on_sync)
            self.bus.watch.arm_sync_watch()
            self._event(EventKind.STARTED, f"program of {program.duration_ms} ms started on SYNC {self._start_sync}")
            sync.start()
        return None

    def _preload_records(self, checked: bool) -> _Refusal | None:
        """Every buffered axis's preload. After a check SYNC (SYNC periods under way), at most the
        cell's record allowance per SYNC period: while one is not all out, one more SYNC before the
        start SYNC (the drives, enabled and idle, answer it), the next share of the records after it;
        a drive that does not answer refuses the start. A start checked by SDO has no SYNC running
        yet, so no period to keep to: its preload goes out whole before the start SYNC (on the wall
        clock that delays the first SYNC by the records' bus time, a few ms, and nothing else)."""
        sync = self.bus.sync
        if not checked:
            with self.bus.network.patient(PRELOAD_PATIENCE_S):
                for feeder in self._feeders:
                    if isinstance(feeder, BufferFeeder):
                        feeder.preload(whole=True)
            return None
        while not preload_shared(self._feeders, self.allowance):
            sync.keep_period()
            owed = sync.step()
            self.allowance.new_period()
            silent = sorted({cob & 0x7F for cob in sync.wait_answered(owed, self.bus.lost_sync_timeout_s)})
            if silent:
                self.configured = False
                link = next((lk for lk in self.links if lk.node_id in silent), None)
                return (
                    Result.LOST_SYNC,
                    f"node(s) {silent} did not answer a SYNC before the start: nothing started",
                    link,
                )
        return None

    def _per_axis(self, work: Callable[[_T], _R], items: Iterable[_T]) -> Iterator[_R]:
        """``work`` on every axis concurrently (the drives answer SDO in parallel); results in axis
        order; the first DriveError in axis order is raised."""
        futures = [self._pool.submit(work, item) for item in items]
        return (f.result() for f in futures)

    def _needs_enable(self, i: int, ready: bool) -> bool:
        """Axis i is enabled at the start (its buffer cleared) unless it was ready and its check just
        found it OPERATION ENABLED."""
        return not (ready and self.links[i].state is PowerState.OPERATION_ENABLED)

    def _enable(self, axes: list[int]) -> None:
        """Enable these axes for the start, all at once, from the statusword their check just read."""
        for _ in self._per_axis(lambda i: self.profiles[i].enable(fresh=True), axes):
            pass

    def settle(self, timeout_s: float | None = None) -> bool:
        """Wait until the end of the last run has been cleaned up in every drive (buffers empty,
        interpolation ended: ``axes.readiness``). False: not within ``timeout_s``."""
        return self.readiness.settle(timeout_s)

    def _check_by_sync(
        self, before_records: Callable[[], object] | None
    ) -> tuple[list[Feeder | None], _Refusal | None]:
        """Every axis is ready (enabled, buffer cleared and open): the start's check is the drives'
        answers to one SYNC, every statusword and position as of the same instant, in one SYNC round
        instead of two SDO round trips per axis. The records go out while the drives answer (no
        start word yet, so they move nothing; a refused start leaves the next start to clear the
        buffers with a full enable), after the check SYNC, so a fixed-period drive's first setpoint
        is validated by the start SYNC, not by the check. The start SYNC follows one period later:
        the motion starts two SYNC periods after the records are out."""
        sync = self.bus.sync
        check = sync.step()
        self.allowance.new_period()
        if before_records is not None:
            before_records()
        preloaded = [p.feeder(prog, self.allowance) for p, prog in zip(self.profiles, self._programs, strict=True)]
        preload_shared(preloaded, self.allowance)
        feeders: list[Feeder | None] = list(preloaded)
        silent = sorted({cob & 0x7F for cob in sync.wait_answered(check, self.bus.lost_sync_timeout_s)})
        if silent:
            link = next((lk for lk in self.links if lk.node_id in silent), None)
            self.configured = False  # it may come back reset: the next start configures again
            return feeders, (
                Result.LOST_SYNC,
                f"node(s) {silent} did not answer the start's check SYNC within "
                f"{self.bus.lost_sync_timeout_s:.3f} s: nothing started",
                link,
            )
        for link, prog in zip(self.links, self._programs, strict=True):
            refusal = self._refusal(link, prog)
            if refusal is not None:
                return feeders, refusal
        # a drive that left OPERATION ENABLED without a fault (nothing should do that) is enabled
        # again, which clears its buffer: its records go out again at the start
        stale = [i for i in range(len(self.links)) if self._needs_enable(i, True)]
        self._enable(stale)
        for i in stale:
            feeders[i] = None
        return feeders, None

    def _check_by_sdo(self, ready: list[bool], before_records: Callable[[], object] | None) -> _Refusal | None:
        """Not every axis is ready (the first start, or after a fault, a stop or a recovery's failure):
        every drive is asked its statusword and position by SDO at once (one round trip per
        question, not per axis), and only when every axis passes, the enables it needs."""
        checks = self._per_axis(self._start_check, zip(self.links, self._programs, strict=True))  # asked now
        if before_records is not None:
            before_records()
        refusal = next((r for r in list(checks) if r is not None), None)
        if refusal is not None:
            return refusal
        self._enable([i for i, r in enumerate(ready) if self._needs_enable(i, r)])
        return None

    def _start_check(self, link_and_program: tuple[AxisLink, AxisProgram]) -> _Refusal | None:
        """Read what the drive says now (SDO), then judge it."""
        link, prog = link_and_program
        link.read_statusword()
        link.position = link.read(od.POSITION_ACTUAL_VALUE, 0, "i")
        return self._refusal(link, prog)

    def _refusal(self, link: AxisLink, prog: AxisProgram) -> _Refusal | None:
        """Why this axis cannot start the program, from the statusword and position it last reported
        (None: it can)."""
        if decode_state(link.statusword).is_fault:
            return (
                Result.REJECTED,
                (
                    f"axis {link.joint} (node {link.node_id}) is in FAULT "
                    f"(statusword 0x{link.statusword:04X}): recover first"
                ),
                link,
            )
        start = int(prog.records[0, 0])
        if link.position is None or abs(link.position - start) > self.start_tolerance_qc:
            where = f"axis {link.joint} is at {link.position} qc, the program starts at {start} qc"
            return Result.REJECTED, where, link
        return None

    def wait(self, timeout_s: float | None = None) -> RunResult:
        """Block until the run ends. The timeouts only detect a cell that stopped answering: the run
        is then halted, and if no drive answers the halt SYNCs either, ended with what is known."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        halt_grace = self.halt_timeout_ms / 1000.0 + 2.0 * self.bus.lost_sync_timeout_s
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
            # a status TPDO every n SYNCs reports ip mode up to n - 1 SYNCs later (axes.tpdo_rates)
            if self._ending is None and elapsed >= START_CHECK_SYNCS + self._status_lag:
                self._check_started()
            if self._ending is None:
                self.allowance.new_period()
                for feeder in self._feeders:
                    feeder.on_sync(elapsed)
                top_up_by_need(self._feeders, self.allowance)
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

    def _on_status(self, link: AxisLink) -> None:
        """A TPDO arrived (notifier thread): buffered feeders react to the buffer status at once."""
        if not self._running:
            return
        i = self.links.index(link)
        if self._feeders and link.buffer_status:
            self._feeders[i].on_status(link.buffer_status)

    def _on_bus_fault(self, fault: BusFault) -> None:
        link = next((lk for lk in self.links if lk.node_id == fault.node_id), None)
        if link is not None and fault.kind is FaultKind.EMCY:
            link.last_emcy = (fault.code, fault.message)
        self._bus_faults += 1
        if link is not None:  # whatever it was, that drive is enabled again at the next start
            self.readiness.forget(self.links.index(link))
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
                self._quick_stop_too(fault.message, link)  # the halt word waits for a SYNC that will not come
                return
            if self._ending is not None or not self._running:
                return
            if fault.kind.sync_failed:
                self._quick_stop(kind, fault.message, link)
                return
            gone = kind in (Result.HEARTBEAT_LOST, Result.LOST_SYNC)
            stalled = bool(sync.behind())
            if gone:
                self.configured = False  # the node may come back reset: recover() configures again
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

    # --- halt / stop -----------------------------------------------------------------------------
    def _halt(self, result: Result, message: str, link: AxisLink | None) -> None:
        """Halt every axis on the next SYNC and stop feeding (called with the lock held)."""
        t0 = time.perf_counter()
        sync = self.bus.sync
        with sync.lock:
            unsent = []
            for lk, profile, feeder in zip(self.links, self.profiles, self._feeders, strict=True):
                if not profile.ramps_by_itself and isinstance(feeder, SetpointFeeder):
                    # no ramp of its own: braking setpoints within 0x60C5 / 0x6085 (axes.stop_ramp)
                    feeder.decelerate(profile.stop_records(feeder, quick=result is not Result.STOPPED))
                    continue
                feeder.enabled = False
                try:
                    lk.send_controlword(profile.halt_controlword())
                except can.CanError as exc:  # the bus is gone: the drives stop on the master's heartbeat loss
                    unsent.append(f"node {lk.node_id}: {exc}")
            halt_sync = sync.count + 1
            fault_sync = sync.count  # the SYNC period in which the event was seen
        res = self._result(result, message, link)
        res.fault_sync = fault_sync
        res.halt_sync = halt_sync
        res.halt_latency_s = time.perf_counter() - t0
        self._ending = res
        self._halted_at = time.monotonic()
        self._halt_deadline = halt_sync + int(self.halt_timeout_ms / self.bus.config.sync_period_ms)
        lost = f" (not sent to {'; '.join(unsent)}: those drives stop on the master's heartbeat loss)" if unsent else ""
        self._event(EventKind.HALTED, f"all axes halted: {message}{lost}", link)

    def _quick_stop(self, result: Result, message: str, link: AxisLink | None) -> None:
        """The master cannot keep SYNC: no more SYNC, every axis quick stopped by SDO, NMT stop for
        the drives that do not confirm (``axes.quick_stop``); the run ends when that is done (called
        with the SYNC lock and the group lock held)."""
        sync = self.bus.sync
        for feeder in self._feeders:
            feeder.enabled = False
        sync.stop()
        res = self._result(result, message, link)
        res.fault_sync = sync.count
        self._ending = res
        self._halted_at = time.monotonic()
        self._halt_deadline = None
        self.readiness.forget()
        self._event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)
        self.last_quick_stop = self.bus.quick_stop([lk.node_id for lk in self.links], message, self._quick_stopped)

    def _quick_stop_too(self, message: str, link: AxisLink | None) -> None:
        """A halt by the synchronous RPDO is under way and SYNC fails: quick stop by SDO as well."""
        self.bus.sync.stop()
        self._halt_deadline = None
        self._event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)
        self.last_quick_stop = self.bus.quick_stop([lk.node_id for lk in self.links], message, self._quick_stopped)

    def _quick_stopped(self, stop: QuickStop) -> None:
        """Every drive confirmed the quick stop or was sent NMT stop (the quick stop's thread)."""
        ending = self._ending
        if ending is None:
            return
        ending.halt_latency_s = stop.latency_s
        ending.message = f"{ending.message}; {stop.describe()}"
        if stop.nmt_stopped or stop.unsent:
            self.configured = False  # NMT STOPPED: the next start configures again
        self._end(ending)

    def _check_halted(self, n: int) -> None:
        assert self._ending is not None
        if self._halt_deadline is None:
            return  # quick stopped by SDO: the quick stop ends the run (_quick_stopped)
        if n < (self._ending.halt_sync or 0):
            return
        elapsed = n - (self._start_sync or n) - 1  # a stop ramp is over once its drive held its end one SYNC
        still = [
            lk
            for lk, feeder in zip(self.links, self._feeders, strict=True)
            if decode_state(lk.statusword) == PowerState.OPERATION_ENABLED
            and (not lk.statusword & _TARGET_REACHED or (feeder.enabled and not feeder.finished(elapsed, False)))
        ]
        if not still or n >= self._halt_deadline:
            self.bus.sync.stop()
            self._end(self._ending)

    def stop(self, reason: str = "stop requested") -> None:
        """Halt all axes on the next SYNC (any thread). The run then ends with Result.STOPPED; a
        start still configuring the drives does not start the motion."""
        if self._starting:
            self._stop_request = reason
        if self.state.holder is not self:  # a homing holds the cell
            self.state.stop(reason)
        sync = self.bus.sync
        with sync.lock, self._lock:
            if not self._running or self._ending is not None:
                return
            if not sync.running and not sync.lockstep:  # no SYNC to carry the halt word
                self._quick_stop(Result.STOPPED, reason, None)
            else:
                self._halt(Result.STOPPED, reason, None)

    def _result(self, result: Result, message: str, link: AxisLink | None = None) -> RunResult:
        res = RunResult(
            result,
            message,
            link.joint if link else None,
            link.node_id if link else None,
            self._start_sync,
            self.bus.sync.answered,
            sync_period_ms=self.bus.config.sync_period_ms,
        )
        return res

    def _reports(self) -> list[AxisReport]:
        out = []
        for i, (link, status) in enumerate(zip(self.links, self.status().axes, strict=True)):
            prog = self._programs[i] if i < len(self._programs) else None
            feeder = self._feeders[i] if i < len(self._feeders) else None
            out.append(
                AxisReport(
                    **vars(status),
                    target_position=int(prog.records[-1, 0]) if prog is not None else None,
                    feed=feeder.stats if feeder is not None else FeedStats(),
                    start_sync=self._ip_start[i] if i < len(self._ip_start) else None,
                    joint_position=None
                    if link.position is None
                    else float(link.config.scaling.qc_to_position(link.position)),
                )
            )
        return out

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

    # --- recovery and status ---------------------------------------------------------------------
    def recover(self) -> RunResult:
        """Fault reset and re-enable every axis (by SDO), and put lost nodes back to OPERATIONAL."""
        with self._lock:
            if self._running:
                raise GroupError("cannot recover while a program is running: stop it first")
            self.readiness.wait()  # not two enables of one drive at once
            self.bus.sync.stop()
            try:
                self.configure_if_needed()
            except DriveError as exc:
                return self._finish_early(Result.CONFIGURATION_ERROR, str(exc))
            for link in self.links:
                self.bus.nmt(link.node_id, NMT_START)
            self.bus.sync.expect({p.sync_answer_cob_id: p.sync_answer_every for p in self.profiles})
            for link, profile in zip(self.links, self.profiles, strict=True):
                try:
                    profile.enable()
                except DriveError as exc:
                    return self._finish_early(Result.CONFIGURATION_ERROR, f"recover failed: {exc}", link)
                link.last_emcy = None
                link.buffer_status = link.buffer_status & ~int(BUFFER_ERRORS)
            self.readiness.mark_all()  # enabled just now: ready
            self.bus.watch.watch_heartbeat(link.node_id for link in self.links)
            self._event(EventKind.RECOVERED, "all axes fault-free and enabled")
            res = self._result(Result.FINISHED, "recovered: every axis is enabled")
            res.axes = self._reports()
            return res

    def _progress(self, n: int) -> Progress:
        return Progress(
            sync=n,
            elapsed_ms=(n - (self._start_sync or n)) * self.bus.config.sync_period_ms,
            positions=tuple(lk.position for lk in self.links),
            levels=tuple(f.level for f in self._feeders),
            states=tuple(decode_state(lk.statusword) for lk in self.links),
            statuswords=tuple(lk.statusword for lk in self.links),
        )

    def status(self, refresh: bool = False) -> GroupStatus:
        """What the drives say: from their TPDOs while running; ``refresh`` reads statusword and
        position by SDO first when idle (no SYNC, so no TPDO, flows between runs in lockstep)."""
        if refresh and not self._running:
            with contextlib.suppress(DriveError):
                self.refresh()
        axes = []
        homed = self.state.homed
        for i, link in enumerate(self.links):
            level = self._feeders[i].level if self._running and i < len(self._feeders) else None
            axes.append(
                AxisStatus(
                    joint=link.joint,
                    node_id=link.node_id,
                    profile=link.config.profile,
                    state=decode_state(link.statusword),
                    statusword=link.statusword,
                    position=link.position,
                    buffer_status=link.buffer_status,
                    buffer_flags=tuple(f.name.lower() for f in BufferStatus if f & link.buffer_status and f.name),
                    buffer_level=level,
                    last_emcy=link.last_emcy,
                    nmt_state=self.bus.watch.heartbeat_state(link.node_id),
                    homed=homed[i],
                )
            )
        elapsed = None
        if self._running and self._start_sync is not None:
            elapsed = (self.bus.sync.answered - self._start_sync) * self.bus.config.sync_period_ms
        return GroupStatus(
            self._running,
            self.bus.sync.count,
            elapsed,
            tuple(axes),
            self.last_result.result if self.last_result else None,
        )

    def refresh(self) -> None:
        """Read every statusword and position by SDO (when no TPDO flows, e.g. between runs)."""
        for link in self.links:
            link.read_statusword()
            link.position = link.read(od.POSITION_ACTUAL_VALUE, 0, "i")

    def close(self) -> None:
        """Release the drives (at rest, each is shut down, then stops watching the master's heartbeat:
        an orderly close is not a lost master, ``Profile.release_master``) and let go of the bus. A
        close during a run leaves them watching: the heartbeat stops with the bus and every drive
        stops by itself; so does a close after the bus's (nothing can be said on a closed bus)."""
        if self.configured and not self._running and self.bus.is_open:
            for profile in self.profiles:
                profile.release_master()
            self.configured = False  # a group used again arms the consumers again
        self.bus.sync.remove_sender(self._after_sync)
        self._pool.shutdown(wait=True)
        for link in self.links:
            link.unsubscribe()
            if self._on_status in link.status_listeners:
                link.status_listeners.remove(self._on_status)
        self.bus.remove_fault_callback(self._on_bus_fault)
