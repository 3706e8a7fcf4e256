"""The ``status`` reply: what the drives say now, the motion, and the journal's recent motions.

Status is what the drives say (their TPDOs while moving, read by SDO when idle), never what the service hopes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pvtflow.axes.master.group.outcome import AxisStatus
from pvtflow.service.api import CellState, StatusRequest
from pvtflow.service.config import CellConfig
from pvtflow.service.journal import Journal, MotionEntry
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.onpath import PathChanges
from pvtflow.service.motion.plans import PlanBook


@dataclass(eq=False)
class StatusReport:
    """The cell's status and one axis as the replies give it."""

    cell: CellConfig
    drives: CellDrives
    board: CellBoard
    activity: CellActivity
    plans: PlanBook
    journal: Journal
    changes: PathChanges | None = None  # the running motion's override, the paused motion

    def status(self, req: StatusRequest) -> dict[str, Any]:
        """What the drives say now, the motion, and the recent motions of the journal."""
        group = self.drives.connected()
        if not group.running:
            self.drives.positions_qc(refresh=True)
        st = group.status()
        motion = self.activity.motion
        homing = self.activity.homing
        running_id = motion.motion_id if (motion and not motion.done.is_set()) else None
        recent = [e.summary(running=e.motion_id == running_id) for e in self.journal.recent(req.recent)]
        last = motion.outcome if motion is not None else None
        return {
            "cell": self.cell.name,
            "state": self.board.state,
            "fault_reason": self.board.fault_reason,
            "motion": motion.summary() if motion is not None else None,
            "item": motion.item_at(st.elapsed_ms) if running_id is not None and motion is not None else None,
            "queue": [m.summary() for m in self.activity.queued()],
            "sync_count": st.sync_count,
            "elapsed_ms": st.elapsed_ms,
            "joint_names": list(self.cell.joint_names),
            "axes": [self.axis_json(s) for s in st.axes],
            "recent": recent,
            "plans": self.plans.count(),
            "last_result": last,
            "requires_homing": self.cell.requires_homing,
            "homed": all(s.homed for s in st.axes),
            "homing": homing.summary() if homing is not None else None,
            **self._path_status(motion),
        }

    def _path_status(self, motion: Any) -> dict[str, Any]:
        """The running motion's speed override; the paused motion and the share of its path left."""
        changes = self.changes
        if changes is None:
            return {}
        paused = changes.paused if self.board.state == CellState.PAUSED else None
        return {
            "override": changes.scale_of(motion),
            "paused": {"motion_id": paused.motion.motion_id, "remaining": round(paused.remaining, 6)}
            if paused is not None
            else None,
        }

    def journal_entry(self, motion_id: str) -> MotionEntry | None:
        return self.journal.get(motion_id)

    def axes_json(self) -> list[dict[str, Any]]:
        """Every axis as the replies give it, from what the group holds now."""
        return [self.axis_json(s) for s in self.drives.connected().status().axes]

    def axis_json(self, s: AxisStatus) -> dict[str, Any]:
        axis = self.cell.axis_for_joint(s.joint)
        return {
            "joint": s.joint,
            "node_id": s.node_id,
            "profile": s.profile,
            "state": s.state,
            "statusword": s.statusword,
            "statusword_hex": f"0x{s.statusword:04X}",
            "position_qc": s.position,
            "position": None if s.position is None else float(axis.scaling.qc_to_position(s.position)),
            "buffer_status": s.buffer_status,
            "buffer_flags": list(s.buffer_flags),
            "buffer_level": s.buffer_level,
            "last_emcy": None
            if s.last_emcy is None
            else {"code": s.last_emcy[0], "code_hex": f"0x{s.last_emcy[0]:04X}", "message": s.last_emcy[1]},
            "nmt_state": s.nmt_state,
            "fault": s.state.is_fault,
            "homing": axis.homing is not None,
            "homed": s.homed,
        }
