"""Fixtures of the axes tests: a simulated cell on its own virtual channel, with the master on it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from axes_rig import unique_channel

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.service.config import CellConfig


@dataclass
class Rig:
    cell: CellConfig
    sim: SimulatedCell
    bus: CellBus
    group: AxisGroup


@pytest.fixture
def make_rig() -> Iterator[Callable[..., Rig]]:
    rigs: list[Rig] = []

    def make(
        cell: CellConfig,
        *,
        heartbeat_ms: int | None = None,
        eds_paths: dict[int, str | Path] | None = None,
        can_log: Path | None = None,
        lost_sync_timeout_s: float = 1.0,
        clock: Clock = Clock.LOCKSTEP,
        **group_kwargs: object,
    ) -> Rig:
        channel = unique_channel()
        changes: dict[str, object] = {"channel": channel}
        if heartbeat_ms is not None:
            changes["heartbeat_ms"] = heartbeat_ms
        bus_config = dataclasses.replace(cell.bus, **changes)
        cell = sharing_the_interpreter(dataclasses.replace(cell, bus=bus_config))  # the drives run here
        bus_config = cell.bus
        # the drives keep the time the master keeps
        sim = SimulatedCell(cell, channel=channel, eds_paths=eds_paths, clock=clock).start()
        bus = CellBus(bus_config, clock=clock, can_log=can_log, lost_sync_timeout_s=lost_sync_timeout_s).open()
        group = AxisGroup(bus, cell.ordered_axes(), **group_kwargs)  # type: ignore[arg-type]
        rig = Rig(cell, sim, bus, group)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.group.close()
        rig.bus.close()
        rig.sim.stop()
