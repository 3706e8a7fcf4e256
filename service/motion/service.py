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
  position (``not_homed``) until every axis has homed since its drive last booted (axes.master.homing).
- Status is what the drives say: their statuswords, positions and buffer status (from their TPDOs
  while moving, read by SDO when idle), never what the service hopes.

Publications go through ``publish(topic, payload)`` (the server queues them to zenoh); it is
called from the bus threads and must not block.
"""

from __future__ import annotations

import threading

from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.link import DriveError
from pvtflow.service.cell_bus import CellBusError, open_bus
from pvtflow.service.live_rest import RestView
from pvtflow.service.motion.stop_recover import StopRecover
from pvtflow.service.planning import PlanningProcess


class MotionService(StopRecover):
    """One cell: its bus, drives, plans, journal and the one motion that may run on it."""

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
