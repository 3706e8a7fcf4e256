"""``execute``: a stored plan or a given program started on the cell's axis group, and its end.

Every accepted motion is journaled (fsync) before its first record is sent, its outcome after; one
long-lived thread waits for each motion's end. With ``approach`` the axes first move to the program's
start, as a motion of its own.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.outcome import GroupError, Result, RunResult
from pvtflow.axes.master.link import DriveError
from pvtflow.planner.validate import validate_program
from pvtflow.service.api import ApiError, CellState, ErrorCode, ExecuteRequest, refusals
from pvtflow.service.approach import away_from_start
from pvtflow.service.config import CellConfig
from pvtflow.service.journal import Journal, JournalError
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.admission import Admission
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.outbox import Outbox
from pvtflow.service.motion.plans import PlanBook
from pvtflow.service.motion.queueing import QueuedRuns
from pvtflow.service.motion.recordings import RunRecordings
from pvtflow.service.motion.runs import Motion, ServiceEventKind, new_id

log = logging.getLogger("pvtflow.motion")


@dataclass(eq=False)
class MotionRuns:
    """Motions: started, recorded, journaled, ended (one thread waits for each end)."""

    cell: CellConfig
    drives: CellDrives
    board: CellBoard
    activity: CellActivity
    admission: Admission
    plans: PlanBook
    journal: Journal
    outbox: Outbox
    recordings: RunRecordings

    # a motion that ends stopped on its path by a pause: kept for resume (True), or not (service.motion.onpath)
    paused: Callable[[Motion], bool] | None = None

    def __post_init__(self) -> None:
        self._started: queue.Queue[Motion | None] = queue.Queue()
        self._watcher: threading.Thread | None = None
        self.queued = QueuedRuns(self.cell.name, self.activity, self.admission, self.journal, self._finish)

    # --- life cycle ------------------------------------------------------------------------------
    def start_watching(self) -> None:
        self._watcher = threading.Thread(
            target=self._watch_motions, name=f"pvtflow-motions-{self.cell.name}", daemon=True
        )
        self._watcher.start()

    def stop_watching(self) -> None:
        if self._watcher is not None:
            self._started.put(None)
            self._watcher.join(timeout=2.0)
            self._watcher = None
        self.queued.close()

    # --- execute ---------------------------------------------------------------------------------
    def execute(self, req: ExecuteRequest) -> dict[str, Any]:
        """Start a stored plan or a given program; refused (nothing sent) unless everything checks out."""
        if req.plan_id is not None:
            stored = self.plans.stored_plan(req.plan_id)
            program, plan_id, label = stored.program, stored.plan_id, req.label or stored.label
        else:
            assert req.program is not None
            program, plan_id, label = self.plans.program_from_json(req.program), None, req.label
            report = validate_program(program)
            if not report.ok:
                raise refusals.validation_failed([f.format() for f in report.errors], report.to_json())
            problems = program_mismatch(program, self.cell.ordered_axes(), self.cell.name)
            if problems:
                raise refusals.wrong_cell(self.cell.name, problems, program.cell)
        if req.queue:
            queued = self._queue(program, plan_id, label, req.approach)
            if queued is not None:
                if req.wait:
                    queued.done.wait()
                return {**queued.summary(), "approach": None}
        approach = self._approach(program, plan_id) if req.approach else None
        motion = self._start(program, plan_id, label)
        if req.wait:
            motion.done.wait()
        return {**motion.summary(), "approach": approach}

    def _queue(self, program: PvtProgram, plan_id: str | None, label: str | None, approach: bool) -> Motion | None:
        """``queue``: after the running motion and those queued before it (None: nothing runs, it starts)."""
        group = self.drives.connected()
        with self.drives.lock:
            after = self.queued.follows(group)
            if after is None:
                return None
            if approach:
                raise ApiError(
                    ErrorCode.NOT_ALLOWED,
                    f"approach and queue: a queued motion starts where {after.motion_id} ends, with no move before it",
                    {"queued_after": after.motion_id},
                )
            return self.queued.enqueue(group, after, program, plan_id, label)

    def _approach(self, program: PvtProgram, plan_id: str | None) -> dict[str, Any] | None:
        """Asked for (``approach: true``) and the axes are elsewhere: the approach move to the program's
        start (service/approach.py), run to its end as a motion of its own; its summary (None: the axes
        are at the start already). Refused like any execute, and when the approach does not finish."""
        group = self.drives.connected()
        with self.drives.lock:
            self.admission.refuse_a_motion(group)
        positions = self.drives.positions_qc(refresh=True)
        if not away_from_start(positions, program, self.cell.ordered_axes(), group.start_tolerance_qc):
            return None
        move = self.plans.approach(positions, program)
        motion = self._start(move, None, f"approach to {plan_id or 'a program'}")
        motion.done.wait()
        summary = motion.summary()
        if motion.result is None or not motion.result.ok:
            ended = motion.result.result.value if motion.result is not None else "without an outcome"
            raise ApiError(
                ErrorCode.NOT_ALLOWED,
                f"the approach to the program's start ended {ended}: the program was not started",
                {"approach": summary},
            )
        return summary

    def _start(self, program: PvtProgram, plan_id: str | None, label: str | None, resuming: bool = False) -> Motion:
        """Start ``program`` (journaled first) unless the cell refuses it; the motion, running (``resuming``:
        the continuation of the paused motion, which the refusals let through)."""
        group = self.drives.connected()
        with self.drives.lock:
            self.admission.refuse_a_motion(group, program, resuming=resuming)
            motion = Motion(new_id("m"), plan_id, label, program, time.time())
            motion.recorder = self.recordings.open(motion.motion_id, "motion")

            def journaled() -> None:
                self.journal.record_motion(
                    motion.motion_id,
                    program.to_json(),
                    plan_id=plan_id,
                    label=label,
                    duration_ms=int(program.duration_ms),
                    cell=self.cell.name,
                    recording=str(motion.recorder.path) if motion.recorder and motion.recorder.path else None,
                )

            previous = self.activity.begin_motion(motion)
            try:
                # the group asks the drives its checks (a check SYNC or SDO requests), journals the
                # motion while they answer (the fsync lets them have the interpreter), then records
                early = group.start(program, before_records=journaled)
            except JournalError as exc:
                self.activity.begin_motion(previous)
                if motion.recorder is not None:
                    motion.recorder.close({"result": "journal_error", "message": str(exc)})
                raise ApiError(ErrorCode.JOURNAL_ERROR, f"{exc}: nothing was sent") from None
            except GroupError as exc:  # cannot happen under the lock; kept as a guard
                raise ApiError(ErrorCode.BUSY, str(exc)) from None
            except (BusError, DriveError, OSError) as exc:
                early = RunResult(Result.CONFIGURATION_ERROR, f"the bus failed during the start: {exc}")
            if early is not None:
                self._finish(motion, early)
                raise refusals.run_refused(early, {"motion_id": motion.motion_id})
            elapsed = group.elapsed_syncs()
            motion.start_sync = None if elapsed is None else group.bus.sync.answered - elapsed
            self.board.set(CellState.MOVING, motion.motion_id)
            self._started.put(motion)
        return motion

    def _watch_motions(self) -> None:
        """One long-lived thread waits for each motion's end (a thread start per execute costs ms)."""
        while True:
            motion = self._started.get()
            group = self.drives.group
            if motion is None or group is None:
                return
            try:
                result = group.wait()
                last, never_began = self.queued.run_ended(result)  # a queued motion may have run last
                self._finish(last if last is not None and not last.done.is_set() else motion, result)
                for queued in never_began:
                    self._finish(queued, self.queued.never_began(result))
            except Exception:  # never leave a motion without an end: the cell would stay "moving"
                log.exception("while ending motion %s", motion.motion_id)
                self.board.set(CellState.IDLE if not self.drives.running else self.board.state, motion.motion_id)
                motion.done.set()

    def _finish(self, motion: Motion, result: RunResult, runs_on: Motion | None = None) -> None:
        """Journal the outcome, then state and events (the journal first: it is the record); ``runs_on``:
        the queued motion that runs on from this one (the cell stays moving)."""
        outcome = result.to_json()
        if motion.pausing and result.result is Result.STOPPED:
            outcome["paused"] = True  # the journal's record of the pause: resume continues it as a motion of its own
        motion.result = result
        motion.outcome = outcome
        if motion.recorder is not None:
            motion.recorder.close(outcome)
        try:
            self.journal.record_outcome(motion.motion_id, outcome)
        except JournalError as exc:
            self.outbox.event(ServiceEventKind.JOURNAL_ERROR, str(exc), motion_id=motion.motion_id)
        if runs_on is not None:
            self.board.set(CellState.MOVING, runs_on.motion_id)
        elif result.result.is_fault:
            self.board.fault(result.message, motion.motion_id)
        elif motion.pausing and result.result is Result.STOPPED and self.paused is not None and self.paused(motion):
            self.board.set(CellState.PAUSED, motion.motion_id)
        else:
            self.board.set(CellState.IDLE, motion.motion_id)
        self.outbox.event(
            ServiceEventKind.MOTION_ENDED,
            f"{result.result.value}: {result.message}",
            motion_id=motion.motion_id,
            outcome=outcome,
            joint=result.joint,
            node_id=result.node_id,
        )
        motion.done.set()
