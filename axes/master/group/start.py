"""The start's checks, the enables and the preload: ``StartChecks``, a part of ``AxisGroup``.

A cell whose every axis is ready is checked by the drives' answers to one SYNC (no SDO); otherwise
each drive is asked by SDO, all at once. The records go out while the drives answer; the start SYNC
follows one period later (``AxisGroup.start``), so every axis starts on the same SYNC.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState, decode_state
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.configure import Configured
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, RecordAllowance, preload_shared
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.master.link import AxisLink
from pvtflow.axes.master.profiles.base import Profile

_T = TypeVar("_T")
_R = TypeVar("_R")

Refusal = tuple[Result, str, "AxisLink | None"]  # why a start does not go ahead, and which axis


# a whole preload before the first SYNC waits this long at most for room in a full transmit queue
# (nothing moves yet; its frames take their wire time, a few ms, and a bus that takes none is broken)
PRELOAD_PATIENCE_S = 0.1


class StartChecks:
    """Whether the drives can start a program, the enables it needs and its preload."""

    def __init__(
        self,
        bus: CellBus,
        links: Sequence[AxisLink],
        profiles: Sequence[Profile],
        pool: ThreadPoolExecutor,
        allowance: RecordAllowance,
        configuration: Configured,
        tolerance_qc: int,
    ) -> None:
        self.bus = bus
        self.links = links
        self.profiles = profiles
        self._pool = pool
        self.allowance = allowance
        self._configuration = configuration
        self.tolerance_qc = tolerance_qc  # how far from a program's first position an axis may start

    def preload(self, feeders: Sequence[Feeder], checked: bool) -> Refusal | None:
        """Every buffered axis's preload. After a check SYNC (SYNC periods under way), at most the
        cell's record allowance per SYNC period: while one is not all out, one more SYNC before the
        start SYNC (the drives, enabled and idle, answer it), the next share of the records after it;
        a drive that does not answer refuses the start. A start checked by SDO has no SYNC running
        yet, so no period to keep to: its preload goes out whole before the start SYNC (on the wall
        clock that delays the first SYNC by the records' bus time, a few ms, and nothing else)."""
        sync = self.bus.sync
        if not checked:
            with self.bus.network.patient(PRELOAD_PATIENCE_S):
                for feeder in feeders:
                    if isinstance(feeder, BufferFeeder):
                        feeder.preload(whole=True)
            return None
        while not preload_shared(feeders, self.allowance):
            sync.keep_period()
            owed = sync.step()
            self.allowance.new_period(sync.count)
            silent = sorted({od.node_of_cob_id(cob) for cob in sync.wait_answered(owed, self.bus.lost_sync_timeout_s)})
            if silent:
                self._configuration.forget()
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

    def by_sync(
        self, programs: Sequence[AxisProgram], before_records: Callable[[], object] | None
    ) -> tuple[list[Feeder | None], Refusal | None]:
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
        preloaded = [p.feeder(prog, self.allowance) for p, prog in zip(self.profiles, programs, strict=True)]
        preload_shared(preloaded, self.allowance)
        feeders: list[Feeder | None] = list(preloaded)
        silent = sorted({od.node_of_cob_id(cob) for cob in sync.wait_answered(check, self.bus.lost_sync_timeout_s)})
        if silent:
            link = next((lk for lk in self.links if lk.node_id in silent), None)
            self._configuration.forget()  # it may come back reset: the next start configures again
            return feeders, (
                Result.LOST_SYNC,
                f"node(s) {silent} did not answer the start's check SYNC within "
                f"{self.bus.lost_sync_timeout_s:.3f} s: nothing started",
                link,
            )
        for link, prog in zip(self.links, programs, strict=True):
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

    def by_sdo(
        self, programs: Sequence[AxisProgram], ready: list[bool], before_records: Callable[[], object] | None
    ) -> Refusal | None:
        """Not every axis is ready (the first start, or after a fault, a stop or a recovery's failure):
        every drive is asked its statusword and position by SDO at once (one round trip per
        question, not per axis), and only when every axis passes, the enables it needs."""
        checks = self._per_axis(self._start_check, zip(self.links, programs, strict=True))  # asked now
        if before_records is not None:
            before_records()
        refusal = next((r for r in list(checks) if r is not None), None)
        if refusal is not None:
            return refusal
        self._enable([i for i, r in enumerate(ready) if self._needs_enable(i, r)])
        return None

    def _start_check(self, link_and_program: tuple[AxisLink, AxisProgram]) -> Refusal | None:
        """Read what the drive says now (SDO), then judge it."""
        link, prog = link_and_program
        link.read_statusword()
        link.read_position()
        return self._refusal(link, prog)

    def _refusal(self, link: AxisLink, prog: AxisProgram) -> Refusal | None:
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
        if link.position is None or abs(link.position - start) > self.tolerance_qc:
            where = f"axis {link.joint} is at {link.position} qc, the program starts at {start} qc"
            return Result.REJECTED, where, link
        return None
