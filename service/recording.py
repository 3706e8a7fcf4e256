"""One MCAP file per motion: what each axis was told, what it did, and every frame on the bus.

A ``Recorder`` is attached to an open ``CellBus`` and the cell's ``AxisGroup``; it hears the bus
through ``FrameRecorder.taps`` (every frame, sent and received), the bus's fault callbacks and a
SYNC listener, and the group's events through ``event()``. Those run in the bus's threads, so they
only append what they saw to a deque (one tuple of the numbers and objects as they are: no
conversion, no encoding, no lock). One writer thread takes what was appended every ``BATCH_S`` and
turns the batch into JSON messages (``json`` encoding, each channel with a JSON schema registered
once): the unit conversions, the planned positions and the link transforms (service/link_transforms.py)
over all the batch's SYNCs at once, the messages formatted directly. They are written with the
Foxglove SDK's MCAP writer (one call per message into its native code; zstd in the writing thread,
not in worker threads that would compete with the bus's) and handed to the live server.

The writer keeps its normal scheduling priority: it holds the interpreter's lock while it works, and
a thread of lower priority that is preempted while holding it would keep the SYNC thread waiting for
the lock (priority inversion); what keeps it off the SYNC thread's way is its small cost per SYNC
and the switch interval (``axes.bus.SWITCH_INTERVAL_S``), which makes it hand the lock over within 0.1 ms.

Channels (the joint's name in ``/axis/<joint>/...``):

- ``/axis/<joint>/planned``: the program as the drive will execute it, every ms from the start
  SYNC: ``AxisProgram.reconstruction()`` (axes/interpolation.py, the one cubic) sampled on the
  drive's own 1 kHz grid, in counts and joint units; written ``PLANNED_LEAD_MS`` ahead of the run
  (a whole plan at once is tens of thousands of messages: the writer would fall seconds behind the
  bus, and a kill -9 would lose the actual data it had not reached), the rest at the close.
- ``/axis/<joint>/actual``: per SYNC, the position the drive answered, its statusword and power
  state, and during a run the planned position at that SYNC and the following error (planned
  minus actual, counts).
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

A kill -9 loses at most the chunk being built: a chunk is closed every ``chunk_ms`` of bus time,
every ``CHUNK_WALL_S`` of wall time (checked after each batch) and at ``chunk_bytes``, whichever
comes first
(``read_recording`` reads a file cut anywhere up to its last complete record).
"""

from __future__ import annotations

import bisect
import contextlib
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from numpy.typing import NDArray

from axes.bus import CellBus
from axes.bus_faults import BusFault, FaultKind
from axes.cia402 import decode_state
from axes.interpolation import PiecewiseCubic
from axes.objects import SYNC_COB_ID
from axes.outcome import Result
from service.link_transforms import LinkTransforms
from service.live import new_channel

if TYPE_CHECKING:
    from axes.group import AxisGroup
    from axes.program import AxisProgram
    from service.config import CellConfig
    from service.live import LiveServer

log = logging.getLogger("pvtflow.recording")

PROFILE = "pvtflow"
CHUNK_MS = 250.0  # bus time a chunk spans at most
CHUNK_WALL_S = 0.25  # wall time a chunk stays open at most (a lockstep cell runs faster than the wall)
CHUNK_BYTES = 256 * 1024
TF_EVERY_MS = 20.0
PLANNED_LEAD_MS = 250.0  # the planned channel is written this far ahead of the run (a chunk's span)
BATCH_S = 0.05  # the writer takes what the bus's threads appended this often
DRIVE_SAMPLE_MS = 1.0  # the planned channel's grid: the drives interpolate at 1 kHz

# Foxglove's schemas (https://docs.foxglove.dev/docs/visualization/message-schemas), JSON flavour
_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
}
_VECTOR3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
LOG_SCHEMA = {
    "title": "foxglove.Log",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {"type": "integer", "enum": [0, 1, 2, 3, 4, 5]},
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    },
}
FRAME_TRANSFORMS_SCHEMA = {
    "title": "foxglove.FrameTransforms",
    "type": "object",
    "properties": {
        "transforms": {
            "type": "array",
            "items": {
                "title": "foxglove.FrameTransform",
                "type": "object",
                "properties": {
                    "timestamp": _TIME,
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": _VECTOR3,
                    "rotation": _QUATERNION,
                },
            },
        }
    },
}
_INT_OR_NULL = {"type": ["integer", "null"]}
_NUM_OR_NULL = {"type": ["number", "null"]}
JOINT_STATE_SCHEMA = {
    "title": "pvtflow.JointState",
    "description": "sensor_msgs/JointState's fields: joint names and positions (rad or m)",
    "type": "object",
    "properties": {
        "header": {"type": "object", "properties": {"stamp": _TIME, "frame_id": {"type": "string"}}},
        "name": {"type": "array", "items": {"type": "string"}},
        "position": {"type": "array", "items": _NUM_OR_NULL},
    },
}
PLANNED_SCHEMA = {
    "title": "pvtflow.PlannedSample",
    "description": "the drive's reconstruction of its records at program time t_ms (counts, ms)",
    "type": "object",
    "properties": {
        "t_ms": {"type": "number"},
        "position_qc": {"type": "number"},
        "velocity_qc_per_ms": {"type": "number"},
        "acceleration_qc_per_ms2": {"type": "number"},
        "position": {"type": "number"},
    },
}
ACTUAL_SCHEMA = {
    "title": "pvtflow.AxisSample",
    "description": "what the drive answered to one SYNC; planned and following error (planned - actual) in a run",
    "type": "object",
    "properties": {
        "sync": {"type": "integer"},
        "elapsed_ms": _NUM_OR_NULL,
        "position_qc": _INT_OR_NULL,
        "position": _NUM_OR_NULL,
        "planned_qc": _NUM_OR_NULL,
        "following_error_qc": _NUM_OR_NULL,
        "statusword": {"type": "integer"},
        "state": {"type": "string"},
    },
}
BUFFERS_SCHEMA = {
    "title": "pvtflow.BufferLevels",
    "type": "object",
    "properties": {
        "sync": {"type": "integer"},
        "joints": {"type": "array", "items": {"type": "string"}},
        "levels": {"type": "array", "items": _INT_OR_NULL},
    },
}
SYNC_SCHEMA = {
    "title": "pvtflow.Sync",
    "type": "object",
    "properties": {"sync": {"type": "integer"}, "interval_ms": _NUM_OR_NULL},
}
FAULT_SCHEMA = {
    "title": "pvtflow.Fault",
    "type": "object",
    "properties": {
        "kind": {"type": "string"},
        "node_id": _INT_OR_NULL,
        "joint": {"type": ["string", "null"]},
        "message": {"type": "string"},
        "code": {"type": "integer"},
    },
}
CAN_SCHEMA = {
    "title": "pvtflow.CanFrame",
    "type": "object",
    "properties": {
        "id": {"type": "integer"},
        "extended": {"type": "boolean"},
        "remote": {"type": "boolean"},
        "error": {"type": "boolean"},
        "rx": {"type": "boolean", "description": "false: sent by the master"},
        "dlc": {"type": "integer"},
        "data": {"type": "string", "description": "hex"},
    },
}

ROBOT_DESCRIPTION_SCHEMA = {
    "title": "std_msgs/msg/String",
    "description": "the robot's URDF, for a 3D panel's URDF layer (topic source)",
    "type": "object",
    "properties": {"data": {"type": "string"}},
}

_JSON_BOOL = {True: "true", False: "false"}

# foxglove.Log levels
DEBUG, INFO, WARNING, ERROR = 1, 2, 3, 4
_FAULT_LEVEL = {k.value: (WARNING if k.warning else ERROR) for k in FaultKind}
# how a run ended, as a log level: a fault is an error, a stop or a refusal a warning
_FAULT_LEVEL.update({r.value: ERROR for r in Result if not r.ok})
_FAULT_LEVEL.update({Result.STOPPED.value: WARNING, Result.REJECTED.value: WARNING, "halted": WARNING})


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
        self.chunk_ms = chunk_ms
        self.joints = tuple(a.joint for a in cell.ordered_axes())
        self._joints_json = json.dumps(list(self.joints))
        self._node_joint = {a.node_id: a.joint for a in cell.axes}
        self._scaling = [a.scaling for a in cell.ordered_axes()]
        self._mcap: McapFile | None = None
        self._context: Any = None
        if self.path is not None:
            self.path.open("wb").close()  # an OSError for the caller, before anything else
            self._mcap = open_mcap_file(self.path, chunk_bytes)
            self._context = self._mcap.context
        self._channels: dict[str, Any] = {}  # topic -> the native log call of its channel
        # what the bus's threads hand over: one tuple appended per frame, SYNC, fault or event (a deque's
        # append is atomic and takes no lock); the writer takes them in batches every ``BATCH_S``
        self._items: deque[tuple[Any, ...]] = deque()
        self._closing = threading.Event()
        self._held: list[tuple[Any, ...]] = []  # appended before the bus's clock was known
        self._last_s = 0.0  # the latest bus time written
        # the bus's clock as the master last heard it; None until the first frame that tells it (what
        # comes before is stamped with that frame's time by the writer: it happened just before)
        self._clock_s: float | None = None
        self._lockstep = True
        self._bus: CellBus | None = None
        self._group: AxisGroup | None = None
        self._last_sync_s: float | None = None
        self._last_tf_s: float | None = None
        self._sync_frames = 0
        self._states: dict[int, str] = {}  # statusword -> its power state's name
        self._links: LinkTransforms | None = None
        self._run_programs: tuple[AxisProgram, ...] | None = None
        self._run_cubics: list[PiecewiseCubic] = []  # the reconstruction of each axis's program of the run
        # per axis: t, position, velocity, acceleration, joint units (lists: the writer reads them one by one)
        self._planned: list[tuple[list[float], ...]] = []
        self._planned_qc: list[NDArray[np.float64]] = []  # the positions again, for lookups by index
        self._planned_next: list[int] = []
        self._planned_t0_s = 0.0
        self.messages = 0
        self.writer_cpu_s: float | None = None  # the writer thread's CPU time, once closed (bench/record_cost.py)
        self._write_header(kind)
        self._thread = threading.Thread(target=self._drain, name="pvtflow-recorder", daemon=True)
        self._thread.start()

    # --- the bus's threads: append only ----------------------------------------------------------------
    def attach(self, bus: CellBus, group: AxisGroup | None = None) -> Recorder:
        self._bus, self._group = bus, group
        self._lockstep = bus.sync.lockstep
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

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_rx or not self._lockstep:
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
            self._items.append(("sync_state", self._clock_s, n, None, None, (), (), ()))
            return
        links = group.links
        elapsed = group.elapsed_syncs() if group.running else None
        programs = group.programs if elapsed is not None else None
        levels = [f.level for f in group.feeders] if elapsed is not None else ()
        positions = [lk.position for lk in links]
        words = [lk.statusword for lk in links]
        self._items.append(("sync_state", self._clock_s, n, elapsed, programs, positions, words, levels))

    def event(self, kind: str, message: str, joint: str | None = None, level: int | None = None) -> None:
        if level is None:
            level = _FAULT_LEVEL.get(str(kind), INFO)
        self._items.append(("event", self._clock_s, str(kind), message, joint, level))

    def close(self, outcome: dict[str, Any] | None = None) -> None:
        """Everything queued written, the outcome as metadata, the summary; the file closed."""
        self.detach()
        if outcome is not None:
            self._items.append(("outcome", None, outcome))
        self._closing.set()
        self._thread.join(timeout=30.0)
        if self._mcap is not None:
            self._mcap.close()
            self._mcap = None

    # --- the writer thread -------------------------------------------------------------------------------
    def _drain(self) -> None:
        """Every ``BATCH_S``: what the bus's threads appended since, written as one batch; a chunk closed
        every ``chunk_ms`` of bus time or ``CHUNK_WALL_S`` of wall time."""
        chunk_start_s: float | None = None
        flushed_wall = time.monotonic()
        items = self._items
        while True:
            closing = self._closing.wait(BATCH_S)
            batch = [items.popleft() for _ in range(len(items))]
            first = self._write_batch(batch)
            if first is not None and chunk_start_s is None:
                chunk_start_s = first
            if closing:
                held, self._held = self._held, []
                self._write_batch([(h[0], self._last_s, *h[2:]) for h in held])
                self._safely("planned", self._write_planned_until, float("inf"))
                self.writer_cpu_s = time.thread_time()
                return
            now = time.monotonic()
            bus_due = chunk_start_s is not None and self._last_s - chunk_start_s >= self.chunk_ms / 1000.0
            if bus_due or (chunk_start_s is not None and now - flushed_wall >= CHUNK_WALL_S):
                if self._mcap is not None:
                    self._mcap.flush()
                chunk_start_s, flushed_wall = None, now

    def _safely(self, what: str, write: Any, *args: Any) -> None:
        try:
            write(*args)
        except Exception:  # a recording must never take the motion down
            log.exception("recording %s failed", what)

    def _write_batch(self, batch: list[tuple[Any, ...]]) -> float | None:
        """One batch in order, the SYNC snapshots together (``_sync_states``); the first bus time in it."""
        first: float | None = None
        syncs: list[tuple[Any, ...]] = []
        for item in batch:
            stamp = item[1]
            if item[0] == "outcome":
                if self._mcap is not None:
                    self._safely("outcome", self._mcap.write_metadata, "outcome", {"json": json.dumps(item[2])})
                continue
            if stamp is None:
                self._held.append(item)
                continue
            if self._held:
                held, self._held = self._held, []
                self._write_batch([(h[0], stamp, *h[2:]) for h in held])
            if first is None:
                first = stamp
            if stamp > self._last_s:
                self._last_s = stamp
            if item[0] == "sync_state":
                syncs.append(item)
            else:
                self._safely(item[0], self._write, item)
        if syncs:
            self._safely("sync_state", self._sync_states, syncs)
        return first

    def _write(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "can":
            _, stamp, msg = item
            # the most frequent message, written without a dict and json.dumps (CAN_SCHEMA's fields)
            data = (
                f'{{"id":{msg.arbitration_id},"extended":{_JSON_BOOL[msg.is_extended_id]},'
                f'"remote":{_JSON_BOOL[msg.is_remote_frame]},"error":{_JSON_BOOL[msg.is_error_frame]},'
                f'"rx":{_JSON_BOOL[bool(msg.is_rx)]},"dlc":{msg.dlc},"data":"{bytes(msg.data).hex()}"}}'
            )
            self._log_encoded("/can", CAN_SCHEMA, stamp, data.encode())
            if msg.arbitration_id == SYNC_COB_ID and not msg.is_error_frame:
                self._sync_frames += 1
                interval = "null" if self._last_sync_s is None else repr((stamp - self._last_sync_s) * 1000.0)
                self._last_sync_s = stamp
                self._log_encoded(
                    "/sync", SYNC_SCHEMA, stamp, f'{{"sync":{self._sync_frames},"interval_ms":{interval}}}'.encode()
                )
        elif kind == "fault":
            _, stamp, fault = item
            joint = self._node_joint.get(fault.node_id) if fault.node_id is not None else None
            self._log(
                "/faults",
                FAULT_SCHEMA,
                stamp,
                {
                    "kind": str(fault.kind),
                    "node_id": fault.node_id,
                    "joint": joint,
                    "message": fault.message,
                    "code": fault.code,
                },
            )
            self._log_event(stamp, str(fault.kind), fault.message, joint, _FAULT_LEVEL.get(str(fault.kind), ERROR))
        elif kind == "event":
            _, stamp, what, message, joint, level = item
            self._log_event(stamp, what, message, joint, level)
        elif kind == "robot":
            self._log("/robot_description", ROBOT_DESCRIPTION_SCHEMA, item[1], {"data": item[2]})

    def _log_event(self, stamp: float, kind: str, message: str, joint: str | None, level: int) -> None:
        self._log(
            "/events",
            LOG_SCHEMA,
            stamp,
            {
                "timestamp": _time(stamp),
                "level": level,
                "message": message,
                "name": f"{kind}" + (f" [{joint}]" if joint else ""),
                "file": "",
                "line": 0,
            },
        )

    def _sync_states(self, items: list[tuple[Any, ...]]) -> None:
        """SYNC snapshots, each run's part at once (a new run's plan written first)."""
        items = [it for it in items if it[5]]  # a snapshot without axes (no group) says nothing
        begin = 0
        for k, it in enumerate(items):
            programs = it[4]
            if programs is not None and programs is not self._run_programs and programs != self._run_programs:
                self._sync_run_part(items[begin:k])
                begin = k
                self._run_programs = programs
                self._write_planned(programs, it[1] - (it[3] or 0) * self.cell.bus.sync_period_ms / 1000.0)
        self._sync_run_part(items[begin:])

    def _sync_run_part(self, items: list[tuple[Any, ...]]) -> None:
        """/axis/<joint>/actual, /buffers, /joint_states and /tf of SYNC snapshots of one run (or of
        none), the unit conversions, planned positions and link transforms over all of them at once."""
        if not items:
            return
        period = self.cell.bus.sync_period_ms
        stamps = [it[1] for it in items]
        elapsed_ms = [None if it[3] is None else it[3] * period for it in items]
        counts = np.array([[np.nan if v is None else v for v in it[5]] for it in items], dtype=float)
        positions = np.column_stack([s.qc_to_position(counts[:, i]) for i, s in enumerate(self._scaling)])
        planned = np.full(counts.shape, np.nan)
        in_run = [k for k, e in enumerate(elapsed_ms) if e is not None]
        if in_run:
            self._write_planned_until(max(elapsed_ms[k] for k in in_run) + PLANNED_LEAD_MS)  # type: ignore[operator]
            if self._run_cubics:
                t = np.array([elapsed_ms[k] for k in in_run], dtype=float)
                for i in range(len(self.joints)):
                    planned[in_run, i] = self._planned_at(i, t)
        following = planned - counts
        position_rows, planned_rows, following_rows = positions.tolist(), planned.tolist(), following.tolist()
        states = self._states
        for k, it in enumerate(items):
            stamp, n, qcs, words, levels = it[1], it[2], it[5], it[6], it[7]
            e = elapsed_ms[k]
            for i, joint in enumerate(self.joints):
                word = words[i]
                state = states.get(word)
                if state is None:
                    state = states[word] = decode_state(word).value
                data = encode_actual(
                    n, e, qcs[i], position_rows[k][i], planned_rows[k][i], following_rows[k][i], word, state
                )
                self._log_encoded(f"/axis/{joint}/actual", ACTUAL_SCHEMA, stamp, data)
            if levels:
                text = ",".join("null" if v is None else str(int(v)) for v in levels)
                self._log_encoded(
                    "/buffers",
                    BUFFERS_SCHEMA,
                    stamp,
                    f'{{"sync":{n},"joints":{self._joints_json},"levels":[{text}]}}'.encode(),
                )
            states_json = encode_joint_states(stamp, self._joints_json, position_rows[k])
            self._log_encoded("/joint_states", JOINT_STATE_SCHEMA, stamp, states_json)
        due = []
        for k, stamp in enumerate(stamps):
            if not np.isnan(positions[k]).any() and (
                self._last_tf_s is None or stamp - self._last_tf_s >= TF_EVERY_MS / 1000.0
            ):
                self._last_tf_s = stamp
                due.append(k)
        if due:
            if self._links is None:
                self._links = LinkTransforms(self.cell.model, self.joints)
            translations, rotations = self._links.compute(positions[due])
            for row, k in enumerate(due):
                data = encode_transforms(stamps[k], self._links.frames, translations[row], rotations[row])
                self._log_encoded("/tf", FRAME_TRANSFORMS_SCHEMA, stamps[k], data)

    def _write_planned(self, programs: Sequence[AxisProgram], t0_s: float) -> None:
        """A new run: each axis's reconstruction sampled on the drive's grid, written ``PLANNED_LEAD_MS``
        ahead of the run (``_write_planned_until``) and the rest when the recording closes, so the
        writer never falls behind the bus with a whole plan at once."""
        self._write_planned_until(float("inf"))  # the rest of the run before
        self._run_cubics = [prog.reconstruction() for prog in programs]
        self._planned, self._planned_qc = [], []
        for cubic, scaling in zip(self._run_cubics, self._scaling, strict=True):
            t = cubic.sample_times(DRIVE_SAMPLE_MS)
            p = np.asarray(cubic.position(t), dtype=float)
            columns = (t, p, cubic.velocity(t), cubic.acceleration(t), scaling.qc_to_position(p))
            self._planned.append(tuple(np.asarray(c, dtype=float).tolist() for c in columns))
            self._planned_qc.append(p)
        self._planned_next = [0] * len(self._planned)
        self._planned_t0_s = t0_s

    def _planned_at(self, i: int, t_ms: NDArray[np.float64]) -> NDArray[np.float64]:
        """Axis i's planned positions at program times t_ms: the sample of the drive's grid where a time
        is on it (a SYNC period of whole ms), else the reconstruction itself."""
        p = self._planned_qc[i]
        k = np.rint(t_ms / DRIVE_SAMPLE_MS)
        on_grid = (np.abs(k * DRIVE_SAMPLE_MS - t_ms) < 1e-9) & (k >= 0) & (k < len(p))
        if on_grid.all():
            return p[k.astype(int)]
        off = np.asarray(self._run_cubics[i].position(t_ms), dtype=float)
        return np.where(on_grid, p[np.clip(k, 0, len(p) - 1).astype(int)], off)

    def _write_planned_until(self, t_ms: float) -> None:
        for i, (t, p, v, a, q) in enumerate(self._planned):
            stop = bisect.bisect_right(t, t_ms)
            topic = f"/axis/{self.joints[i]}/planned"
            t0 = self._planned_t0_s
            for k in range(self._planned_next[i], stop):
                data = (
                    f'{{"t_ms":{t[k]!r},"position_qc":{p[k]!r},"velocity_qc_per_ms":{v[k]!r},'
                    f'"acceleration_qc_per_ms2":{a[k]!r},"position":{q[k]!r}}}'
                )
                self._log_encoded(topic, PLANNED_SCHEMA, t0 + t[k] / 1000.0, data.encode())
            self._planned_next[i] = max(self._planned_next[i], stop)

    # --- MCAP ----------------------------------------------------------------------------------------------
    def _write_header(self, kind: str) -> None:
        cell = self.cell
        urdf = cell.urdf.read_bytes()
        self._items.append(("robot", None, urdf.decode()))  # at the bus time of the first frame
        if self._mcap is None:
            return
        self._mcap.write_metadata(
            "pvtflow",
            {
                "kind": kind,
                "cell": cell.name,
                "joints": ",".join(self.joints),
                "sync_period_ms": str(cell.bus.sync_period_ms),
                "wall_time_started": f"{time.time():.6f}",
            },
        )
        self._mcap.attach(
            log_time=time.time_ns(), create_time=0, name="robot.urdf", media_type="application/xml", data=urdf
        )
        self._mcap.flush()

    def _log(self, topic: str, schema: dict[str, Any], stamp_s: float, payload: dict[str, Any]) -> None:
        self._log_encoded(topic, schema, stamp_s, json.dumps(payload).encode())

    def _log_encoded(self, topic: str, schema: dict[str, Any], stamp_s: float, data: bytes) -> None:
        ns = max(0, round(stamp_s * 1e9))
        self.messages += 1
        if self.live is not None:
            self.live.log(topic, schema, ns, data)
        if self._context is None:
            return
        log_bytes = self._channels.get(topic)
        if log_bytes is None:
            log_bytes = self._channels[topic] = new_channel(self._context, topic, schema).base.log
        log_bytes(data, ns, None)


def _time(stamp_s: float) -> dict[str, int]:
    ns = max(0, round(stamp_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _number(x: float | None) -> str:
    """A JSON number, null for None or NaN."""
    return "null" if x is None or x != x else repr(float(x))


def encode_actual(
    sync: int,
    elapsed_ms: float | None,
    qc: int | None,
    position: float | None,
    planned: float | None,
    following: float | None,
    statusword: int,
    state: str,
) -> bytes:
    """/axis/<joint>/actual (ACTUAL_SCHEMA) as JSON; NaN and None are null."""
    return (
        f'{{"sync":{sync},"elapsed_ms":{_number(elapsed_ms)},"position_qc":{"null" if qc is None else int(qc)},'
        f'"position":{_number(position)},"planned_qc":{_number(planned)},"following_error_qc":{_number(following)},'
        f'"statusword":{statusword},"state":"{state}"}}'
    ).encode()


def encode_joint_states(stamp_s: float, joints_json: str, positions: Sequence[float | None]) -> bytes:
    """/joint_states (JOINT_STATE_SCHEMA) as JSON; NaN positions are null."""
    ns = max(0, round(stamp_s * 1e9))
    values = ",".join(_number(v) for v in positions)
    return (
        f'{{"header":{{"stamp":{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}},"frame_id":""}},'
        f'"name":{joints_json},"position":[{values}]}}'
    ).encode()


def encode_transforms(
    stamp_s: float, frames: Sequence[str], translations: NDArray[np.float64], rotations: NDArray[np.float64]
) -> bytes:
    """/tf (foxglove.FrameTransforms) as JSON: every frame's placement in ``world``."""
    ns = max(0, round(stamp_s * 1e9))
    stamp = f'{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}}'
    parts = []
    for name, (tx, ty, tz), (x, y, z, w) in zip(frames, translations.tolist(), rotations.tolist(), strict=True):
        parts.append(
            f'{{"timestamp":{stamp},"parent_frame_id":"world","child_frame_id":"{name}",'
            f'"translation":{{"x":{tx!r},"y":{ty!r},"z":{tz!r}}},"rotation":{{"x":{x!r},"y":{y!r},"z":{z!r},"w":{w!r}}}}}'
        )
    return ('{"transforms":[' + ",".join(parts) + "]}").encode()


class McapFile:
    """An MCAP file of the Foxglove SDK's writer and the context whose channels it records."""

    def __init__(self, path: Path, chunk_bytes: int) -> None:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.context = foxglove.Context()
        # compression in the writing thread (0): zstd's own worker threads would compete with the bus's
        options = MCAPWriteOptions(
            compression=MCAPCompression.Zstd, profile=PROFILE, chunk_size=chunk_bytes, compression_threads=0
        )
        self.writer = foxglove.open_mcap(path, allow_overwrite=True, context=self.context, writer_options=options)

    def write_metadata(self, name: str, metadata: dict[str, str]) -> None:
        self.writer.write_metadata(name, metadata)

    def attach(self, **kwargs: Any) -> None:
        self.writer.attach(**kwargs)

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


def open_mcap_file(path: Path, chunk_bytes: int = CHUNK_BYTES) -> McapFile:
    return McapFile(path, chunk_bytes)


# --- reading -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Recorded:
    topic: str
    log_time_ns: int
    data: dict[str, Any]
    schema: str


@dataclass
class Recording:
    """What ``read_recording`` found: messages in file order, metadata, attachments, and whether
    the file ended properly (False: cut short, e.g. a process killed mid-motion)."""

    messages: list[Recorded]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]
    complete: bool

    def topic(self, name: str) -> list[Recorded]:
        return [m for m in self.messages if m.topic == name]

    @property
    def topics(self) -> set[str]:
        return {m.topic for m in self.messages}


class RecordingError(ValueError):
    """Not an MCAP file pvtflow can read (one line for the user)."""


def read_recording(path: str | Path) -> Recording:
    """Every complete record of an MCAP file, also of one cut short (a truncated chunk is dropped)."""
    from mcap.records import Attachment, DataEnd, Footer, Metadata

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    out = Recording([], {}, {}, complete=False)
    if not Path(path).is_file():
        raise RecordingError(f"{path}: no such file")
    with Path(path).open("rb") as handle:
        records: Iterator[Any] = StreamReader(handle, validate_crcs=True).records
        try:
            for record in records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    schema = schemas.get(channel.schema_id)
                    out.messages.append(
                        Recorded(
                            channel.topic,
                            record.log_time,
                            json.loads(record.data),
                            schema.name if schema else "",
                        )
                    )
                elif isinstance(record, Metadata):
                    out.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Attachment):
                    out.attachments[record.name] = bytes(record.data)
                elif isinstance(record, DataEnd | Footer):
                    out.complete = True
        except McapError as exc:
            if not out.messages and not out.metadata and "Magic" in type(exc).__name__:
                raise RecordingError(f"{path}: not an MCAP file") from None
        except (EOFError, ValueError, KeyError, OSError) as exc:
            log.debug("%s: read up to a damaged record: %s", path, exc)
    return out
