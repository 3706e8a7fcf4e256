"""The state one cell's service holds (bus, group, plans, the motion, the cell state) and the axes' positions.

The base of :class:`service.motion.MotionService`: every part of the service (plans, execution, homing,
stop and recover, status, publications) works on these attributes.
"""

from __future__ import annotations

import queue
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.homing import CellHoming
from pvtflow.axes.master.link import DriveError
from pvtflow.service.api import ApiError, CellState, ErrorCode
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CellConfig
from pvtflow.service.journal import Journal, default_directory
from pvtflow.service.live import LiveServer
from pvtflow.service.live_rest import RestView
from pvtflow.service.motion.runs import Homing, Motion, StoredPlan
from pvtflow.service.planning import PlanningProcess

Publish = Callable[[str, dict[str, Any]], None]


def _no_publish(topic: str, payload: dict[str, Any]) -> None:
    del topic, payload


class CellSession:
    """What every part of the service works on: the cell, its bus and group, plans, the motion, the cell state."""

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
