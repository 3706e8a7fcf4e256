"""What the axes layer needs to know about a cell: its bus and each axis (drive, scaling, limits).

The YAML reader that fills these lives with the service (``service.config``); the types live here,
below every layer that reads them, so that the axes never import the service or the planner.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from axes.scaling import AxisScaling, DriveLimits


@dataclass(frozen=True)
class BusConfig:
    interface: str = "virtual"
    channel: str = "pvtflow"
    bitrate: int = 1_000_000
    sync_period_ms: float = 1.0
    time_stamp: bool = True  # send 0x1013 after every SYNC
    heartbeat_ms: int = 100  # producer time asked of every node (0x1017)
    heartbeat_timeout_factor: float = 3.0  # a node is lost after this many missed periods (either way)
    master_node_id: int = 127  # the master's own heartbeat (0x700 + id), which every drive watches (0x1016)
    master_heartbeat_ms: int = 100  # the master's heartbeat period

    @property
    def master_consumer_time_ms(self) -> int:
        """The drives' 0x1016 time for the master's heartbeat: the same number of missed periods as
        the master allows a drive (``heartbeat_timeout_factor``), in whole ms."""
        return math.ceil(self.master_heartbeat_ms * self.heartbeat_timeout_factor)


@dataclass(frozen=True)
class BufferConfig:
    """EPOS2 0x20C4:02 / :03: the levels the feeder keeps the FIFO between."""

    underflow_warning: int = 4
    overflow_warning: int = 60


@dataclass(frozen=True)
class AxisConfig:
    joint: str
    node_id: int
    profile: str
    scaling: AxisScaling
    limits: DriveLimits
    period_ms: int | None = None  # fixed-period profiles: one record per period
    interpolation_submode: int | None = None  # parker_slvdn 0x60C0
    buffer: BufferConfig = field(default_factory=BufferConfig)


@dataclass(frozen=True)
class Wiring:
    """A bus and its axes without a cell file (``service.config.CellConfig`` is the other kind)."""

    bus: BusConfig
    axes: tuple[AxisConfig, ...]


class CellWiring(Protocol):
    """The part of a cell description a bus of drives needs: the bus and its axes."""

    @property
    def bus(self) -> BusConfig: ...

    @property
    def axes(self) -> Sequence[AxisConfig]: ...
