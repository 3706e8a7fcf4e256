"""What an axis group reports: a run's result and its axes, progress, the drives' status.

The types live in ``axes.master.group.outcome``; ``GroupReports`` (a part of ``AxisGroup``) fills them
from the links, and from the run's feeders and SYNC counts it is given.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from typing import Protocol

from pvtflow.axes.drive.cia402 import decode_state
from pvtflow.axes.drive.objects import BufferStatus
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.feeder import Feeder, FeedStats
from pvtflow.axes.master.group.outcome import AxisReport, AxisStatus, GroupStatus, Progress, Result, RunResult
from pvtflow.axes.master.link import AxisLink, DriveError


class RunView(Protocol):
    """What the reports read of a run (``axes.master.group.run.Run``)."""

    @property
    def programs(self) -> Sequence[AxisProgram]: ...

    @property
    def feeders(self) -> Sequence[Feeder]: ...

    @property
    def ip_start(self) -> Sequence[int | None]: ...

    @property
    def start_sync(self) -> int | None: ...

    @property
    def live(self) -> bool: ...


class GroupReports:
    """A group's results, reports, progress and status, for the run it is given (None: none yet)."""

    def __init__(self, bus: CellBus, links: Sequence[AxisLink], homed: Callable[[], tuple[bool, ...]]) -> None:
        self.bus = bus
        self.links = links
        self._homed = homed  # which axes have homed since their drive booted (``CellRunState.homed``)

    def result(self, run: RunView | None, result: Result, message: str, link: AxisLink | None = None) -> RunResult:
        return RunResult(
            result,
            message,
            link.joint if link else None,
            link.node_id if link else None,
            run.start_sync if run is not None else None,
            self.bus.sync.answered,
            sync_period_ms=self.bus.config.sync_period_ms,
        )

    def axis_reports(self, run: RunView | None) -> list[AxisReport]:
        programs = run.programs if run is not None else ()
        feeders = run.feeders if run is not None else ()
        ip_start = run.ip_start if run is not None else ()
        out = []
        for i, (link, status) in enumerate(zip(self.links, self.status(run, None).axes, strict=True)):
            prog = programs[i] if i < len(programs) else None
            feeder = feeders[i] if i < len(feeders) else None
            out.append(
                AxisReport(
                    **vars(status),
                    target_position=int(prog.records[-1, 0]) if prog is not None else None,
                    feed=feeder.stats if feeder is not None else FeedStats(),
                    start_sync=ip_start[i] if i < len(ip_start) else None,
                    joint_position=None
                    if link.position is None
                    else float(link.config.scaling.qc_to_position(link.position)),
                )
            )
        return out

    def progress(self, run: RunView, n: int) -> Progress:
        return Progress(
            sync=n,
            elapsed_ms=(n - (run.start_sync or n)) * self.bus.config.sync_period_ms,
            positions=tuple(lk.position for lk in self.links),
            levels=tuple(f.level for f in run.feeders),
            states=tuple(decode_state(lk.statusword) for lk in self.links),
            statuswords=tuple(lk.statusword for lk in self.links),
        )

    def status(self, run: RunView | None, last: Result | None, refresh: bool = False) -> GroupStatus:
        """What the drives say: from their TPDOs while running; ``refresh`` reads statusword and
        position by SDO first when idle (no SYNC, so no TPDO, flows between runs in lockstep).
        ``last``: how the last run ended."""
        running = run is not None and run.live
        feeders = run.feeders if run is not None else ()
        if refresh and not running:
            with contextlib.suppress(DriveError):
                self.refresh()
        axes = []
        homed = self._homed()
        for i, link in enumerate(self.links):
            level = feeders[i].level if running and i < len(feeders) else None
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
        if running and run is not None and run.start_sync is not None:
            elapsed = (self.bus.sync.answered - run.start_sync) * self.bus.config.sync_period_ms
        return GroupStatus(running, self.bus.sync.count, elapsed, tuple(axes), last)

    def refresh(self) -> None:
        """Read every statusword and position by SDO (when no TPDO flows, e.g. between runs)."""
        for link in self.links:
            link.read_statusword()
            link.read_position()
