"""What the service publishes on its own as the axis group reports: events and telemetry.

The group calls ``on_event`` and ``on_progress`` from the bus threads: they hand over to the outbox and
never block.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from pvtflow.axes.master.group.outcome import Event, Progress
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.outbox import Outbox
from pvtflow.service.motion.runs import Motion, ServiceEventKind


@dataclass(eq=False)
class Publications:
    """The group's events and progress, as the cell's ``events`` and ``telemetry``."""

    outbox: Outbox
    board: CellBoard
    drives: CellDrives
    activity: CellActivity
    _item: tuple[str, int] | None = field(default=None, init=False)  # the motion and item last announced

    def on_event(self, event: Event) -> None:
        motion = self.activity.motion
        motion_id = motion.motion_id if motion is not None and not motion.done.is_set() else None
        if motion_id is not None and motion is not None and motion.recorder is not None:
            motion.recorder.event(event.kind, event.message, event.joint)
        self.outbox.event(event.kind, event.message, joint=event.joint, node_id=event.node_id, motion_id=motion_id)
        if event.kind.is_bus_fault and not self.drives.running:
            self.board.fault(event.message, None)  # a drive faulted while idle: recover before the next motion

    def on_progress(self, p: Progress) -> None:
        """Every ``telemetry_every`` SYNCs during a motion (SYNC thread: hand over, never block)."""
        motion = self.activity.motion
        duration = motion.program.duration_ms if motion is not None else 0
        elapsed_ms = p.elapsed_ms - (motion.run_offset_ms if motion is not None else 0.0)  # a queued motion's own
        if motion is not None:
            self._announce_item(motion, p.elapsed_ms)
        self.outbox.publish(
            "telemetry",
            {
                "cell": self.outbox.cell,
                "motion_id": motion.motion_id if motion else None,
                "sync": p.sync,
                "elapsed_ms": elapsed_ms,
                "progress": min(1.0, elapsed_ms / duration) if duration else None,
                "positions_qc": list(p.positions),
                "positions": self.drives.to_joint(p.positions),
                "buffer_levels": list(p.levels),
                "states": list(p.states),
                "time": time.time(),
            },
        )
        self.board.drive_states(p.states, motion.motion_id if motion else None)

    def _announce_item(self, motion: Motion, elapsed_ms: float) -> None:
        """``item_started`` when a motion sequence's next item runs (as ros2_control's sequence action
        reports its current primitive)."""
        item = motion.item_at(elapsed_ms)
        if item is None or self._item == (motion.motion_id, item["index"]):
            return
        self._item = (motion.motion_id, item["index"])
        self.outbox.event(
            ServiceEventKind.ITEM_STARTED,
            f"item {item['index']}" + (f" ({item['label']})" if item["label"] else ""),
            motion_id=motion.motion_id,
            item=item,
        )

    def telemetry_snapshot(self) -> dict[str, Any]:
        """Idle telemetry: the last positions the drives reported (no bus traffic)."""
        st = self.drives.connected().status()
        positions = [s.position for s in st.axes]
        return {
            "cell": self.outbox.cell,
            "motion_id": None,
            "sync": st.sync_count,
            "elapsed_ms": None,
            "progress": None,
            "positions_qc": positions,
            "positions": self.drives.to_joint(positions),
            "buffer_levels": [s.buffer_level for s in st.axes],
            "states": [s.state for s in st.axes],
            "time": time.time(),
        }
