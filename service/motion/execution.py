"""``execute``: a stored plan or a given program started on the cell's axis group, and its end.

Every accepted motion is journaled (fsync) before its first record is sent, its outcome after; one
long-lived thread waits for each motion's end. With ``approach`` the axes first move to the program's
start, as a motion of its own.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.outcome import GroupError, Result, RunResult
from pvtflow.axes.master.link import DriveError
from pvtflow.planner.validate import validate_program
from pvtflow.service.api import ApiError, CellState, ErrorCode, ExecuteRequest, refusals
from pvtflow.service.approach import away_from_start, plan_approach
from pvtflow.service.journal import JournalError
from pvtflow.service.motion.plans import PlanBook
from pvtflow.service.motion.runs import Motion, ServiceEventKind, new_id
from pvtflow.service.recording import Recorder

log = logging.getLogger("pvtflow.motion")


class Execution(PlanBook):
    """Motions: started, recorded, journaled, ended."""

    def execute(self, req: ExecuteRequest) -> dict[str, Any]:
        """Start a stored plan or a given program; refused (nothing sent) unless everything checks out."""
        if req.plan_id is not None:
            stored = self.stored_plan(req.plan_id)
            program, plan_id, label = stored.program, stored.plan_id, req.label or stored.label
        else:
            assert req.program is not None
            program, plan_id, label = self._program_from_json(req.program), None, req.label
            report = validate_program(program)
            if not report.ok:
                raise refusals.validation_failed([f.format() for f in report.errors], report.to_json())
            problems = program_mismatch(program, self.cell.ordered_axes(), self.cell.name)
            if problems:
                raise refusals.wrong_cell(self.cell.name, problems, program.cell)
        approach = self._approach(program, plan_id) if req.approach else None
        motion = self._start(program, plan_id, label)
        if req.wait:
            motion.done.wait()
        return {**motion.summary(), "approach": approach}

    def _approach(self, program: PvtProgram, plan_id: str | None) -> dict[str, Any] | None:
        """Asked for (``approach: true``) and the axes are elsewhere: the approach move to the program's
        start (service/approach.py), run to its end as a motion of its own; its summary (None: the axes
        are at the start already). Refused like any execute, and when the approach does not finish."""
        group = self._group()
        with self._lock:
            self._refuse_if_busy(group)
            self._refuse_unless_homed(group)
            self._refuse_if_faulted(group)
        positions = self.positions_qc(refresh=True)
        if not away_from_start(positions, program, self.cell.ordered_axes(), group.start_tolerance_qc):
            return None
        with self._planner_lock:
            move = plan_approach(self.planner, self.cell, positions, program)
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

    def _start(self, program: PvtProgram, plan_id: str | None, label: str | None) -> Motion:
        """Start ``program`` (journaled first) unless the cell refuses it; the motion, running."""
        group = self._group()
        with self._lock:
            self._refuse_if_busy(group)
            self._refuse_unless_homed(group)
            self._refuse_if_faulted(group)
            self._refuse_unless_at_start(group, program)
            motion = Motion(new_id("m"), plan_id, label, program, time.time())
            motion.recorder = self._recorder(motion.motion_id, "motion")

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

            previous, self.motion = self.motion, motion
            try:
                # the group asks the drives its checks (a check SYNC or SDO requests), journals the
                # motion while they answer (the fsync lets them have the interpreter), then records
                early = group.start(program, before_records=journaled)
            except JournalError as exc:
                self.motion = previous
                if motion.recorder is not None:
                    motion.recorder.close({"result": "journal_error", "message": str(exc)})
                raise ApiError(ErrorCode.JOURNAL_ERROR, f"{exc}: nothing was sent") from None
            except GroupError as exc:  # cannot happen under the lock; kept as a guard
                raise ApiError(ErrorCode.BUSY, str(exc)) from None
            except (BusError, DriveError, OSError) as exc:
                early = RunResult(Result.CONFIGURATION_ERROR, f"the bus failed during the start: {exc}")
            if early is not None:
                self._finish(motion, early)
                raise self._start_error(early, motion)
            elapsed = group.elapsed_syncs()
            motion.start_sync = None if elapsed is None else group.bus.sync.answered - elapsed
            self._set_state(CellState.MOVING, motion.motion_id)
            self._started.put(motion)
        return motion

    def _watch_motions(self) -> None:
        """One long-lived thread waits for each motion's end (a thread start per execute costs ms)."""
        while True:
            motion = self._started.get()
            if motion is None or self.group is None:
                return
            try:
                self._finish(motion, self.group.wait())
            except Exception:  # never leave a motion without an end: the cell would stay "moving"
                log.exception("while ending motion %s", motion.motion_id)
                self._set_state(CellState.IDLE if not self.running else self.state, motion.motion_id)
                motion.done.set()

    def _recorder(self, motion_id: str, kind: str) -> Recorder | None:
        """The motion's recording (``record_dir``/ID.mcap), attached to the bus; None without
        ``record_dir``, or when the file cannot be written (logged: the motion does not depend on it)."""
        if (self.record_dir is None and self.live is None) or self.bus is None:
            return None
        path = None
        try:
            if self.record_dir is not None:
                self.record_dir.mkdir(parents=True, exist_ok=True)
                path = self.record_dir / f"{motion_id}.mcap"
            return Recorder(path, self.cell, kind=kind, live=self.live).attach(self.bus, self.group)
        except OSError as exc:
            log.warning("no recording of %s: %s", motion_id, exc)
            return None

    def _finish(self, motion: Motion, result: RunResult) -> None:
        """Journal the outcome, then state and events (the journal first: it is the record)."""
        outcome = result.to_json()
        motion.result = result
        motion.outcome = outcome
        if motion.recorder is not None:
            motion.recorder.close(outcome)
        try:
            self.journal.record_outcome(motion.motion_id, outcome)
        except JournalError as exc:
            self.publish(
                "events", self.event_payload(ServiceEventKind.JOURNAL_ERROR, str(exc), motion_id=motion.motion_id)
            )
        if result.result.is_fault:
            self.fault_reason = result.message
            self._set_state(CellState.FAULT, motion.motion_id)
        else:
            self._set_state(CellState.IDLE, motion.motion_id)
        self.publish(
            "events",
            self.event_payload(
                ServiceEventKind.MOTION_ENDED,
                f"{result.result.value}: {result.message}",
                motion_id=motion.motion_id,
                outcome=outcome,
                joint=result.joint,
                node_id=result.node_id,
            ),
        )
        motion.done.set()
