"""One MCAP file per motion: what each axis was told, what it did, and every frame on the bus.

A ``Recorder`` is attached to an open ``CellBus`` and the cell's ``AxisGroup``; it hears the bus
through ``FrameLog.taps`` (every frame, sent and received), the bus's fault callbacks and a
SYNC listener, and the group's events through ``event()``. Those run in the bus's threads, so they
only append what they saw to a deque (one tuple of the numbers and objects as they are: no
conversion, no encoding, no lock); the writer thread (service/recording/writer.py) takes them in
batches and writes the channels (service/recording/channels.py).

Channels (the joint's name in ``/axis/<joint>/...``):

- ``/axis/<joint>/planned``: the program as the drive will execute it, every ms from the start
  SYNC, in counts and joint units (service/recording/planned.py).
- ``/axis/<joint>/actual``: per SYNC, the position the drive answered, its statusword and power
  state, the SYNC they are as of (``status_sync``: with status TPDOs every n SYNCs, ``axes/master/tpdo_rates.py``,
  an answer stands for the n - 1 SYNCs after it too), and during a run the planned position at that
  SYNC (the status's, not the one it is still the latest on) and the following error (planned minus
  actual, counts).
- ``/buffers``: per SYNC, the records queued in each drive's buffer (the feeders' levels).
- ``/sync``: per SYNC frame, its number and the interval since the one before (ms, bus clock).
- ``/joint_states``: per SYNC, positions in joint units (sensor_msgs/JointState's field names).
- ``/tf``: ``foxglove.FrameTransforms``, every link in the world frame by Pinocchio's forward
  kinematics of the answered positions, at most every ``TF_EVERY_MS`` of bus time.
- ``/events``: ``foxglove.Log``: the group's and the homing's events, the bus's faults.
- ``/faults``: every fault the bus reports (EMCY with its code, heartbeat, SYNC, bus state).
- ``/can``: every frame: identifier, data, direction.

The robot's URDF is an attachment (``robot.urdf``) and a message on ``/robot_description``
(``std_msgs/msg/String``'s one field, which Foxglove's URDF layer takes from a topic), the cell's
facts a metadata record. The same messages go to a live server (service/live.py) when one is given.

Time stamps are the bus's clock: a received frame's time stamp (python-can's, on the simulated wire
the bus time its last bit left the wire). With SYNC in lockstep the bus time is virtual while the
master stamps what it sends with the wall clock, so there the master's own frames, the SYNC
listeners' snapshots and the events are logged at the latest time stamp the master received (the
master's local bus time, as the simulated wire defines it); on the wall clock every frame keeps its
own time stamp and the rest is logged at the latest one.
"""

from __future__ import annotations

import contextlib
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault
from pvtflow.service.recording.channels import FAULT_LEVEL, INFO
from pvtflow.service.recording.mcap_file import CHUNK_BYTES, McapFile, open_mcap_file
from pvtflow.service.recording.writer import CHUNK_MS, RecordWriter

if TYPE_CHECKING:
    from pvtflow.axes.master.group.axis_group import AxisGroup
    from pvtflow.service.config import CellConfig
    from pvtflow.service.live import LiveServer


class Recorder:
    """``Recorder(path, cell).attach(bus, group)``, then the motion, then ``close(outcome)``.

    ``event(kind, message, joint)`` from any thread (the group's and the homing's callbacks)."""

    def __init__(
        self,
        path: str | Path | None,
        cell: CellConfig,
        *,
        chunk_ms: float = CHUNK_MS,
        chunk_bytes: int = CHUNK_BYTES,
        kind: str = "motion",
        live: LiveServer | None = None,
    ) -> None:
        self.path = Path(path) if path is not None else None  # None: live only (``live``), no file
        self.live = live
        self.cell = cell
        mcap: McapFile | None = None
        if self.path is not None:
            self.path.open("wb").close()  # an OSError for the caller, before anything else
            mcap = open_mcap_file(self.path, chunk_bytes)
        # what the bus's threads hand over: one tuple appended per frame, SYNC, fault or event (a deque's
        # append is atomic and takes no lock); the writer takes them in batches
        self._items: deque[tuple[Any, ...]] = deque()
        # the bus's clock as the master last heard it; None until the first frame that tells it (what
        # comes before is stamped with that frame's time by the writer: it happened just before)
        self._clock_s: float | None = None
        self._clock = Clock.LOCKSTEP
        self._bus: CellBus | None = None
        self._group: AxisGroup | None = None
        self._writer = RecordWriter(cell, self._items, mcap, live, chunk_ms)
        self._writer.start(kind)

    @property
    def messages(self) -> int:
        """The messages written so far."""
        return self._writer.messages

    @property
    def writer_cpu_s(self) -> float | None:
        """The writer thread's CPU time, once closed (bench/record_cost.py)."""
        return self._writer.cpu_s

    def attach(self, bus: CellBus, group: AxisGroup | None = None) -> Recorder:
        self._bus, self._group = bus, group
        self._clock = bus.sync.clock
        bus.recorder.taps.append(self._on_frame)
        bus.on_fault(self._on_fault)
        bus.sync.add_listener(self._on_sync)
        return self

    def detach(self) -> None:
        bus = self._bus
        if bus is None:
            return
        with contextlib.suppress(ValueError):  # a tap already gone
            bus.recorder.taps.remove(self._on_frame)
        bus.remove_fault_callback(self._on_fault)
        bus.sync.remove_listener(self._on_sync)
        self._bus = None

    # --- the bus's threads: append only ----------------------------------------------------------------
    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_rx or self._clock is Clock.WALL:
            clock = self._clock_s
            self._clock_s = msg.timestamp if clock is None or msg.timestamp > clock else clock
            self._items.append(("can", msg.timestamp, msg))
        else:
            self._items.append(("can", self._clock_s, msg))

    def _on_fault(self, fault: BusFault) -> None:
        self._items.append(("fault", self._clock_s, fault))

    def _on_sync(self, n: int) -> None:
        group = self._group
        if group is None:
            self._items.append(("sync_state", self._clock_s, n, None, None, (), (), (), ()))
            return
        links = group.links
        elapsed = group.elapsed_syncs() if group.running else None
        programs = group.programs if elapsed is not None else None
        levels = [f.level for f in group.feeders] if elapsed is not None else ()
        positions = [lk.position for lk in links]
        words = [lk.statusword for lk in links]
        statuses = [lk.status_sync for lk in links]  # the SYNC each drive's position and statusword are as of
        self._items.append(("sync_state", self._clock_s, n, elapsed, programs, positions, words, levels, statuses))

    def event(self, kind: str, message: str, joint: str | None = None, level: int | None = None) -> None:
        if level is None:
            level = FAULT_LEVEL.get(str(kind), INFO)
        self._items.append(("event", self._clock_s, str(kind), message, joint, level))

    def close(self, outcome: dict[str, Any] | None = None) -> None:
        """Everything queued written, the outcome as metadata; the file closed."""
        self.detach()
        self._writer.close(outcome)
