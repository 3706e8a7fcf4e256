"""What the service publishes on its own: the cell state, events, telemetry.

``publish(topic, payload)`` is called from the bus threads (progress, events) and must not block: the
server queues the payloads to zenoh.
"""

from __future__ import annotations

import time
from typing import Any

from pvtflow.axes.master.group.outcome import Event, EventKind, Progress
from pvtflow.axes.master.homing import HomingEventKind
from pvtflow.service.api import CellState
from pvtflow.service.motion.cell_session import CellSession
from pvtflow.service.motion.runs import ServiceEventKind


class Publications(CellSession):
    """The cell state, the events and the telemetry, as they go out."""

    def _set_state(self, state: CellState, motion_id: str | None) -> None:
        with self._state_lock:
            changed = state != self.state
            self.state = state
        if changed:
            self._publish_state(motion_id)

    def _publish_state(self, motion_id: str | None = None) -> None:
        group = self.group
        if group is not None and not group.running:  # idle: the drives' last word (no bus traffic)
            self._last_states = tuple(a.state for a in group.status().axes)
        axes = (
            []
            if group is None
            else [
                {"joint": lk.joint, "state": s, "statusword": lk.statusword}
                for lk, s in zip(group.links, self._last_states, strict=False)
            ]
        )
        with self._state_lock:
            self._state_seq += 1
            seq = self._state_seq
        self.publish(
            "state",
            {
                "cell": self.cell.name,
                "state": self.state,
                "motion_id": motion_id,
                "fault_reason": self.fault_reason,
                "axes": axes,
                "seq": seq,
                "time": time.time(),
            },
        )

    def event_payload(
        self, kind: EventKind | ServiceEventKind | HomingEventKind, message: str, **extra: Any
    ) -> dict[str, Any]:
        return {
            "cell": self.cell.name,
            "kind": kind,
            "message": message,
            "time": time.time(),
            "joint": None,
            "node_id": None,
            "motion_id": None,
            **extra,
        }

    def _on_event(self, event: Event) -> None:
        motion = self.motion
        motion_id = motion.motion_id if motion is not None and not motion.done.is_set() else None
        if motion_id is not None and motion is not None and motion.recorder is not None:
            motion.recorder.event(event.kind, event.message, event.joint)
        self.publish(
            "events",
            self.event_payload(
                event.kind, event.message, joint=event.joint, node_id=event.node_id, motion_id=motion_id
            ),
        )
        if event.kind.is_bus_fault and not self.running:
            self.fault_reason = event.message  # a drive faulted while idle: recover before the next motion
            self._set_state(CellState.FAULT, None)

    def _on_progress(self, p: Progress) -> None:
        """Every ``telemetry_every`` SYNCs during a motion (SYNC thread: hand over, never block)."""
        motion = self.motion
        duration = motion.program.duration_ms if motion is not None else 0
        self.publish(
            "telemetry",
            {
                "cell": self.cell.name,
                "motion_id": motion.motion_id if motion else None,
                "sync": p.sync,
                "elapsed_ms": p.elapsed_ms,
                "progress": min(1.0, p.elapsed_ms / duration) if duration else None,
                "positions_qc": list(p.positions),
                "positions": self.to_joint(p.positions),
                "buffer_levels": list(p.levels),
                "states": list(p.states),
                "time": time.time(),
            },
        )
        if p.states != self._last_states:
            self._last_states = p.states
            self._publish_state(motion.motion_id if motion else None)

    def telemetry_snapshot(self) -> dict[str, Any]:
        """Idle telemetry: the last positions the drives reported (no bus traffic)."""
        group = self._group()
        st = group.status()
        positions = [s.position for s in st.axes]
        return {
            "cell": self.cell.name,
            "motion_id": None,
            "sync": st.sync_count,
            "elapsed_ms": None,
            "progress": None,
            "positions_qc": positions,
            "positions": self.to_joint(positions),
            "buffer_levels": [s.buffer_level for s in st.axes],
            "states": [s.state for s in st.axes],
            "time": time.time(),
        }
