"""``home``: the cell's axes homed in its homing order (axes.master.homing), as a run of the cell.

One at a time with motions, journaled, stopped by ``stop``; a fault puts the cell in ``fault``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.outcome import GroupError, Result
from pvtflow.axes.master.homing import CellHoming, HomingEventKind, HomingOutcome, HomingRequestError
from pvtflow.service.api import ApiError, CellState, ErrorCode, HomeRequest
from pvtflow.service.config import CellConfig
from pvtflow.service.journal import Journal, JournalError
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.admission import Admission
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.outbox import Outbox
from pvtflow.service.motion.recordings import RunRecordings
from pvtflow.service.motion.runs import Homing, ServiceEventKind, new_id

log = logging.getLogger("pvtflow.motion")


@dataclass(eq=False)
class HomingRuns:
    """A homing on the cell: accepted, run in a thread of its own, journaled, ended."""

    cell: CellConfig
    drives: CellDrives
    board: CellBoard
    activity: CellActivity
    admission: Admission
    journal: Journal
    outbox: Outbox
    recordings: RunRecordings

    def home(self, req: HomeRequest) -> dict[str, Any]:
        """Home the cell's axes (all with homing, or those named) in the cell's homing order."""
        group = self.drives.connected()
        try:
            stages = self.cell.homing_stages(list(req.joints) if req.joints is not None else None)
        except HomingRequestError as exc:
            unknown = "unknown axis" in str(exc)
            code = ErrorCode.UNKNOWN_JOINT if unknown else ErrorCode.NOT_ALLOWED
            raise ApiError(
                code, f"cell {self.cell.name}: {exc}: nothing moved", {"joints": list(req.joints or ())}
            ) from None
        if not stages:
            raise ApiError(ErrorCode.NOT_ALLOWED, f"cell {self.cell.name} has no axis to home (absolute encoders)")
        with self.drives.lock:
            self.admission.refuse_if_busy(group)
            self.admission.refuse_if_faulted(group)
            homing = Homing(new_id("h"), stages, time.time())
            homing.recorder = self.recordings.open(homing.homing_id, "homing")
            try:
                recording = homing.recorder.path if homing.recorder is not None else None
                self.journal.record_homing(
                    homing.homing_id, stages, cell=self.cell.name, recording=str(recording) if recording else None
                )
            except JournalError as exc:
                if homing.recorder is not None:
                    homing.recorder.close({"result": "journal_error", "message": str(exc)})
                raise ApiError(ErrorCode.JOURNAL_ERROR, f"{exc}: nothing moved") from None
            self.activity.begin_homing(homing)
            homer = CellHoming(group, on_event=self._on_homing_event)
            self.board.set(CellState.HOMING, None)
            threading.Thread(
                target=self._run_homing, args=(homing, homer), name=f"pvtflow-home-{self.cell.name}", daemon=True
            ).start()
        if req.wait:
            homing.done.wait()
        return homing.summary()

    def _run_homing(self, homing: Homing, homer: CellHoming) -> None:
        try:
            outcome = homer.run(homing.stages)
        except (GroupError, BusError, OSError) as exc:
            outcome = HomingOutcome(Result.CONFIGURATION_ERROR, f"homing failed: {exc}")
        except Exception as exc:  # never leave a homing without an end: the cell would stay "homing"
            log.exception("while homing %s", homing.homing_id)
            outcome = HomingOutcome(Result.CONFIGURATION_ERROR, f"homing failed: {type(exc).__name__}: {exc}")
        homing.outcome = outcome
        if homing.recorder is not None:
            homing.recorder.close(outcome.to_json())
        try:
            self.journal.record_homing_outcome(homing.homing_id, outcome.to_json())
        except JournalError as exc:
            self.outbox.event(ServiceEventKind.JOURNAL_ERROR, str(exc))
        if outcome.result.is_fault:
            self.board.fault(outcome.message, None)
        else:
            self.board.set(CellState.IDLE, None)
        self.outbox.event(
            ServiceEventKind.HOMING_ENDED,
            f"{outcome.result.value}: {outcome.message}",
            homing_id=homing.homing_id,
            outcome=outcome.to_json(),
            joint=outcome.joint,
            node_id=outcome.node_id,
        )
        homing.done.set()

    def _on_homing_event(self, kind: HomingEventKind, message: str, joint: str | None) -> None:
        homing = self.activity.homing
        if homing is not None and homing.recorder is not None:
            homing.recorder.event(str(kind), message, joint)
        self.outbox.event(kind, message, joint=joint, homing_id=homing.homing_id if homing else None)
