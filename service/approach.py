"""The approach move: from where the axes stand to where a program starts, a joint move planned by the
cell's own planner (the same limits, the same knots, the same validation as any plan).

Never implicit: ``pvtflow execute --approach`` and the execute request's ``approach: true`` ask for it.
Without them a program that starts elsewhere is refused with ``start_mismatch`` (a program is a
contract: what runs is what was planned and validated). With them, the axes first move to the
program's start in a straight joint-space line, then the program runs as planned. Both ends must be
inside the joint limits (``out_of_limits`` otherwise: an axis standing outside them is not moved).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.plan import PlanInput
from pvtflow.service.api import ApiError, ErrorCode, check_limits, refusals
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CellConfig
from pvtflow.service.planning import PlanningProcess


def program_start(program: PvtProgram, axes: Sequence[AxisConfig]) -> NDArray[np.float64]:
    """The program's first position per axis of ``axes`` (by node id), in joint units."""
    first = {a.node_id: int(a.records[0, 0]) for a in program.axes}
    return np.array([float(a.scaling.qc_to_position(first[a.node_id])) for a in axes])


def away_from_start(
    positions_qc: Sequence[int | None], program: PvtProgram, axes: Sequence[AxisConfig], tolerance_qc: int
) -> bool:
    """Whether any axis stands further than ``tolerance_qc`` from where the program starts."""
    first = {a.node_id: int(a.records[0, 0]) for a in program.axes}
    return any(p is None or abs(p - first[a.node_id]) > tolerance_qc for a, p in zip(axes, positions_qc, strict=True))


def plan_approach(
    planner: CellPlanner | PlanningProcess, cell: CellConfig, positions_qc: Sequence[int | None], program: PvtProgram
) -> PvtProgram:
    """The approach's program from ``positions_qc`` (the axes as they stand, the cell's joint order) to
    the program's start, planned by ``planner`` (the cell's, in this process or its planning child);
    ApiError (``out_of_limits``, ``plan_failed``, ``bus_error``) when there is none."""
    axes = cell.ordered_axes()
    if any(p is None for p in positions_qc):
        raise ApiError(ErrorCode.BUS_ERROR, "approach: the drives' positions are unknown")
    here = np.array([float(a.scaling.qc_to_position(p)) for a, p in zip(axes, positions_qc, strict=True)])
    there = program_start(program, axes)
    try:
        check_limits(np.vstack([here, there]), cell.joint_limits())
    except ApiError as exc:
        where = "where the axes stand" if exc.details.get("path") == "$.waypoints[0]" else "the program's start"
        raise ApiError(exc.code, f"approach: {where} is outside the limits: {exc.message}", exc.details) from None
    result = planner.plan(PlanInput(np.vstack([here, there])), None, {"approach": True})
    if not result.ok or result.program is None:
        raise refusals.plan_failed(cell.name, result.code, f"approach: {result.message}")
    return result.program
