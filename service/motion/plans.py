"""``plan`` and ``validate``: waypoints or poses to a validated program, kept in memory under a plan id.

The last ``max_plans`` plans are kept (oldest dropped first); a program is checked against the drives'
rules and against this cell.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import ProgramFormatError, PvtProgram, program_mismatch
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.api import ApiError, ErrorCode, PlanRequest, PlanStart, ValidateRequest, refusals
from pvtflow.service.approach import plan_approach
from pvtflow.service.cell_planner import TIMEOUT, CellPlanner
from pvtflow.service.config import CellConfig
from pvtflow.service.motion.admission import Admission
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.runs import StoredPlan, new_id
from pvtflow.service.planning import PlanningProcess


class PlanBook:
    """The plans of the cell, by id, and the planner that makes them (one plan at a time)."""

    def __init__(
        self,
        cell: CellConfig,
        planner: CellPlanner | PlanningProcess,
        drives: CellDrives,
        admission: Admission,
        max_plans: int,
    ) -> None:
        self.cell = cell
        self.planner = planner
        self.drives = drives
        self.admission = admission
        self.max_plans = max_plans
        self.plans: OrderedDict[str, StoredPlan] = OrderedDict()
        self._lock = threading.Lock()
        self._planner_lock = threading.Lock()  # the CellPlanner is not for concurrent use

    def count(self) -> int:
        with self._lock:
            return len(self.plans)

    def approach(self, positions_qc: list[int | None], program: PvtProgram) -> PvtProgram:
        """The joint move from where the axes stand to ``program``'s start (service/approach.py)."""
        with self._planner_lock:
            return plan_approach(self.planner, self.cell, positions_qc, program)

    def _start(self, start: PlanStart) -> NDArray[np.float64]:
        """Where a plan from ``home`` or from here starts: the cell's home position, or where the axes
        stand (NOT_HOMED first on a cell that requires homing)."""
        return self._home_position() if start is PlanStart.HOME else self._here()

    def _home_position(self) -> NDArray[np.float64]:
        """The cell's home position (service.config.CellConfig.home_position); NOT_ALLOWED on a cell without one."""
        try:
            return self.cell.home_position()
        except ValueError as exc:
            raise ApiError(ErrorCode.NOT_ALLOWED, f"start home: {exc}", {"path": "$.start"}) from None

    def _here(self) -> NDArray[np.float64]:
        """Where the axes stand, for a plan from here: NOT_HOMED first on a cell that requires homing."""
        self.admission.refuse_unless_homed(self.drives.connected())
        return self.drives.current_joint_positions()

    def plan(self, req: PlanRequest) -> dict[str, Any]:
        """Waypoints or poses -> a validated program kept under a new plan id (PLAN_FAILED when impossible)."""
        t0 = time.perf_counter()
        plan_id = new_id("p")
        scales: dict[str, Any] = {
            "velocity_scale": req.velocity_scale,
            "acceleration_scale": req.acceleration_scale,
            "max_jerk": req.max_jerk,
        }
        budget_ms = self.cell.planning.budget_ms if req.budget_ms is None else req.budget_ms
        if req.poses is not None or req.sequence is not None:
            given = req.start_joints is not None and req.start is not PlanStart.HOME
            q0 = req.start_joints if given else self._start(req.start)
            with self._planner_lock:
                result = self.planner.plan(
                    req.plan_input(q0, **scales), req.tolerance_qc, {"plan_id": plan_id}, budget_ms
                )
            waypoints = result.waypoints if result.waypoints is not None else q0[None, :]
        else:
            waypoints = req.waypoints
            if req.start in (PlanStart.CURRENT, PlanStart.HOME):
                q0 = self._start(req.start)
                axes = self.drives.axes
                first_qc = [float(a.scaling.position_to_qc(q)) for a, q in zip(axes, waypoints[0], strict=True)]
                here_qc = [float(a.scaling.position_to_qc(q)) for a, q in zip(axes, q0, strict=True)]
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
            "joint_names": list(self.cell.joint_names),
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
        if result.speed_band is not None:  # motion time given for fewer records: how much, and why
            reply["speed_band"] = result.speed_band
        with self._lock:
            self.plans[plan_id] = StoredPlan(plan_id, program, reply, req.label)
            while len(self.plans) > self.max_plans:
                self.plans.popitem(last=False)
        if req.include_program:
            return {**reply, "program": program.to_json()}
        return reply

    def stored_plan(self, plan_id: str) -> StoredPlan:
        with self._lock:
            stored = self.plans.get(plan_id)
        if stored is None:
            raise ApiError(
                ErrorCode.UNKNOWN_PLAN,
                f"no plan {plan_id!r} on cell {self.cell.name} (plans are kept in memory, the last {self.max_plans})",
                {"plan_id": plan_id},
            )
        return stored

    def program_from_json(self, data: dict[str, Any]) -> PvtProgram:
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
            program = self.program_from_json(req.program)
        report = validate_program(program)
        problems = program_mismatch(program, self.cell.ordered_axes(), self.cell.name)
        return {"ok": report.ok and not problems, "report": report.to_json(), "cell_problems": problems}


def _plain(details: dict[str, Any]) -> dict[str, Any]:
    """A planner's error details as JSON values (numbers, strings)."""
    return {k: v if isinstance(v, str | int | float | bool) or v is None else str(v) for k, v in details.items()}
