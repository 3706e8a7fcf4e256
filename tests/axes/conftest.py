"""Fixtures of the axes tests: a simulated cell on its own virtual channel, with the master on it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from axes_rig import unique_channel

from axes.bus import CellBus
from axes.group import AxisGroup
from axes.sim.cell import SimulatedCell
from service.config import CellConfig

# The rigs run the simulated drives in the test's own interpreter, where every pause of the master
# (a compile, a feed replay, the host's load) is the drives' pause too: they keep the factor the
# shipped cells had for that. The shipped cells' factor (about 3) is for drives in a process of
# their own (axes.sim.process), as pvtflow's commands run them; tests/service runs those.
IN_PROCESS_HEARTBEAT_FACTOR = 10.0


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
        lockstep: bool = True,
        **group_kwargs: object,
    ) -> Rig:
        channel = unique_channel()
        changes: dict[str, object] = {"channel": channel}
        if cell.bus.heartbeat_timeout_factor < IN_PROCESS_HEARTBEAT_FACTOR:
            changes["heartbeat_timeout_factor"] = IN_PROCESS_HEARTBEAT_FACTOR
        if heartbeat_ms is not None:
            changes["heartbeat_ms"] = heartbeat_ms
        bus_config = dataclasses.replace(cell.bus, **changes)
        cell = dataclasses.replace(cell, bus=bus_config)
        clock = "lockstep" if lockstep else "wall"  # the drives keep the time the master keeps
        sim = SimulatedCell(cell, channel=channel, eds_paths=eds_paths, clock=clock).start()
        bus = CellBus(bus_config, lockstep=lockstep, can_log=can_log, lost_sync_timeout_s=lost_sync_timeout_s).open()
        group = AxisGroup(bus, cell.ordered_axes(), **group_kwargs)  # type: ignore[arg-type]
        rig = Rig(cell, sim, bus, group)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.group.close()
        rig.bus.close()
        rig.sim.stop()
