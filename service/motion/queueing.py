"""``execute`` with ``queue``: a motion accepted while another runs, run on from where that one ends.

The axis group appends its program to the running run (``axes.master.run_queue``): no halt, no cleanup, no
start between the two. The queued motion is journaled (with the motion it follows) before any record of
it reaches a feeder; it becomes the cell's motion on the SYNC where its t = 0 is passed, and the one
before it ends there, finished (journaled, ``motion_ended``) by a thread of its own, never the bus's.
``stop`` ends the running and every queued motion: the run ends, and those that never began end with it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import GroupError, Result, RunResult
from pvtflow.service.api import ApiError, ErrorCode
from pvtflow.service.journal import Journal, JournalError
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.admission import Admission
from pvtflow.service.motion.runs import Motion, new_id

Finish = Callable[[Motion, RunResult, "Motion | None"], None]  # a motion's end; the motion that runs on from it


@dataclass(eq=False)
class QueuedRuns:
    """Motions queued on the running run: accepted, appended, handed over at their start, ended with the run."""

    cell_name: str
    activity: CellActivity
    admission: Admission
    journal: Journal
    finish: Finish
    _handover: ThreadPoolExecutor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._handover = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"pvtflow-queue-{self.cell_name}")

    def follows(self, group: AxisGroup) -> Motion | None:
        """The motion a motion queued now would run on from (None: nothing runs to queue after)."""
        running = self.activity.motion
        if not group.running or running is None or running.done.is_set():
            return None
        queued = self.activity.queued()
        return queued[-1] if queued else running

    def enqueue(
        self, group: AxisGroup, after: Motion, program: PvtProgram, plan_id: str | None, label: str | None
    ) -> Motion:
        """Queue ``program`` after ``after`` (the drives' lock held): journaled, then appended to the run;
        refused (ApiError, nothing sent) when it cannot follow: before the journal as a rule; after it only
        when the run passed the end record's hold in between, the motion then journaled ``rejected``."""
        self.admission.refuse_if_faulted(group)
        motion = Motion(new_id("m"), plan_id, label, program, time.time(), queued_after=after.motion_id, queued=True)

        def journaled() -> None:
            self.journal.record_motion(
                motion.motion_id,
                program.to_json(),
                plan_id=plan_id,
                label=label,
                duration_ms=int(program.duration_ms),
                cell=self.cell_name,
                queued_after=after.motion_id,
            )

        elapsed = group.elapsed_syncs()
        run_start = None if elapsed is None else group.bus.sync.answered - elapsed  # the run's start SYNC
        try:
            entry = group.append(program, lambda elapsed: self._began(motion, elapsed, run_start), journaled)
        except JournalError as exc:
            raise ApiError(ErrorCode.JOURNAL_ERROR, f"{exc}: nothing was queued") from None
        except GroupError as exc:
            if self.journal.get(motion.motion_id) is not None:  # checked, journaled, then too late
                self.journal.record_outcome(motion.motion_id, RunResult(Result.REJECTED, str(exc)).to_json())
            raise ApiError(ErrorCode.NOT_ALLOWED, f"not queued: {exc}", {"queued_after": after.motion_id}) from None
        motion.run_offset_ms = float(entry.start_ms)
        self.activity.queue(motion)
        return motion

    def _began(self, motion: Motion, elapsed: int, run_start: int | None) -> None:
        """The run passed the queued motion's t = 0 (the bus thread, the group's lock held): it is the cell's
        motion from here; the one before it is finished by the hand-over thread."""
        motion.start_sync = None if run_start is None else run_start + elapsed
        motion.queued = False
        previous = self.activity.begin_motion(motion)
        if previous is not None:
            self._handover.submit(self._hand_over, previous, motion)

    def _hand_over(self, previous: Motion, motion: Motion) -> None:
        done = RunResult(
            Result.FINISHED, f"every axis reached the end of its program; {motion.motion_id} runs on from it"
        )
        self.finish(previous, done, motion)

    def run_ended(self, result: RunResult) -> tuple[Motion | None, list[Motion]]:
        """The run ended: once the hand-overs before the end are done, the motion that ran last (it ends
        with the run's result) and the queued motions that never began (``never_began``)."""
        self._handover.submit(lambda: None).result()
        return self.activity.motion, self.activity.drop_queue()

    @staticmethod
    def never_began(result: RunResult) -> RunResult:
        """The outcome of a queued motion the run ended before it began (a stop, a fault)."""
        return RunResult(
            result.result if not result.ok else Result.STOPPED,
            f"ended before it began ({result.result.value}: {result.message})",
            result.joint,
            result.node_id,
        )

    def close(self) -> None:
        self._handover.shutdown(wait=True)
