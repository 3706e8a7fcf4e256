"""The one activity a cell has at a time: the motion running (or last run) and the homing.

``busy`` is the rule every start checks; the motion and the homing are set here only, by the runs
that start them (``execution``, ``homing``).
"""

from __future__ import annotations

from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.service.motion.runs import Homing, Motion


class CellActivity:
    """The cell's motion and homing, the latest of each."""

    def __init__(self) -> None:
        self.motion: Motion | None = None
        self.homing: Homing | None = None

    def begin_motion(self, motion: Motion | None) -> Motion | None:
        """``motion`` is the cell's motion now (None: none); the one it replaces."""
        previous, self.motion = self.motion, motion
        return previous

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
