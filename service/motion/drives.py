"""The cell's drives as the service holds them: its bus, its axis group, their positions.

One lock orders what talks to the drives outside a motion's own threads (execute's start, stop,
recover, an SDO read of the positions): one at a time.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Event, Progress
from pvtflow.axes.master.link import DriveError
from pvtflow.service.api import ApiError, ErrorCode
from pvtflow.service.cell_bus import CellBusError, open_bus
from pvtflow.service.config import CellConfig


class CellDrives:
    """The bus (and the simulated drives of a simulated cell), the axis group, the axes' positions."""

    def __init__(
        self,
        cell: CellConfig,
        *,
        simulate: bool,
        clock: Clock,
        can_log: str | Path | None,
        drives_process: bool,
    ) -> None:
        self.cell = cell
        self.axes = cell.ordered_axes()
        self.simulate = simulate
        self.clock = clock
        self.can_log = can_log
        self.drives_process = drives_process  # simulated drives in a process of their own (axes.sim.process)
        self.bus: CellBus | None = None
        self.sim: Any = None
        self.group: AxisGroup | None = None
        self.lock = threading.RLock()  # execute / stop / recover / SDO: one at a time

    def open(
        self, on_progress: Callable[[Progress], None], on_event: Callable[[Event], None], progress_every: int
    ) -> AxisGroup:
        """Bus up (simulated drives first when the cell is simulated: with ``drives_process`` in a
        process of their own on the simulated wire, as ``pvtflow serve`` runs them; else in this
        one, for tests that read a drive directly), drives configured, state read."""
        try:
            self.bus, self.sim = open_bus(
                self.cell,
                simulate=self.simulate,
                clock=self.clock,
                can_log=self.can_log,
                drives_process=self.drives_process,
            )
            self.group = AxisGroup(
                self.bus, self.axes, on_progress=on_progress, on_event=on_event, progress_every=progress_every
            )
            self.group.configure()
            self.group.refresh()
        except (CellBusError, BusError, DriveError, OSError) as exc:
            self.close()
            raise BusError(f"cell {self.cell.name}: {exc}") from None
        return self.group

    def close(self) -> None:
        """Group, bus and simulated drives down."""
        if self.group is not None:
            self.group.close()
        if self.bus is not None:
            self.bus.close()
        if self.sim is not None:
            self.sim.stop()
        self.group, self.bus, self.sim = None, None, None

    @property
    def running(self) -> bool:
        return self.group is not None and self.group.running

    def connected(self) -> AxisGroup:
        """The axis group; BUS_ERROR when the cell is not connected to its bus."""
        if self.group is None:
            raise ApiError(ErrorCode.BUS_ERROR, f"cell {self.cell.name} is not connected to its bus")
        return self.group

    # --- positions -------------------------------------------------------------------------------
    def positions_qc(self, refresh: bool = False) -> list[int | None]:
        group = self.connected()
        if refresh and not group.running:
            with self.lock:
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

    def current_joint_positions(self) -> NDArray[np.float64]:
        qc = self.positions_qc(refresh=True)
        if any(p is None for p in qc):
            raise ApiError(ErrorCode.BUS_ERROR, "the drives' positions are unknown")
        return np.array(self.to_joint(qc), dtype=float)
