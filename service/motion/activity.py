"""The one activity a cell has at a time: the motion running (or last run), the motions queued after it, and
the homing.

``busy`` is the rule every start checks; the motion and the homing are set here only, by the runs
that start them (``execution``, ``queueing``, ``homing``).
"""

from __future__ import annotations

import threading

from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.service.motion.runs import Homing, Motion


class CellActivity:
    """The cell's motion and homing, the latest of each, and the motions queued after the motion."""

    def __init__(self) -> None:
        self.motion: Motion | None = None
        self.homing: Homing | None = None
        self._queued: list[Motion] = []  # execute with queue: in the order they will run
        self._lock = threading.Lock()  # the queue: the bus thread begins its motions

    def begin_motion(self, motion: Motion | None) -> Motion | None:
        """``motion`` is the cell's motion now (None: none); the one it replaces."""
        with self._lock:
            previous, self.motion = self.motion, motion
            self._queued = [m for m in self._queued if m is not motion]
        return previous

    def queue(self, motion: Motion) -> None:
        with self._lock:
            self._queued.append(motion)

    def queued(self) -> list[Motion]:
        """The motions queued after the running one, in order."""
        with self._lock:
            return list(self._queued)

    def drop_queue(self) -> list[Motion]:
        """The run has ended: the queued motions that never began (they are no longer queued)."""
        with self._lock:
            dropped, self._queued = self._queued, []
        return dropped

    def begin_homing(self, homing: Homing) -> None:
        self.homing = homing

    def homing_runs(self) -> bool:
        homing = self.homing
        return homing is not None and not homing.done.is_set()

    def motion_id(self) -> str | None:
        """The id of the motion that has not ended yet (None: none)."""
        motion = self.motion
        return motion.motion_id if motion is not None and not motion.done.is_set() else None

    def busy(self, group: AxisGroup | None) -> bool:
        """A motion or a homing runs."""
        return (group is not None and group.running) or self.homing_runs()
