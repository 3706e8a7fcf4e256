"""The service's motion logic on one cell, without zenoh: :class:`MotionService` is its front door.

``MotionService`` (service.py) is a facade over collaborators, one concept per module, each owning its
state and lock: the drives (drives.py), the cell's state board (board.py), the one activity
(activity.py), where publications go (outbox.py), admission (the refusals), the plans (plans.py), the
runs (execution.py, homing_runs.py, stop_recover.py, their recordings: recordings.py), status and the
group's publications. What it keeps of a plan, a motion and a homing is in runs.py.
"""

from pvtflow.service.motion.runs import Homing, Motion, ServiceEventKind, StoredPlan
from pvtflow.service.motion.service import MotionService

__all__ = ["Homing", "Motion", "MotionService", "ServiceEventKind", "StoredPlan"]
