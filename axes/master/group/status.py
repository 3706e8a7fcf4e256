"""What an axis group reports: a run's result and its axes, progress, the drives' status, a part of ``AxisGroup``.

The types live in ``axes.master.group.outcome``; this part fills them from the links, the feeders and the run's
SYNC counts. The methods work on ``AxisGroup``'s state (``axes.master.group.axis_group``).
"""

from __future__ import annotations

import contextlib

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import decode_state
from pvtflow.axes.drive.objects import BufferStatus
from pvtflow.axes.master.group.feeder import FeedStats
from pvtflow.axes.master.group.outcome import AxisReport, AxisStatus, GroupStatus, Progress, Result, RunResult
from pvtflow.axes.master.link import AxisLink, DriveError


class GroupReports:
    """AxisGroup's results, reports, progress and status (mixed into ``AxisGroup``)."""

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
