"""What a cell's program runs and its homing share: the links to its drives, which axes have homed
since their drive last booted, the cleanup every activity waits for, and the one activity at a time;
and what every run of a program works with (``RunParts``).

``AxisGroup`` (axes/master/group/axis_group.py) makes it and runs programs in it; ``CellHoming`` (axes/master/homing.py)
homes in it. Neither works the other's internals: an activity claims the cell and releases it, a
homing marks what it homed, and a stop reaches whichever activity holds the cell.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.group.configure import Configured
from pvtflow.axes.master.group.feeder import RecordAllowance
from pvtflow.axes.master.group.outcome import EventKind, GroupError
from pvtflow.axes.master.group.readiness import Readiness
from pvtflow.axes.master.group.status import GroupReports, RunView
from pvtflow.axes.master.link import AxisLink
from pvtflow.axes.master.profiles.base import Profile

EventSink = Callable[[EventKind, str, "AxisLink | None"], None]


class Activity(Protocol):
    """A program run or a homing: what holds the cell, and how it is stopped from any thread."""

    def stop(self, reason: str = ...) -> None: ...


class CellRunState:
    """The run state of one cell's axes, shared by its group and its homing (``lock`` guards it)."""

    def __init__(self, bus: CellBus, links: Sequence[AxisLink], readiness: Readiness) -> None:
        self.bus = bus
        self.links = list(links)
        self.readiness = readiness
        self.lock = threading.RLock()
        self._holder: Activity | None = None
        self._homed_boot: list[int | None] = [None] * len(self.links)  # the drive's boot count when it homed
        bus.on_fault(self._on_fault)

    # --- the one activity at a time -----------------------------------------------------------------
    @property
    def holder(self) -> Activity | None:
        """The activity that holds the cell (None: it is free)."""
        return self._holder

    def claim(self, activity: Activity, busy: str) -> None:
        """``activity`` holds the cell from now on, once the last one's cleanup is over; GroupError
        with ``busy`` when another holds it."""
        with self.lock:
            if self._holder is not None and self._holder is not activity:
                raise GroupError(busy)
            self.readiness.wait()
            self._holder = activity

    def release(self, activity: Activity) -> None:
        with self.lock:
            if self._holder is activity:
                self._holder = None

    def stop(self, reason: str) -> None:
        """Stop whatever holds the cell (any thread)."""
        holder = self._holder
        if holder is not None:
            holder.stop(reason)

    # --- homed since boot ---------------------------------------------------------------------------
    @property
    def homed(self) -> tuple[bool, ...]:
        """Per axis: nothing to home, or homed since its drive last booted (a boot-up message, an NMT
        reset or a lost heartbeat, a power loss, undoes it)."""
        return tuple(
            link.config.homing is None or self._homed_boot[i] == self.bus.watch.boot_count(link.node_id)
            for i, link in enumerate(self.links)
        )

    def mark_homed(self, i: int) -> None:
        self._homed_boot[i] = self.bus.watch.boot_count(self.links[i].node_id)

    def _on_fault(self, fault: BusFault) -> None:
        """A drive whose heartbeat was lost may have lost power: its position means nothing any more."""
        if fault.kind is FaultKind.HEARTBEAT:
            for i, link in enumerate(self.links):
                if link.node_id == fault.node_id:
                    self._homed_boot[i] = None


@dataclass(frozen=True)
class RunParts:
    """What every run of a group works with (``axes.master.group.run``); the group owns all of it,
    ``lock`` is its cell's (``CellRunState.lock``)."""

    bus: CellBus
    links: Sequence[AxisLink]
    profiles: Sequence[Profile]
    allowance: RecordAllowance
    reports: GroupReports
    readiness: Readiness
    configuration: Configured
    lock: threading.RLock
    event: EventSink
    progress: Callable[[int, RunView], None]  # after every answered SYNC: the group's progress report
    halt_timeout_ms: float

    @property
    def status_lag(self) -> int:
        """SYNCs by which a status TPDO sent every n SYNCs may report late (axes.master.tpdo_rates)."""
        return max((p.sync_answer_every for p in self.profiles), default=1) - 1
