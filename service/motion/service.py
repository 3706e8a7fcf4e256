"""plan -> validate -> execute on one cell's AxisGroup: the service's motion logic, without zenoh.

One :class:`MotionService` per cell. It owns the cell's bus (and its simulated drives when the cell
is simulated), one AxisGroup, the plans (by id, in memory) and the journal (on disk). Rules:

- One motion at a time: an execute while a motion runs is refused (``busy``); nothing changes.
- ``stop`` always preempts: it takes the drives' lock only after an execute has finished starting
  (so a stop can never slip in before the start and be lost), then halts every axis on the next SYNC.
- A fault (drive, EMCY, heartbeat, lost SYNC) puts the cell in ``fault``: execute is refused until
  ``recover``, so that a fault is always acknowledged by someone.
- Every accepted motion is journaled (fsync) before its first record is sent, its outcome after.
- Homing (``home``) is a motion too: one at a time, journaled, stopped by ``stop``, a fault puts the
  cell in ``fault``. A cell that ``requires_homing`` refuses ``execute`` and plans from the current
  position (``not_homed``) until every axis has homed since its drive last booted (axes.master.homing).
- Status is what the drives say: their statuswords, positions and buffer status (from their TPDOs
  while moving, read by SDO when idle), never what the service hopes.

It is a facade over collaborators that each own their state and lock: the drives (``CellDrives``: bus,
group, the drives' lock), the cell's state board (``CellBoard``), the one activity (``CellActivity``:
the motion and the homing), admission (the refusals), the plans (``PlanBook``), the runs
(``MotionRuns``, ``HomingRuns``, ``StopRecover``), status and publications. Publications go through
``publish(topic, payload)`` (the server sets it); it is called from the bus threads and must not block.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.service.api import (
    CellState,
    ExecuteRequest,
    HomeRequest,
    OverrideRequest,
    PauseRequest,
    PlanRequest,
    RecoverRequest,
    ResumeRequest,
    StatusRequest,
    StopRequest,
    ValidateRequest,
)
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CellConfig
from pvtflow.service.journal import Journal, MotionEntry, default_directory
from pvtflow.service.live import LiveServer
from pvtflow.service.live_rest import RestView
from pvtflow.service.motion.activity import CellActivity
from pvtflow.service.motion.admission import Admission
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.execution import MotionRuns
from pvtflow.service.motion.homing_runs import HomingRuns
from pvtflow.service.motion.onpath import PathChanges
from pvtflow.service.motion.outbox import Outbox, Publish
from pvtflow.service.motion.pausing import PauseResume
from pvtflow.service.motion.plans import PlanBook
from pvtflow.service.motion.publications import Publications
from pvtflow.service.motion.recordings import RunRecordings
from pvtflow.service.motion.runs import Homing, Motion, StoredPlan
from pvtflow.service.motion.status import StatusReport
from pvtflow.service.motion.stop_recover import HOMING_STOP_WAIT_S, RUN_END_S, StopRecover
from pvtflow.service.planning import PlanningProcess


class MotionService:
    """One cell: its bus, drives, plans, journal and the one motion that may run on it."""

    def __init__(
        self,
        cell: CellConfig,
        *,
        journal_dir: str | Path | None = None,
        clock: Clock | None = None,
        can_log: str | Path | None = None,
        simulate: bool | None = None,
        telemetry_period_ms: float = 20.0,
        max_plans: int = 64,
        publish: Publish | None = None,
        planner_process: bool = False,
        record_dir: str | Path | None = None,
        live: LiveServer | None = None,
        drives_process: bool = False,
    ) -> None:
        self.cell = cell
        self.joint_names: tuple[str, ...] = tuple(cell.joint_names)
        simulate = cell.simulated if simulate is None else simulate
        self.drives = CellDrives(
            cell,
            simulate=simulate,
            clock=Clock.of(simulate) if clock is None else clock,
            can_log=can_log,
            drives_process=drives_process,
        )
        self.journal = Journal(journal_dir if journal_dir is not None else default_directory(cell.name))
        # built once: a plan request pays for planning only (in a child process: service/planning.py)
        self.planner: CellPlanner | PlanningProcess
        if planner_process:
            self.planner = PlanningProcess(cell)  # warms up in the child
        else:
            self.planner = CellPlanner(cell)
            self.planner.warm_up()
        self.limits = self.planner.limits
        self.telemetry_every = max(1, round(telemetry_period_ms / cell.bus.sync_period_ms))
        self.outbox = Outbox(cell.name, publish)
        self.board = CellBoard(self.outbox, self.drives)
        self.activity = CellActivity()
        self.admission = Admission(cell, self.board, self.activity)
        self.plan_book = PlanBook(cell, self.planner, self.drives, self.admission, max_plans)
        self.recordings = RunRecordings(cell, self.drives, Path(record_dir) if record_dir is not None else None, live)
        self.changes = PathChanges(cell, self.drives, self.board, self.limits)
        self.motions = MotionRuns(
            cell, self.drives, self.board, self.activity, self.admission, self.plan_book, self.journal,
            self.outbox, self.recordings, lambda m: self.changes.pause_kept(m) is not None,
        )  # fmt: skip
        self.homings = HomingRuns(
            cell, self.drives, self.board, self.activity, self.admission, self.journal, self.outbox, self.recordings
        )
        self.status_report = StatusReport(
            cell, self.drives, self.board, self.activity, self.plan_book, self.journal, self.changes
        )
        self.stopping = StopRecover(self.drives, self.board, self.activity, self.status_report, self.changes)
        self.pausing = PauseResume(
            self.drives, self.board, self.activity, self.motions, self.stopping, self.changes, self.status_report
        )
        self.publications = Publications(self.outbox, self.board, self.drives, self.activity)
        self._rest_view: RestView | None = None

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> MotionService:
        """Bus up (simulated drives first when the cell is simulated: with ``drives_process`` in a
        process of their own on the simulated wire, as ``pvtflow serve`` runs them; else in this
        one, for tests that read a drive directly), drives configured, state read, and the planning
        process (``planner_process``) warmed up: the first plan request after start does not wait
        for it (PlanningError where it cannot start)."""
        group = self.drives.open(self.publications.on_progress, self.publications.on_event, self.telemetry_every)
        self.board.drive_states_read()
        self.motions.start_watching()
        live = self.recordings.live
        if live is not None and self.drives.bus is not None:  # the cell between motions on the live channels too
            self._rest_view = RestView(live, self.cell, self.drives.bus, group, self._busy).start()
        self.board.publish()
        if isinstance(self.planner, PlanningProcess):  # it warmed up meanwhile, in its own process
            self.planner.wait_ready()
        return self

    def _busy(self) -> bool:
        """A motion or a homing runs: its recorder publishes the live channels."""
        return self.activity.busy(self.drives.group)

    def close(self) -> None:
        """Halt a running motion, then bus, drives and journal down."""
        group = self.drives.group
        if group is not None and self.activity.homing_runs():
            group.stop("the service is shutting down")
            homing = self.activity.homing
            if homing is not None:
                homing.done.wait(HOMING_STOP_WAIT_S)
        if group is not None and group.running:
            group.stop("the service is shutting down")
            motion = self.activity.motion
            if motion is not None:
                motion.done.wait(group.halt_budget_s + RUN_END_S)
        if self._rest_view is not None:
            self._rest_view.stop()
            self._rest_view = None
        self.motions.stop_watching()
        self.drives.close()
        if isinstance(self.planner, PlanningProcess):
            self.planner.close()
        self.journal.close()

    def __enter__(self) -> MotionService:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- requests --------------------------------------------------------------------------------
    def plan(self, req: PlanRequest) -> dict[str, Any]:
        return self.plan_book.plan(req)

    def validate(self, req: ValidateRequest) -> dict[str, Any]:
        return self.plan_book.validate(req)

    def stored_plan(self, plan_id: str) -> StoredPlan:
        return self.plan_book.stored_plan(plan_id)

    def execute(self, req: ExecuteRequest) -> dict[str, Any]:
        return self.motions.execute(req)

    def home(self, req: HomeRequest) -> dict[str, Any]:
        return self.homings.home(req)

    def stop(self, req: StopRequest) -> dict[str, Any]:
        return self.stopping.stop(req)

    def recover(self, req: RecoverRequest) -> dict[str, Any]:
        return self.stopping.recover(req)

    def pause(self, req: PauseRequest) -> dict[str, Any]:
        return self.pausing.pause(req)

    def resume(self, req: ResumeRequest) -> dict[str, Any]:
        return self.pausing.resume(req)

    def override(self, req: OverrideRequest) -> dict[str, Any]:
        return self.pausing.override(req)

    def status(self, req: StatusRequest) -> dict[str, Any]:
        return self.status_report.status(req)

    def journal_entry(self, motion_id: str) -> MotionEntry | None:
        return self.status_report.journal_entry(motion_id)

    def telemetry_snapshot(self) -> dict[str, Any]:
        return self.publications.telemetry_snapshot()

    def event_payload(self, kind: Any, message: str, **extra: Any) -> dict[str, Any]:
        return self.outbox.event_payload(kind, message, **extra)

    def to_joint(self, positions_qc: list[int | None]) -> list[float | None]:
        return self.drives.to_joint(positions_qc)

    def positions_qc(self, refresh: bool = False) -> list[int | None]:
        return self.drives.positions_qc(refresh)

    def current_joint_positions(self) -> NDArray[np.float64]:
        return self.drives.current_joint_positions()

    # --- what the collaborators hold, read through the facade -------------------------------------
    @property
    def publish(self) -> Publish:
        return self.outbox.publish

    @publish.setter
    def publish(self, target: Publish) -> None:
        self.outbox.send_to(target)

    @property
    def state(self) -> CellState:
        return self.board.state

    @property
    def fault_reason(self) -> str | None:
        return self.board.fault_reason

    @property
    def motion(self) -> Motion | None:
        return self.activity.motion

    @property
    def homing(self) -> Homing | None:
        return self.activity.homing

    @property
    def plans(self) -> dict[str, StoredPlan]:
        return self.plan_book.plans

    @property
    def running(self) -> bool:
        return self.drives.running

    @property
    def group(self) -> AxisGroup | None:
        return self.drives.group

    @property
    def bus(self) -> CellBus | None:
        return self.drives.bus

    @property
    def sim(self) -> Any:
        return self.drives.sim

    @property
    def axes(self) -> list[Any]:
        return self.drives.axes

    @property
    def simulate(self) -> bool:
        return self.drives.simulate

    @property
    def clock(self) -> Clock:
        """The SYNC's clock: lockstep with simulated drives (the default for a simulated cell) or the wall."""
        return self.drives.clock

    @property
    def record_dir(self) -> Path | None:
        return self.recordings.record_dir

    @property
    def live(self) -> LiveServer | None:
        return self.recordings.live
