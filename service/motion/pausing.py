"""``pause``, ``resume`` and ``override``: the running motion held on its path, continued, re-timed (issue 37).

``pause`` is the on-path stop that keeps the motion (``StopRecover.stop`` with the motion kept); the cell is
then ``paused`` until ``resume`` continues it from where the axes stand to its end, as a motion of its own
(journaled, the paused one named in its program's metadata), or a ``stop`` or a fault ends it. ``override``
re-times the rest of the running motion (``service.motion.onpath``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pvtflow.service.api import (
    ApiError,
    CellState,
    ErrorCode,
    OverrideRequest,
    PauseRequest,
    ResumeRequest,
    StopRequest,
)
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.execution import MotionRuns
from pvtflow.service.motion.onpath import PathChanges
from pvtflow.service.motion.status import StatusReport
from pvtflow.service.motion.stop_recover import StopRecover


@dataclass(eq=False)
class PauseResume:
    """Pause, resume and override of the cell's motion."""

    drives: CellDrives
    board: CellBoard
    activity: CellActivity
    motions: MotionRuns
    stopping: StopRecover
    changes: PathChanges
    status: StatusReport

    def _running(self) -> Any:
        """The running motion and its group; NOT_ALLOWED when none runs."""
        group = self.drives.connected()
        motion = self.activity.motion
        if motion is None or motion.done.is_set() or not group.running:
            raise ApiError(ErrorCode.NOT_ALLOWED, "no motion runs on this cell")
        if motion.queued_after or self.activity.queued():
            # queued motions run on one time line, which a change of one motion's timing would break
            raise ApiError(
                ErrorCode.NOT_ALLOWED,
                "queued motions run: pause and override act on a single motion (stop ends the queue)",
                {"motion_id": motion.motion_id},
            )
        return group, motion

    def pause(self, req: PauseRequest) -> dict[str, Any]:
        """Stop the running motion on its path and keep it for ``resume``."""
        _, motion = self._running()
        reply = self.stopping.stop(StopRequest(req.reason), pausing=True)
        paused = self.changes.paused if self.board.state == CellState.PAUSED else None
        return {
            "paused": paused is not None and paused.motion is motion,
            "motion_id": motion.motion_id,
            "braking": reply["braking"],
            "remaining": round(paused.remaining, 6) if paused is not None else None,
            "outcome": reply["outcome"],
            "fallback": reply["fallback"],
            "axes": reply["axes"],
        }

    def resume(self, req: ResumeRequest) -> dict[str, Any]:
        """Continue the paused motion from where its axes stand to its end (a motion of its own)."""
        paused, program = self.changes.resume_program()
        before = paused.motion
        motion = self.motions._start(
            program, before.plan_id, f"resume of {before.motion_id}" + (f" ({before.label})" if before.label else ""),
            resuming=True,
        )  # fmt: skip
        self.changes.end_pause()
        if req.wait:
            motion.done.wait()
        return {**motion.summary(), "resumed": before.motion_id}

    def override(self, req: OverrideRequest) -> dict[str, Any]:
        """Re-time the rest of the running motion to ``req.scale`` of its planned speed."""
        with self.drives.lock:
            group, motion = self._running()
            return self.changes.override(group, motion, req.scale)
