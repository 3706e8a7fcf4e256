"""One start of a program on a cell: what it runs, the SYNC it started on, and its SYNC-time work.

``AxisGroup`` (axes/master/group/axis_group.py) is the cell's lasting parts (links, profiles, the
configuration, the readiness, one lock); every start makes a ``Run`` that owns what belongs to that
start alone: the axis programs and their feeders, the start SYNC, which axes reported ip mode, the
fixed-period end words sent, and its ``Halting`` (axes/master/group/halt.py). Nothing of a run is reset
by hand for the next one: the next start makes a new ``Run``.

A run is event driven: after every SYNC sent (``after_sync``, the sending thread) the fixed-period
setpoints go out; after every SYNC answered (``on_sync``, the notifier thread) the drives are checked,
the buffered axes topped up and the end detected; a status TPDO (``on_status``) tops its buffered axis
up at once on the wall clock.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence

import can

from pvtflow.axes.drive.cia402 import Statusword, decode_state
from pvtflow.axes.drive.objects import BUFFER_ERRORS
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, top_up_by_need
from pvtflow.axes.master.group.halt import Halting
from pvtflow.axes.master.group.outcome import GroupError, Result, RunResult
from pvtflow.axes.master.group.run_state import RunParts
from pvtflow.axes.master.link import AxisLink
from pvtflow.axes.master.run_queue import RunQueue

_IP_MODE_ACTIVE = int(Statusword.IP_MODE_ACTIVE)
_FAULT_BITS = int(Statusword.FAULT)  # set in FAULT and FAULT REACTION ACTIVE
_BUFFER_ERRORS = int(BUFFER_ERRORS)
START_CHECK_SYNCS = 2  # SYNCs after the start SYNC by which every axis must report ip mode active


class Run:
    """One start: ``Run(parts, programs)``, then ``take_feeders`` once the start's checks passed and
    ``begin`` on the start SYNC's count. ``live`` until ``end``; ``on_end`` hears the result."""

    def __init__(self, parts: RunParts, programs: Sequence[AxisProgram], on_end: Callable[[RunResult], None]) -> None:
        self.parts = parts
        self.programs: tuple[AxisProgram, ...] = tuple(programs)
        self.feeders: tuple[Feeder, ...] = ()
        self.start_sync: int | None = None
        self.start_sent: float | None = None  # time.monotonic() once the start SYNC was out (wall clock)
        self.ip_start: list[int | None] = [None] * len(parts.links)  # the SYNC each axis reported ip mode
        self.end_words_sent = [False] * len(parts.links)
        self.live = False
        self.end_as: tuple[Result, str] | None = None  # how the run ends at its end, if changed (ends_as)
        self.halting = Halting(parts, self)
        self.queue = RunQueue(parts.bus.config)  # the programs queued after this run's first
        self._on_end = on_end

    # --- the run's life ------------------------------------------------------------------------------
    def take_feeders(self, feeders: Sequence[Feeder]) -> None:
        self.feeders = tuple(feeders)
        self.queue.begin(self.programs, self.feeders)

    def begin(self, start_sync: int) -> None:
        """The run is live from now on; its motion starts on SYNC ``start_sync`` (SYNC lock held)."""
        self.start_sync = start_sync
        self.live = True

    def take_program(self, i: int, program: AxisProgram) -> None:
        """Axis ``i`` runs ``program`` from now on (a change of the records not yet sent: axes.master.splice)."""
        programs = list(self.programs)
        programs[i] = program
        self.programs = tuple(programs)

    def ends_as(self, outcome: tuple[Result, str] | None) -> None:
        """The run, changed to end early (an on-path stop), ends with ``outcome`` at its end (None: FINISHED)."""
        self.end_as = outcome

    def queue_refusal(self, programs: Sequence[AxisProgram]) -> float:
        """The run's time now (ms), if ``programs`` (axis order) can be queued after it now (else
        GroupError, nothing changed; axes.master.run_queue). Group lock held."""
        sync = self.parts.bus.sync
        if not self.live or self.ending is not None or self.start_sync is None:
            raise GroupError("no program runs on this cell to queue after")
        # the SYNCs sent, not answered: a program queued now must not be late for the one going out
        elapsed_ms = (sync.count - self.start_sync) * self.parts.bus.config.sync_period_ms
        elapsed_ms = max(elapsed_ms, self.drive_clock_ms())
        why = self.queue.refusal(programs, self.feeders, elapsed_ms)
        if why is not None:
            raise GroupError(why)
        return elapsed_ms

    def drive_clock_ms(self) -> float:
        """The drives' clock (program time): SYNC periods since the start SYNC; on the wall clock the time
        since the start SYNC went out, which the EPOS2 runs its records by (``axes.master.group.feeder``)."""
        sync = self.parts.bus.sync
        now = (sync.answered - (self.start_sync or sync.answered)) * self.parts.bus.config.sync_period_ms
        if not sync.clock.lockstep and self.start_sent is not None:
            now = max(now, (time.monotonic() - self.start_sent) * 1000.0)
        return now

    def result(self, result: Result, message: str, link: AxisLink | None = None) -> RunResult:
        return self.parts.reports.result(self, result, message, link)

    def end(self, result: RunResult) -> None:
        """The run is over (any thread): no more SYNC work, the result with every axis's report."""
        bus = self.parts.bus
        with bus.sync.lock, self.parts.lock:
            if not self.live:
                return
            bus.sync.remove_listener(self.on_sync)
            bus.watch.disarm_sync_watch()
            result.end_sync = bus.sync.answered
            result.axes = self.parts.reports.axis_reports(self)
            self.live = False
            self._on_end(result)

    @property
    def ending(self) -> RunResult | None:
        """How the run ends, once it is halting or ending."""
        return self.halting.ending

    # --- events ----------------------------------------------------------------------------------
    def after_sync(self, n: int) -> None:
        """SYNC ``n`` is on the bus (the sending thread, SYNC lock held): the frames that must precede
        SYNC n + 1 go out now, unpaced by the drives' answers. No group lock: a halt disables the
        feeders under the SYNC lock, so none sends after it."""
        start = self.start_sync
        if not self.live or start is None or n < start:
            return
        if n == start:
            self.start_sent = time.monotonic()  # t = 0 of the buffered drives' records
        if self.parts.bus.sync.cyclic_producing:
            return  # the cyclic process sent them (axes.master.cyclic.process)
        for feeder in self.feeders:  # halting: only the stop ramps of drives without a ramp (Halting.halt)
            feeder.after_sync(n - start)

    def on_sync(self, n: int) -> None:
        """After every answered SYNC (notifier thread; before the next SYNC in lockstep)."""
        parts = self.parts
        with parts.lock:
            if not self.live or self.start_sync is None:
                return
            elapsed = n - self.start_sync
            for i, link in enumerate(parts.links):
                if self.ip_start[i] is None and link.statusword & _IP_MODE_ACTIVE:
                    self.ip_start[i] = n
            if self.ending is None:
                self._check_drives()
            # a status TPDO every n SYNCs reports ip mode up to n - 1 SYNCs later (axes.master.tpdo_rates)
            if self.ending is None and elapsed >= START_CHECK_SYNCS + parts.status_lag:
                self._check_started()
            if self.ending is None:
                for feeder in self.feeders:
                    feeder.on_sync(elapsed)
                self._feed()
                self.queue.at_sync(elapsed)
                self._check_finished(elapsed)
            else:
                self.halting.check(n)
            parts.progress(n, self)

    def on_status(self, link: AxisLink) -> None:
        """A TPDO arrived (notifier thread): buffered feeders react to the buffer status at once; on
        the wall clock a buffered drive's own answer tops it up too, whatever the others' answers do."""
        if not self.live or not self.feeders:
            return
        feeder = self.feeders[self.parts.links.index(link)]
        if link.buffer_status:
            feeder.on_status(link.buffer_status)
        bus = self.parts.bus
        if isinstance(feeder, BufferFeeder) and not bus.sync.clock.lockstep:
            # one try per record: a full transmit queue keeps its room for SYNC and the setpoints, and
            # a record refused waits for the next top-up (the FIFO's depth covers it)
            with self.parts.lock, bus.network.patient(0), contextlib.suppress(can.CanError):
                if self.live and self.ending is None and self.start_sent is not None:
                    self._feed()

    # --- what every answered SYNC checks ---------------------------------------------------------------
    def _check_drives(self) -> None:
        for link in self.parts.links:
            if not (link.statusword & _FAULT_BITS or link.buffer_status & _BUFFER_ERRORS):
                continue
            state = decode_state(link.statusword)
            if state.is_fault or link.buffer_status & _BUFFER_ERRORS:
                why = f"statusword 0x{link.statusword:04X} ({state.value})"
                if link.buffer_status & BUFFER_ERRORS:
                    why += f", buffer: {link.describe_buffer()}"
                if link.last_emcy is not None:
                    why += f", last EMCY 0x{link.last_emcy[0]:04X} {link.last_emcy[1]}"
                self.halting.halt(Result.DRIVE_FAULT, f"axis {link.joint} (node {link.node_id}) faulted: {why}", link)
                return

    def _check_started(self) -> None:
        for i, link in enumerate(self.parts.links):
            if self.ip_start[i] is None:
                self.halting.halt(
                    Result.DRIVE_FAULT,
                    f"axis {link.joint} (node {link.node_id}) did not enter ip mode "
                    f"(statusword 0x{link.statusword:04X})",
                    link,
                )
                return

    def _check_finished(self, elapsed: int) -> None:
        done = True
        parts = self.parts
        for i, (link, profile, feeder) in enumerate(zip(parts.links, parts.profiles, self.feeders, strict=True)):
            ip_active = bool(link.statusword & _IP_MODE_ACTIVE)
            if feeder.finished(elapsed, ip_active and profile.name.buffered):
                if not profile.name.buffered and not self.end_words_sent[i]:
                    link.send_controlword(profile.end_controlword())  # the fixed-period end: bit 4 off
                    self.end_words_sent[i] = True
                    done = False
            else:
                done = False
        if done:
            parts.bus.sync.stop()
            self.end(self.result(*(self.end_as or (Result.FINISHED, "every axis reached its end record"))))

    def _feed(self) -> None:
        """Top the buffered axes up from the allowance of the period of the last SYNC sent (group lock
        held). On the wall clock their drives' clock is the time since the start SYNC went out
        (``axes.master.group.feeder``), not the SYNCs every drive has answered: one drive's late answers must not
        stop another drive's feed while that one runs its records on its own clock."""
        sync = self.parts.bus.sync
        if sync.cyclic_producing:
            return  # the cyclic process tops up; the feeders here mirror it (axes.master.cyclic.process)
        allowance = self.parts.allowance
        allowance.at_sync(sync.count)
        if not sync.clock.lockstep and self.start_sent is not None:
            elapsed_ms = (time.monotonic() - self.start_sent) * 1000.0
            for feeder in self.feeders:
                if isinstance(feeder, BufferFeeder):
                    feeder.run_to(elapsed_ms)
        top_up_by_need(self.feeders, allowance)
