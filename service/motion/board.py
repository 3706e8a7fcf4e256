"""The cell's state as the service announces it (idle, moving, homing, stopping, fault) and why it faulted.

Set here only: the runs report what happened (``set``, ``fault``, ``recovered``), the board keeps the
state and its reason under its own lock and publishes each change with what the drives last said.
"""

from __future__ import annotations

import threading
import time

from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.service.api import CellState
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.outbox import Outbox


class CellBoard:
    """The cell state, its fault reason, and the drives' power states last published."""

    def __init__(self, outbox: Outbox, drives: CellDrives) -> None:
        self.outbox = outbox
        self.drives = drives
        self.state = CellState.IDLE
        self.fault_reason: str | None = None
        self._lock = threading.Lock()
        self._seq = 0
        self._drive_states: tuple[PowerState, ...] = ()

    def set(self, state: CellState, motion_id: str | None) -> None:
        with self._lock:
            changed = state != self.state
            self.state = state
        if changed:
            self.publish(motion_id)

    def fault(self, reason: str, motion_id: str | None) -> None:
        """The cell is in fault until ``recover``, for ``reason``."""
        self.fault_reason = reason
        self.set(CellState.FAULT, motion_id)

    def recovered(self) -> None:
        """Idle and without a fault, published even when the cell was idle: the drives' power states changed."""
        self.fault_reason = None
        with self._lock:
            self.state = CellState.IDLE
        self.publish(None)

    def drive_states_read(self) -> None:
        """The drives' power states as the group has them now (idle: no bus traffic)."""
        group = self.drives.group
        if group is not None:
            self._drive_states = tuple(a.state for a in group.status().axes)

    def drive_states(self, states: tuple[PowerState, ...], motion_id: str | None) -> None:
        """The drives' power states in a motion's progress: published when they changed."""
        if states != self._drive_states:
            self._drive_states = states
            self.publish(motion_id)

    def publish(self, motion_id: str | None = None) -> None:
        group = self.drives.group
        if group is not None and not group.running:  # idle: the drives' last word (no bus traffic)
            self.drive_states_read()
        axes = (
            []
            if group is None
            else [
                {"joint": lk.joint, "state": s, "statusword": lk.statusword}
                for lk, s in zip(group.links, self._drive_states, strict=False)
            ]
        )
        with self._lock:
            self._seq += 1
            seq = self._seq
        self.outbox.publish(
            "state",
            {
                "cell": self.outbox.cell,
                "state": self.state,
                "motion_id": motion_id,
                "fault_reason": self.fault_reason,
                "axes": axes,
                "seq": seq,
                "time": time.time(),
            },
        )
