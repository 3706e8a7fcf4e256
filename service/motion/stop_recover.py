"""``stop`` and ``recover``: halting whatever runs, and acknowledging a fault.

``stop`` always preempts: it takes the drives' lock only after an execute has finished starting (so a
stop can never slip in before the start and be lost), then halts every axis on the next SYNC. A fault
keeps the cell in ``fault`` until ``recover``, so that a fault is always acknowledged by someone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.outcome import GroupError
from pvtflow.axes.master.link import DriveError
from pvtflow.service.api import ApiError, CellState, ErrorCode, RecoverRequest, StopMode, StopRequest
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.onpath import PathChanges
from pvtflow.service.motion.status import StatusReport

HOMING_STOP_WAIT_S = 60.0  # a stopped homing ends within its drives' halt; past this the reply goes anyway
RUN_END_S = 5.0  # after the group's halt budget: the motion's outcome journaled and published


@dataclass(eq=False)
class StopRecover:
    """Stop what runs; fault reset and re-enable every axis."""

    drives: CellDrives
    board: CellBoard
    activity: CellActivity
    status: StatusReport
    changes: PathChanges

    def stop(self, req: StopRequest, pausing: bool = False) -> dict[str, Any]:
        """Stop every axis: on the path (the default: braking from where the drives' records end, every axis
        at rest on the same SYNC) or the quick way (every axis halts on the next SYNC, off the path; also
        where a path stop cannot be made in time); wait until they stand still. A stop while paused ends
        the paused motion. ``pausing``: a ``pause`` (the motion is kept for ``resume``)."""
        group = self.drives.connected()
        homing = self.activity.homing
        if homing is not None and not homing.done.is_set():
            self.board.set(CellState.STOPPING, None)
            group.stop(req.reason)
            homing.done.wait(HOMING_STOP_WAIT_S)
            return {
                "was_moving": True,
                "motion_id": None,
                "homing_id": homing.homing_id,
                "outcome": homing.outcome.to_json() if homing.outcome is not None else None,
                "axes": self.status.axes_json(),
            }
        braking: dict[str, Any] | None = None
        fallback: str | None = None
        ended_pause = None
        with self.drives.lock:  # an execute still starting has finished its start: its motion is stopped
            motion = self.activity.motion
            queued = self.activity.queued()  # they end with the run
            was_moving = group.running
            if not was_moving and self.board.state == CellState.PAUSED:
                ended_pause = self.changes.end_pause()
                self.board.set(CellState.IDLE, ended_pause.motion.motion_id if ended_pause else None)
            if was_moving:
                self.board.set(CellState.STOPPING, motion.motion_id if motion else None)
                if req.mode is StopMode.PATH and motion is not None and (queued or motion.queued_after):
                    # a queue runs the motions on one time line the path stop does not re-time: quick
                    fallback = "queued motions are stopped the quick way"
                elif req.mode is StopMode.PATH and motion is not None:
                    motion.pausing = pausing
                    braking, fallback = self.changes.brake(group, motion, req.reason)
                if braking is None:
                    if motion is not None:
                        motion.pausing = False
                    group.stop(req.reason)
        if was_moving and motion is not None:
            braking_s = (braking or {}).get("ended_ms", 0.0) / 1000.0
            deadline = time.monotonic() + group.halt_budget_s + RUN_END_S + braking_s
            for ending in [*queued, motion]:  # the last queued one ends last
                ending.done.wait(max(0.0, deadline - time.monotonic()))
            group.settle(5.0)  # the reply says what the drives say once nothing of the motion is left in them
        stopped = self.activity.motion if queued and was_moving else motion  # a queued one may have begun
        reply: dict[str, Any] = {
            "was_moving": was_moving,
            "motion_id": stopped.motion_id if (stopped and was_moving) else None,
            "outcome": stopped.outcome if (stopped and was_moving) else None,
            "queued": [q.motion_id for q in queued if q.queued],
            "axes": self.status.axes_json(),
            "mode": StopMode.PATH.value
            if braking is not None
            else (StopMode.QUICK.value if was_moving else req.mode.value),
            "braking": braking,
            "fallback": fallback,
        }
        if ended_pause is not None:
            reply["ended_pause"] = ended_pause.motion.motion_id
        return reply

    def recover(self, req: RecoverRequest) -> dict[str, Any]:
        """Fault reset and re-enable every axis; the cell is idle again when every drive is."""
        del req
        group = self.drives.connected()
        with self.drives.lock:
            if group.running or self.activity.homing_runs():
                motion = self.activity.motion
                raise ApiError(
                    ErrorCode.BUSY,
                    "cannot recover while a motion runs: stop it first",
                    {"motion_id": motion.motion_id if motion else None},
                )
            try:
                res = group.recover()
                group.refresh()
            except (GroupError, DriveError, BusError) as exc:
                raise ApiError(ErrorCode.DRIVE_FAULT, f"recover failed: {exc}") from None
            if not res.ok:
                raise ApiError(
                    ErrorCode.DRIVE_FAULT,
                    f"recover failed: {res.message}",
                    {"joint": res.joint, "node_id": res.node_id},
                )
            self.board.recovered()
            return {"ok": True, "message": res.message, "axes": self.status.axes_json()}
