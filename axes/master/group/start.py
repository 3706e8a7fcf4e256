"""Starting a run on one SYNC: the start's checks, the enables and the preload, a part of ``AxisGroup``.

A cell whose every axis is ready is checked by the drives' answers to one SYNC (no SDO); otherwise
each drive is asked by SDO, all at once. The records go out while the drives answer; the start SYNC
follows one period later, so every axis starts on the same SYNC. The methods work on ``AxisGroup``'s
state (``axes.master.group.axis_group``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

import can

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState, decode_state
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.master.bus.sync import below_sync
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, preload_shared
from pvtflow.axes.master.group.outcome import EventKind, GroupError, Result, RunResult
from pvtflow.axes.master.link import AxisLink, DriveError

_T = TypeVar("_T")
_R = TypeVar("_R")

_Refusal = tuple[Result, str, "AxisLink | None"]  # why a start does not go ahead, and which axis


# a whole preload before the first SYNC waits this long at most for room in a full transmit queue
# (nothing moves yet; its frames take their wire time, a few ms, and a bus that takes none is broken)
PRELOAD_PATIENCE_S = 0.1


class GroupStart:
    """AxisGroup's start: checks, enables, preload, the start SYNC (mixed into ``AxisGroup``)."""

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
            self.queue.begin(self._programs, self._feeders)
            refusal = self._preload_records(checked=any(f is not None for f in feeders))
            if refusal is not None:
                return self._finish_early(*refusal)
            self._ip_start = [None] * len(self.links)
            self._end_words_sent = [False] * len(self.links)
            self._ending = None
            self._halted_at = None
            self._halt_deadline = None
        sync = self.bus.sync
        # the caller holds the SYNC lock while SYNC starts: at normal priority, preempted there, it would
        # hold the start SYNC up for a scheduler slice (axes.master.bus.sync.below_sync)
        with below_sync(sync):
            sync.keep_period()  # real time: the start SYNC one period after the check SYNC
            with sync.lock, self._lock:
                self.state.claim(self, "the cell is homing: one motion at a time")
                self._done.clear()
                self._running = True
                self._start_sync = sync.count + 1
                self._start_sent = None
                sync.setpoints_per_sync = any(not p.name.buffered for p in self.profiles)
                run_gap_s = None  # the bus's own, set in its config
                if self.bus.config.max_sync_gap_periods is None:  # the profiles say (axes.master.bus.sync)
                    gaps = (p.max_sync_gap_ms(prog) for p, prog in zip(self.profiles, self._programs, strict=True))
                    run_gap_s = min(gaps) / 1000.0
                # before the start SYNC nothing waits on these frames: a full transmit queue only delays
                # them by the wire time of what is ahead (as the preload's)
                try:
                    with self.bus.network.patient(PRELOAD_PATIENCE_S):
                        for feeder in self._feeders:  # the fixed-period setpoints the start SYNC validates
                            if not isinstance(feeder, BufferFeeder):
                                feeder.preload()
                        for link, profile in zip(self.links, self.profiles, strict=True):
                            link.send_controlword(profile.start_controlword())
                except (can.CanError, OSError) as exc:
                    # the drives that got their start word would start alone at the next SYNC, whoever
                    # sends it: every axis is quick stopped by SDO instead, and that ends the run
                    self._quick_stop(Result.BUS_ERROR, f"the start could not be sent: {exc}", None)
                    return None
                if sync.cyclic is not None:  # the run's feeders go on in the cyclic process from here
                    sync.cyclic.hand_over(self._feeders, self.profiles, self.allowance, sync.max_gap_s)
                sync.add_listener(self._on_sync)
                self.bus.watch.arm_sync_watch()
                started = f"program of {program.duration_ms} ms started on SYNC {self._start_sync}"
                self._event(EventKind.STARTED, started)
                sync.start(max_gap_s=run_gap_s)
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
            self.allowance.new_period(sync.count)
            silent = sorted({od.node_of_cob_id(cob) for cob in sync.wait_answered(owed, self.bus.lost_sync_timeout_s)})
            if silent:
                self.configuration.forget()
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
        interpolation ended: ``axes.master.group.readiness``). False: not within ``timeout_s``."""
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
        silent = sorted({od.node_of_cob_id(cob) for cob in sync.wait_answered(check, self.bus.lost_sync_timeout_s)})
        if silent:
            link = next((lk for lk in self.links if lk.node_id in silent), None)
            self.configuration.forget()  # it may come back reset: the next start configures again
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
