"""Whether the cell takes a motion or a homing now: the refusals, checked before anything is journaled or sent.

One activity at a time (``busy``), a faulted cell waits for ``recover``, a cell that requires homing
waits for every axis to have homed (``not_homed``), and a program starts where the axes stand.
"""

from __future__ import annotations

from dataclasses import dataclass

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.service.api import ApiError, CellState, ErrorCode, refusals
from pvtflow.service.config import CellConfig
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.board import CellBoard


@dataclass(eq=False)
class Admission:
    """The checks an execute, an approach, a plan from here and a homing pass first."""

    cell: CellConfig
    board: CellBoard
    activity: CellActivity

    def refuse_if_busy(self, group: AxisGroup) -> None:
        homing = self.activity.homing
        if homing is not None and not homing.done.is_set():
            raise ApiError(
                ErrorCode.BUSY,
                f"cell {self.cell.name} is homing ({homing.homing_id}): one motion at a time; "
                "stop it or wait for its end",
                {"homing_id": homing.homing_id},
            )
        previous = self.activity.motion
        if previous is not None and not previous.done.is_set() and not group.running:
            previous.done.wait(2.0)  # it has just ended: its outcome is being journaled
        if group.running or (previous is not None and not previous.done.is_set()):
            moving = previous.motion_id if previous else None
            raise ApiError(
                ErrorCode.BUSY,
                f"a motion is running on cell {self.cell.name} ({moving}): one at a time; stop it or wait for its end",
                {"motion_id": moving},
            )

    def refuse_unless_homed(self, group: AxisGroup) -> None:
        """NOT_HOMED on a cell that requires homing while an axis has not homed since its drive booted."""
        if not self.cell.requires_homing:
            return
        missing = [link.joint for link, homed in zip(group.links, group.state.homed, strict=True) if not homed]
        if missing:
            raise refusals.not_homed(self.cell.name, missing)

    def refuse_if_faulted(self, group: AxisGroup) -> None:
        if self.board.state == CellState.FAULT:
            reason = self.board.fault_reason
            raise ApiError(
                ErrorCode.DRIVE_FAULT,
                f"cell {self.cell.name} is in fault ({reason}): call recover first",
                {"reason": reason},
            )
        faulted = [s for s in group.status().axes if s.state.is_fault]
        if faulted:
            s = faulted[0]
            raise ApiError(
                ErrorCode.DRIVE_FAULT,
                f"axis {s.joint} (node {s.node_id}) is {s.state} (statusword 0x{s.statusword:04X}): call recover first",
                {"joint": s.joint, "node_id": s.node_id},
            )

    def refuse_unless_at_start(self, group: AxisGroup, program: PvtProgram) -> None:
        """START_MISMATCH before anything is journaled or sent, from the positions the drives last reported
        (the group checks again with what the drives answer at the start: this only keeps a plainly wrong
        request out of the journal)."""
        starts = {a.node_id: int(a.records[0, 0]) for a in program.axes}
        tolerance = group.start_tolerance_qc
        for link in group.links:
            start = starts.get(link.node_id)
            if start is not None and link.position is not None and abs(link.position - start) > tolerance:
                raise refusals.start_mismatch(link.joint, link.position, start)

    def refuse_a_motion(self, group: AxisGroup, program: PvtProgram | None = None, resuming: bool = False) -> None:
        """Every check a motion passes (an approach: all but the start, which it moves to); while a motion
        is paused only its continuation (``resuming``)."""
        if self.board.state == CellState.PAUSED and not resuming:
            paused = self.activity.motion.motion_id if self.activity.motion is not None else None
            raise ApiError(
                ErrorCode.BUSY,
                f"a motion is paused on cell {self.cell.name} ({paused}): resume it or stop it first",
                {"motion_id": paused},
            )
        self.refuse_if_busy(group)
        self.refuse_unless_homed(group)
        self.refuse_if_faulted(group)
        if program is not None:
            self.refuse_unless_at_start(group, program)
