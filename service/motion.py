"""plan -> validate -> execute on one cell's AxisGroup: the service's motion logic, without zenoh.

One :class:`MotionService` per cell. It owns the cell's bus (and its simulated drives when the cell
is simulated), one AxisGroup, the plans (by id, in memory) and the journal (on disk). Rules:

- One motion at a time: an execute while a motion runs is refused (``busy``); nothing changes.
- ``stop`` always preempts: it takes the motion lock only after an execute has finished starting
  (so a stop can never slip in before the start and be lost), then halts every axis on the next SYNC.
- A fault (drive, EMCY, heartbeat, lost SYNC) puts the cell in ``fault``: execute is refused until
  ``recover``, so that a fault is always acknowledged by someone.
- Every accepted motion is journaled (fsync) before its first record is sent, its outcome after.
- Homing (``home``) is a motion too: one at a time, journaled, stopped by ``stop``, a fault puts the
  cell in ``fault``. A cell that ``requires_homing`` refuses ``execute`` and plans from the current
  position (``not_homed``) until every axis has homed since its drive last booted (axes.homing).
- Status is what the drives say: their statuswords, positions and buffer status (from their TPDOs
  while moving, read by SDO when idle), never what the service hopes.

Publications go through ``publish(topic, payload)`` (the server queues them to zenoh); it is
called from the bus threads and must not block.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from axes.bus import CellBus
from axes.bus_faults import BusError
from axes.cia402 import PowerState
from axes.group import AxisGroup
from axes.homing import CellHoming, HomingEventKind, HomingOutcome, HomingRequestError
from axes.link import DriveError
from axes.outcome import AxisStatus, Event, EventKind, GroupError, Progress, Result, RunResult
from axes.program import ProgramFormatError, PvtProgram, program_mismatch
from planner.plan import PlanInput
from planner.validate import validate_program
from service.api import (
    ApiError,
    CellState,
    ErrorCode,
    ExecuteRequest,
    HomeRequest,
    PlanRequest,
    PlanStart,
    RecoverRequest,
    RunState,
    StatusRequest,
    StopRequest,
    ValidateRequest,
    refusals,
)
from service.approach import away_from_start, plan_approach
from service.cell_bus import CellBusError, open_bus
from service.cell_planner import TIMEOUT, CellPlanner
from service.config import CellConfig
from service.journal import Journal, JournalError, MotionEntry, default_directory
from service.live import LiveServer
from service.live_rest import RestView
from service.planning import PlanningProcess
from service.recording import Recorder

Publish = Callable[[str, dict[str, Any]], None]
log = logging.getLogger("pvtflow.motion")


class ServiceEventKind(StrEnum):
    """The service's own ``events`` beside the axis group's (``axes.group.EventKind``)."""

    SERVICE_STARTED = "service_started"
    MOTION_ENDED = "motion_ended"
    JOURNAL_ERROR = "journal_error"
    HOMING_ENDED = "homing_ended"  # with its outcome (the homing's steps: axes.homing.HomingEventKind)


def _new_id(prefix: str) -> str:
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

    def summary(self) -> dict[str, Any]:
        return {
            "motion_id": self.motion_id,
            "plan_id": self.plan_id,
            "label": self.label,
            "state": RunState.of(self.done.is_set()),
            "duration_ms": int(self.program.duration_ms),
            "start_sync": self.start_sync,
            "outcome": self.outcome,
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


def _no_publish(topic: str, payload: dict[str, Any]) -> None:
    del topic, payload


class MotionService:
    """One cell: its bus, drives, plans, journal and the one motion that may run on it."""

    def __init__(
        self,
        cell: CellConfig,
        *,
        journal_dir: str | Path | None = None,
        lockstep: bool | None = None,
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
        self.drives_process = drives_process  # simulated drives in a process of their own (axes.sim.process)
        self.record_dir = Path(record_dir) if record_dir is not None else None  # one MCAP file per motion
        self.live = live  # every motion's channels served live too (service/live.py)
        self.axes = cell.ordered_axes()
        self.joint_names: tuple[str, ...] = tuple(cell.joint_names)
        self.simulate = cell.simulated if simulate is None else simulate
        self.lockstep = self.simulate if lockstep is None else lockstep
        self.can_log = can_log
        self.journal = Journal(journal_dir if journal_dir is not None else default_directory(cell.name))
        # built once: a plan request pays for planning only (in a child process: service/planning.py)
        self.planner: CellPlanner | PlanningProcess
        if planner_process:
            self.planner = PlanningProcess(cell)  # warms up in the child
        else:
            self.planner = CellPlanner(cell)
            self.planner.warm_up()
        self.limits = self.planner.limits
        self.publish: Publish = publish or _no_publish
        self.max_plans = max_plans
        self.telemetry_every = max(1, round(telemetry_period_ms / cell.bus.sync_period_ms))
        self.bus: CellBus | None = None
        self.sim: Any = None
        self.group: AxisGroup | None = None
        self.plans: OrderedDict[str, StoredPlan] = OrderedDict()
        self.motion: Motion | None = None
        self.homing: Homing | None = None
        self._homer: CellHoming | None = None
        self.state = CellState.IDLE
        self.fault_reason: str | None = None
        self._lock = threading.RLock()  # execute / stop / recover / SDO: one at a time
        self._plans_lock = threading.Lock()
        self._planner_lock = threading.Lock()  # the CellPlanner is not for concurrent use
        self._state_lock = threading.Lock()
        self._state_seq = 0
        self._last_states: tuple[PowerState, ...] = ()
        self._started: queue.Queue[Motion | None] = queue.Queue()
        self._watcher: threading.Thread | None = None
        self._rest_view: RestView | None = None

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> MotionService:
        """Bus up (simulated drives first when the cell is simulated: with ``drives_process`` in a
        process of their own on the simulated wire, as ``pvtflow serve`` runs them; else in this
        one, for tests that read a drive directly), drives configured, state read."""
        try:
            self.bus, self.sim = open_bus(
                self.cell,
                simulate=self.simulate,
                lockstep=self.lockstep,
                can_log=self.can_log,
                drives_process=self.drives_process,
            )
            self.group = AxisGroup(
                self.bus,
                self.axes,
                on_progress=self._on_progress,
                on_event=self._on_event,
                progress_every=self.telemetry_every,
            )
            self.group.configure()
            self.group.refresh()
        except (CellBusError, BusError, DriveError, OSError) as exc:
            self.close()
            raise BusError(f"cell {self.cell.name}: {exc}") from None
        self._last_states = tuple(a.state for a in self.group.status().axes)
        self._watcher = threading.Thread(
            target=self._watch_motions, name=f"pvtflow-motions-{self.cell.name}", daemon=True
        )
        self._watcher.start()
        if self.live is not None:  # the cell between motions on the live channels too
            self._rest_view = RestView(self.live, self.cell, self.bus, self.group, self._busy).start()
        self._publish_state()
        return self

    def _busy(self) -> bool:
        """A motion or a homing runs: its recorder publishes the live channels."""
        homing = self.homing
        return self.running or (homing is not None and not homing.done.is_set())

    def close(self) -> None:
        """Halt a running motion, then bus, drives and journal down."""
        group = self.group
        homing = self.homing
        if group is not None and homing is not None and not homing.done.is_set():
            group.stop("the service is shutting down")
            homing.done.wait(30.0)
        if group is not None and group.running:
            group.stop("the service is shutting down")
            if self.motion is not None:
                self.motion.done.wait(group.halt_timeout_ms / 1000.0 + 2.0)
        if self._rest_view is not None:
            self._rest_view.stop()
            self._rest_view = None
        if self._watcher is not None:
            self._started.put(None)
            self._watcher.join(timeout=2.0)
            self._watcher = None
        if group is not None:
            group.close()
        if self.bus is not None:
            self.bus.close()
        if self.sim is not None:
            self.sim.stop()
        if isinstance(self.planner, PlanningProcess):
            self.planner.close()
        self.journal.close()
        self.group, self.bus, self.sim = None, None, None

    def __enter__(self) -> MotionService:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        return self.group is not None and self.group.running

    def _group(self) -> AxisGroup:
        if self.group is None:
            raise ApiError(ErrorCode.BUS_ERROR, f"cell {self.cell.name} is not connected to its bus")
        return self.group

    # --- positions -------------------------------------------------------------------------------
    def positions_qc(self, refresh: bool = False) -> list[int | None]:
        group = self._group()
        if refresh and not group.running:
            with self._lock:
                if not group.running:
                    try:
                        group.refresh()
                    except DriveError as exc:
                        raise ApiError(ErrorCode.BUS_ERROR, f"cannot read the drives: {exc}") from None
        return [link.position for link in group.links]

    def to_joint(self, positions_qc: Sequence[int | None]) -> list[float | None]:
        return [
            None if p is None else float(a.scaling.qc_to_position(p))
            for a, p in zip(self.axes, positions_qc, strict=True)
        ]

    def home_position(self) -> NDArray[np.float64]:
        """The cell's home position (service.config.CellConfig.home_position); NOT_ALLOWED on a cell without one."""
        try:
            return self.cell.home_position()
        except ValueError as exc:
            raise ApiError(ErrorCode.NOT_ALLOWED, f"start home: {exc}", {"path": "$.start"}) from None

    def current_joint_positions(self) -> NDArray[np.float64]:
        qc = self.positions_qc(refresh=True)
        if any(p is None for p in qc):
            raise ApiError(ErrorCode.BUS_ERROR, "the drives' positions are unknown")
        return np.array(self.to_joint(qc), dtype=float)

    # --- plan ------------------------------------------------------------------------------------
    def plan(self, req: PlanRequest) -> dict[str, Any]:
        """Waypoints or poses -> a validated program kept under a new plan id (PLAN_FAILED when impossible)."""
        t0 = time.perf_counter()
        plan_id = _new_id("p")
        scales: dict[str, Any] = {
            "velocity_scale": req.velocity_scale,
            "acceleration_scale": req.acceleration_scale,
            "max_jerk": req.max_jerk,
        }
        budget_ms = self.cell.planning.budget_ms if req.budget_ms is None else req.budget_ms
        if req.poses is not None:
            if req.start is PlanStart.HOME:
                q0 = self.home_position()
            elif req.start_joints is not None:
                q0 = req.start_joints
            else:
                self._refuse_unless_homed(self._group())
                q0 = self.current_joint_positions()
            with self._planner_lock:
                result = self.planner.plan(
                    PlanInput(q0, req.poses, req.motion, **scales), req.tolerance_qc, {"plan_id": plan_id}, budget_ms
                )
            waypoints = result.waypoints if result.waypoints is not None else q0[None, :]
        else:
            waypoints = req.waypoints
            if req.start in (PlanStart.CURRENT, PlanStart.HOME):
                if req.start is PlanStart.HOME:
                    q0 = self.home_position()
                else:
                    self._refuse_unless_homed(self._group())
                    q0 = self.current_joint_positions()
                first_qc = [float(a.scaling.position_to_qc(q)) for a, q in zip(self.axes, waypoints[0], strict=True)]
                here_qc = [float(a.scaling.position_to_qc(q)) for a, q in zip(self.axes, q0, strict=True)]
                if max(abs(x - y) for x, y in zip(first_qc, here_qc, strict=True)) <= 1.0:
                    waypoints = np.vstack([q0, waypoints[1:]])  # the first waypoint is where the axes are
                else:
                    waypoints = np.vstack([q0, waypoints])
                if len(waypoints) < 2:
                    raise ApiError(
                        ErrorCode.PLAN_FAILED,
                        f"the {'home position is' if req.start is PlanStart.HOME else 'axes are'} already at the "
                        "target: nothing to move",
                        {"result": "repeated_waypoint"},
                    )
            with self._planner_lock:
                result = self.planner.plan(
                    PlanInput(waypoints, **scales), req.tolerance_qc, {"plan_id": plan_id}, budget_ms
                )
        if result.code == TIMEOUT:
            raise ApiError(ErrorCode.TIMEOUT, f"cell {self.cell.name}: {result.message}", {"budget_ms": budget_ms})
        if not result.ok or result.program is None or result.build is None:
            raise refusals.plan_failed(self.cell.name, result.code, result.message, _plain(result.details))
        program = result.program
        timing = {k: round(v * 1000.0, 3) for k, v in result.timing.items()}
        timing["request"] = round((time.perf_counter() - t0) * 1000.0, 3)
        reply: dict[str, Any] = {
            "plan_id": plan_id,
            "cell": self.cell.name,
            "label": req.label,
            "joint_names": list(self.joint_names),
            "duration_s": program.duration_ms / 1000.0,
            "waypoints": len(waypoints),
            "start": [float(x) for x in waypoints[0]],
            "end": [float(x) for x in waypoints[-1]],
            "records": {a.joint: len(a.records) for a in program.axes},
            "validation": {"ok": result.build.report.ok, "warnings": len(result.build.report.warnings)},
            "timing_ms": timing,
            "optimal": result.optimal,
        }
        if result.gap is not None:
            reply["gap"] = result.gap
        with self._plans_lock:
            self.plans[plan_id] = StoredPlan(plan_id, program, reply, req.label)
            while len(self.plans) > self.max_plans:
                self.plans.popitem(last=False)
        if req.include_program:
            return {**reply, "program": program.to_json()}
        return reply

    def stored_plan(self, plan_id: str) -> StoredPlan:
        with self._plans_lock:
            stored = self.plans.get(plan_id)
        if stored is None:
            raise ApiError(
                ErrorCode.UNKNOWN_PLAN,
                f"no plan {plan_id!r} on cell {self.cell.name} (plans are kept in memory, the last {self.max_plans})",
                {"plan_id": plan_id},
            )
        return stored

    def _program_from_json(self, data: dict[str, Any]) -> PvtProgram:
        try:
            return PvtProgram.from_json(data)
        except ProgramFormatError as exc:
            raise ApiError(ErrorCode.INVALID_REQUEST, f"$.program: {exc}", {"path": "$.program"}) from None

    # --- validate --------------------------------------------------------------------------------
    def validate(self, req: ValidateRequest) -> dict[str, Any]:
        """The validator's report on a stored plan or a given program, and whether it fits this cell."""
        if req.plan_id is not None:
            program = self.stored_plan(req.plan_id).program
        else:
            assert req.program is not None
            program = self._program_from_json(req.program)
        report = validate_program(program)
        problems = program_mismatch(program, self.cell.ordered_axes(), self.cell.name)
        return {"ok": report.ok and not problems, "report": report.to_json(), "cell_problems": problems}

    # --- execute ---------------------------------------------------------------------------------
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
            motion = Motion(_new_id("m"), plan_id, label, program, time.time())
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

    def _refuse_if_busy(self, group: AxisGroup) -> None:
        homing = self.homing
        if homing is not None and not homing.done.is_set():
            raise ApiError(
                ErrorCode.BUSY,
                f"cell {self.cell.name} is homing ({homing.homing_id}): one motion at a time; "
                "stop it or wait for its end",
                {"homing_id": homing.homing_id},
            )
        previous = self.motion
        if previous is not None and not previous.done.is_set() and not group.running:
            previous.done.wait(2.0)  # it has just ended: its outcome is being journaled
        if group.running or (previous is not None and not previous.done.is_set()):
            moving = previous.motion_id if previous else None
            raise ApiError(
                ErrorCode.BUSY,
                f"a motion is running on cell {self.cell.name} ({moving}): one at a time; stop it or wait for its end",
                {"motion_id": moving},
            )

    def _refuse_unless_homed(self, group: AxisGroup) -> None:
        """NOT_HOMED on a cell that requires homing while an axis has not homed since its drive booted."""
        if not self.cell.requires_homing:
            return
        missing = [link.joint for link, homed in zip(group.links, group.state.homed, strict=True) if not homed]
        if missing:
            raise refusals.not_homed(self.cell.name, missing)

    def _refuse_if_faulted(self, group: AxisGroup) -> None:
        if self.state == CellState.FAULT:
            raise ApiError(
                ErrorCode.DRIVE_FAULT,
                f"cell {self.cell.name} is in fault ({self.fault_reason}): call recover first",
                {"reason": self.fault_reason},
            )
        faulted = [s for s in group.status().axes if s.state.is_fault]
        if faulted:
            s = faulted[0]
            raise ApiError(
                ErrorCode.DRIVE_FAULT,
                f"axis {s.joint} (node {s.node_id}) is {s.state} (statusword 0x{s.statusword:04X}): call recover first",
                {"joint": s.joint, "node_id": s.node_id},
            )

    def _refuse_unless_at_start(self, group: AxisGroup, program: PvtProgram) -> None:
        """START_MISMATCH before anything is journaled or sent, from the positions the drives last reported
        (the group checks again with what the drives answer at the start: this only keeps a plainly wrong
        request out of the journal)."""
        starts = {a.node_id: int(a.records[0, 0]) for a in program.axes}
        tolerance = group.start_tolerance_qc
        for link in group.links:
            start = starts.get(link.node_id)
            if start is not None and link.position is not None and abs(link.position - start) > tolerance:
                raise refusals.start_mismatch(link.joint, link.position, start)

    def _start_error(self, early: RunResult, motion: Motion) -> ApiError:
        return refusals.run_refused(early, {"motion_id": motion.motion_id})

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

    # --- home ------------------------------------------------------------------------------------
    def home(self, req: HomeRequest) -> dict[str, Any]:
        """Home the cell's axes (all with homing, or those named) in the cell's homing order."""
        group = self._group()
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
        with self._lock:
            self._refuse_if_busy(group)
            self._refuse_if_faulted(group)
            homing = Homing(_new_id("h"), stages, time.time())
            homing.recorder = self._recorder(homing.homing_id, "homing")
            try:
                recording = homing.recorder.path if homing.recorder is not None else None
                self.journal.record_homing(
                    homing.homing_id, stages, cell=self.cell.name, recording=str(recording) if recording else None
                )
            except JournalError as exc:
                if homing.recorder is not None:
                    homing.recorder.close({"result": "journal_error", "message": str(exc)})
                raise ApiError(ErrorCode.JOURNAL_ERROR, f"{exc}: nothing moved") from None
            self.homing = homing
            self._homer = CellHoming(group, on_event=self._on_homing_event)
            self._set_state(CellState.HOMING, None)
            threading.Thread(
                target=self._run_homing, args=(homing, self._homer), name=f"pvtflow-home-{self.cell.name}", daemon=True
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
            self.publish("events", self.event_payload(ServiceEventKind.JOURNAL_ERROR, str(exc)))
        if outcome.result.is_fault:
            self.fault_reason = outcome.message
            self._set_state(CellState.FAULT, None)
        else:
            self._set_state(CellState.IDLE, None)
        self.publish(
            "events",
            self.event_payload(
                ServiceEventKind.HOMING_ENDED,
                f"{outcome.result.value}: {outcome.message}",
                homing_id=homing.homing_id,
                outcome=outcome.to_json(),
                joint=outcome.joint,
                node_id=outcome.node_id,
            ),
        )
        homing.done.set()

    def _on_homing_event(self, kind: HomingEventKind, message: str, joint: str | None) -> None:
        homing = self.homing
        if homing is not None and homing.recorder is not None:
            homing.recorder.event(str(kind), message, joint)
        self.publish(
            "events",
            self.event_payload(kind, message, joint=joint, homing_id=homing.homing_id if homing else None),
        )

    # --- stop ------------------------------------------------------------------------------------
    def stop(self, req: StopRequest) -> dict[str, Any]:
        """Halt every axis now (on the next SYNC) and wait until they stand still."""
        group = self._group()
        homing = self.homing
        if homing is not None and not homing.done.is_set():
            self._set_state(CellState.STOPPING, None)
            group.stop(req.reason)
            homing.done.wait(60.0)
            return {
                "was_moving": True,
                "motion_id": None,
                "homing_id": homing.homing_id,
                "outcome": homing.outcome.to_json() if homing.outcome is not None else None,
                "axes": [self._axis_json(s) for s in group.status().axes],
            }
        with self._lock:  # an execute still starting has finished its start: its motion is stopped
            motion = self.motion
            was_moving = group.running
            if was_moving:
                self._set_state(CellState.STOPPING, motion.motion_id if motion else None)
                group.stop(req.reason)
        if was_moving and motion is not None:
            motion.done.wait(group.halt_timeout_ms / 1000.0 + 5.0)
            group.settle(5.0)  # the reply says what the drives say once nothing of the motion is left in them
        return {
            "was_moving": was_moving,
            "motion_id": motion.motion_id if (motion and was_moving) else None,
            "outcome": motion.outcome if (motion and was_moving) else None,
            "axes": [self._axis_json(s) for s in group.status().axes],
        }

    # --- recover ---------------------------------------------------------------------------------
    def recover(self, req: RecoverRequest) -> dict[str, Any]:
        """Fault reset and re-enable every axis; the cell is idle again when every drive is."""
        del req
        group = self._group()
        with self._lock:
            homing = self.homing
            if group.running or (homing is not None and not homing.done.is_set()):
                raise ApiError(
                    ErrorCode.BUSY,
                    "cannot recover while a motion runs: stop it first",
                    {"motion_id": self.motion.motion_id if self.motion else None},
                )
            try:
                res = group.recover()
                group.refresh()
            except (GroupError, DriveError, BusError) as exc:
                raise ApiError(ErrorCode.DRIVE_FAULT, f"recover failed: {exc}") from None
            if not res.ok:
                raise ApiError(
                    ErrorCode.DRIVE_FAULT,
                    f"recover failed: {res.message}",
                    {"joint": res.joint, "node_id": res.node_id},
                )
            self.fault_reason = None
            with self._state_lock:
                self.state = CellState.IDLE
            self._publish_state(None)  # the drives' power states changed even when the cell was idle
            return {"ok": True, "message": res.message, "axes": [self._axis_json(s) for s in group.status().axes]}

    # --- status ----------------------------------------------------------------------------------
    def status(self, req: StatusRequest) -> dict[str, Any]:
        """What the drives say now, the motion, and the recent motions of the journal."""
        group = self._group()
        if not group.running:
            self.positions_qc(refresh=True)
        st = group.status()
        motion = self.motion
        running_id = motion.motion_id if (motion and not motion.done.is_set()) else None
        recent = [e.summary(running=e.motion_id == running_id) for e in self.journal.recent(req.recent)]
        last = motion.outcome if motion is not None else None
        with self._plans_lock:
            n_plans = len(self.plans)
        return {
            "cell": self.cell.name,
            "state": self.state,
            "fault_reason": self.fault_reason,
            "motion": motion.summary() if motion is not None else None,
            "sync_count": st.sync_count,
            "elapsed_ms": st.elapsed_ms,
            "joint_names": list(self.joint_names),
            "axes": [self._axis_json(s) for s in st.axes],
            "recent": recent,
            "plans": n_plans,
            "last_result": last,
            "requires_homing": self.cell.requires_homing,
            "homed": all(s.homed for s in st.axes),
            "homing": self.homing.summary() if self.homing is not None else None,
        }

    def journal_entry(self, motion_id: str) -> MotionEntry | None:
        return self.journal.get(motion_id)

    def _axis_json(self, s: AxisStatus) -> dict[str, Any]:
        axis = self.cell.axis_for_joint(s.joint)
        return {
            "joint": s.joint,
            "node_id": s.node_id,
            "profile": s.profile,
            "state": s.state,
            "statusword": s.statusword,
            "statusword_hex": f"0x{s.statusword:04X}",
            "position_qc": s.position,
            "position": None if s.position is None else float(axis.scaling.qc_to_position(s.position)),
            "buffer_status": s.buffer_status,
            "buffer_flags": list(s.buffer_flags),
            "buffer_level": s.buffer_level,
            "last_emcy": None
            if s.last_emcy is None
            else {"code": s.last_emcy[0], "code_hex": f"0x{s.last_emcy[0]:04X}", "message": s.last_emcy[1]},
            "nmt_state": s.nmt_state,
            "fault": s.state.is_fault,
            "homing": axis.homing is not None,
            "homed": s.homed,
        }

    # --- publications ----------------------------------------------------------------------------
    def _set_state(self, state: CellState, motion_id: str | None) -> None:
        with self._state_lock:
            changed = state != self.state
            self.state = state
        if changed:
            self._publish_state(motion_id)

    def _publish_state(self, motion_id: str | None = None) -> None:
        group = self.group
        if group is not None and not group.running:  # idle: the drives' last word (no bus traffic)
            self._last_states = tuple(a.state for a in group.status().axes)
        axes = (
            []
            if group is None
            else [
                {"joint": lk.joint, "state": s, "statusword": lk.statusword}
                for lk, s in zip(group.links, self._last_states, strict=False)
            ]
        )
        with self._state_lock:
            self._state_seq += 1
            seq = self._state_seq
        self.publish(
            "state",
            {
                "cell": self.cell.name,
                "state": self.state,
                "motion_id": motion_id,
                "fault_reason": self.fault_reason,
                "axes": axes,
                "seq": seq,
                "time": time.time(),
            },
        )

    def event_payload(
        self, kind: EventKind | ServiceEventKind | HomingEventKind, message: str, **extra: Any
    ) -> dict[str, Any]:
        return {
            "cell": self.cell.name,
            "kind": kind,
            "message": message,
            "time": time.time(),
            "joint": None,
            "node_id": None,
            "motion_id": None,
            **extra,
        }

    def _on_event(self, event: Event) -> None:
        motion = self.motion
        motion_id = motion.motion_id if motion is not None and not motion.done.is_set() else None
        if motion_id is not None and motion is not None and motion.recorder is not None:
            motion.recorder.event(event.kind, event.message, event.joint)
        self.publish(
            "events",
            self.event_payload(
                event.kind, event.message, joint=event.joint, node_id=event.node_id, motion_id=motion_id
            ),
        )
        if event.kind.is_bus_fault and not self.running:
            self.fault_reason = event.message  # a drive faulted while idle: recover before the next motion
            self._set_state(CellState.FAULT, None)

    def _on_progress(self, p: Progress) -> None:
        """Every ``telemetry_every`` SYNCs during a motion (SYNC thread: hand over, never block)."""
        motion = self.motion
        duration = motion.program.duration_ms if motion is not None else 0
        self.publish(
            "telemetry",
            {
                "cell": self.cell.name,
                "motion_id": motion.motion_id if motion else None,
                "sync": p.sync,
                "elapsed_ms": p.elapsed_ms,
                "progress": min(1.0, p.elapsed_ms / duration) if duration else None,
                "positions_qc": list(p.positions),
                "positions": self.to_joint(p.positions),
                "buffer_levels": list(p.levels),
                "states": list(p.states),
                "time": time.time(),
            },
        )
        if p.states != self._last_states:
            self._last_states = p.states
            self._publish_state(motion.motion_id if motion else None)

    def telemetry_snapshot(self) -> dict[str, Any]:
        """Idle telemetry: the last positions the drives reported (no bus traffic)."""
        group = self._group()
        st = group.status()
        positions = [s.position for s in st.axes]
        return {
            "cell": self.cell.name,
            "motion_id": None,
            "sync": st.sync_count,
            "elapsed_ms": None,
            "progress": None,
            "positions_qc": positions,
            "positions": self.to_joint(positions),
            "buffer_levels": [s.buffer_level for s in st.axes],
            "states": [s.state for s in st.axes],
            "time": time.time(),
        }


def _plain(details: dict[str, Any]) -> dict[str, Any]:
    """A planner's error details as JSON values (numbers, strings)."""
    return {k: v if isinstance(v, str | int | float | bool) or v is None else str(v) for k, v in details.items()}
