"""What the service keeps of a plan, a motion and a homing, and the events it adds to the axis group's.

Plain records, shared by every part of :class:`service.motion.MotionService` and by the server.
"""

from __future__ import annotations

import threading
import time
import uuid
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.group.outcome import RunResult
from pvtflow.axes.master.homing import HomingOutcome
from pvtflow.service.api import RunState
from pvtflow.service.recording import Recorder


class ServiceEventKind(StrEnum):
    """The service's own ``events`` beside the axis group's (``axes.master.group.axis_group.EventKind``)."""

    SERVICE_STARTED = "service_started"
    MOTION_ENDED = "motion_ended"
    JOURNAL_ERROR = "journal_error"
    HOMING_ENDED = "homing_ended"  # with its outcome (the homing's steps: axes.master.homing.HomingEventKind)
    ITEM_STARTED = "item_started"  # a motion sequence's next item runs (its index and label)


def new_id(prefix: str) -> str:
    """A new id for a plan (p), a motion (m) or a homing (h)."""
    return f"{prefix}-{uuid.uuid4().hex[:16]}"


@dataclass
class StoredPlan:
    plan_id: str
    program: PvtProgram
    reply: dict[str, Any]
    label: str | None
    created: float = field(default_factory=time.time)


@dataclass
class Motion:
    """The motion running (or last run) on the cell."""

    motion_id: str
    plan_id: str | None
    label: str | None
    program: PvtProgram
    accepted_at: float
    start_sync: int | None = None
    outcome: dict[str, Any] | None = None
    result: RunResult | None = None
    done: threading.Event = field(default_factory=threading.Event)
    recorder: Recorder | None = field(default=None, repr=False)
    pausing: bool = False  # stopped on its path by ``pause``: the cell is paused at its end, not idle
    # execute with queue: the motion it runs on from, whether its start is still ahead, where its t = 0 is
    # on the run's time line (ms from the run's start SYNC)
    queued_after: str | None = None
    queued: bool = False
    run_offset_ms: float = 0.0

    def item_at(self, elapsed_ms: float | None) -> dict[str, Any] | None:
        """The item of a motion sequence that runs ``elapsed_ms`` after the start (its ``index`` and
        ``label``); None for a motion that is not a sequence or before its start. The items' spans are
        on the trajectory's timeline, which the program runs slowed by its ``time_scale``; ``elapsed_ms``
        is on the run's, where a queued motion begins at ``run_offset_ms``."""
        items = self.program.metadata.get("items")
        if elapsed_ms is not None:
            elapsed_ms -= self.run_offset_ms
        if not items or elapsed_ms is None or elapsed_ms < 0:
            return None
        t = elapsed_ms / 1000.0 / float(self.program.metadata.get("time_scale", 1.0))
        current = next((it for it in items if t < it["end_s"]), items[-1])
        return {"index": current["index"], "label": current["label"]}

    def summary(self) -> dict[str, Any]:
        return {
            "motion_id": self.motion_id,
            "plan_id": self.plan_id,
            "label": self.label,
            "state": RunState.QUEUED if self.queued and not self.done.is_set() else RunState.of(self.done.is_set()),
            "duration_ms": int(self.program.duration_ms),
            "start_sync": self.start_sync,
            "outcome": self.outcome,
            "queued_after": self.queued_after,
        }


@dataclass
class Homing:
    """The homing running on the cell (or the last one)."""

    homing_id: str
    stages: list[list[str]]
    accepted_at: float
    outcome: HomingOutcome | None = None
    done: threading.Event = field(default_factory=threading.Event)
    recorder: Recorder | None = field(default=None, repr=False)

    def summary(self) -> dict[str, Any]:
        return {
            "homing_id": self.homing_id,
            "state": RunState.of(self.done.is_set()),
            "stages": self.stages,
            "outcome": self.outcome.to_json() if self.outcome is not None else None,
        }
