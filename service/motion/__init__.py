"""The service's motion logic on one cell, without zenoh: :class:`MotionService` is its front door.

The service is built in layers, one concept per module, each a base of the next: the cell's state and
positions (cell_session), publications, status, admission (the refusals), plans, execution, homing,
stop and recover; service.py adds the life cycle. What it keeps of a plan, a motion and a homing is in
runs.py.
"""

from pvtflow.service.motion.runs import Homing, Motion, ServiceEventKind, StoredPlan
from pvtflow.service.motion.service import MotionService

__all__ = ["Homing", "Motion", "MotionService", "ServiceEventKind", "StoredPlan"]
