"""One MCAP file per motion: what each axis was told, what it did, and every frame on the bus.

A ``Recorder`` is attached to an open ``CellBus`` and the cell's ``AxisGroup``; it hears the bus
through ``FrameRecorder.taps`` (every frame, sent and received), the bus's fault callbacks and a
SYNC listener, and the group's events through ``event()``. Those run in the bus's threads, so they
only queue what they saw; one writer thread turns it into JSON messages (``json`` encoding, each
channel with a JSON schema) written with the ``mcap`` library.

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
every ``CHUNK_WALL_S`` of wall time and at ``chunk_bytes``, whichever comes first
(``read_recording`` reads a file cut anywhere up to its last complete record).
"""

from __future__ import annotations

import bisect
import contextlib
import json
import logging
import queue
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from axes.bus import BusFault, CellBus, FaultKind
from axes.cia402 import decode_state
from axes.interpolation import PiecewiseCubic
from axes.objects import SYNC_COB_ID
from axes.outcome import Result

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
        self._node_joint = {a.node_id: a.joint for a in cell.axes}
        self._scaling = [a.scaling for a in cell.ordered_axes()]
        self._file = self.path.open("wb") if self.path is not None else None
        self._writer: Writer | None = None
        if self._file is not None:
            self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
            self._writer.start(profile=PROFILE, library="pvtflow")
        self._channels: dict[str, int] = {}
        self._queue: queue.SimpleQueue[tuple[Any, ...] | None] = queue.SimpleQueue()
        # the bus's clock as the master last heard it; None until the first frame that tells it (what
        # comes before is stamped with that frame's time by the writer: it happened just before)
        self._clock_s: float | None = None
        self._lockstep = True
        self._bus: CellBus | None = None
        self._group: AxisGroup | None = None
        self._last_sync_s: float | None = None
        self._sync_frames = 0
        self._run_programs: tuple[AxisProgram, ...] | None = None
        self._run_cubics: list[PiecewiseCubic] = []  # the reconstruction of each axis's program of the run
        # per axis: t, position, velocity, acceleration, joint units (lists: the writer reads them one by one)
        self._planned: list[tuple[list[float], ...]] = []
        self._planned_next: list[int] = []
        self._planned_t0_s = 0.0
        self._pin_data: Any = None
        self.messages = 0
        self.writer_cpu_s: float | None = None  # the writer thread's CPU time, once closed (bench/record_cost.py)
        self._write_header(kind)
        self._thread = threading.Thread(target=self._drain, name="pvtflow-recorder", daemon=True)
        self._thread.start()

    # --- the bus's threads: queue only ---------------------------------------------------------------
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
            self._clock_s = msg.timestamp if self._clock_s is None else max(self._clock_s, msg.timestamp)
        stamp = msg.timestamp if not self._lockstep or msg.is_rx else self._clock_s
        self._queue.put(("can", stamp, msg))

    def _on_fault(self, fault: BusFault) -> None:
        self._queue.put(("fault", self._clock_s, fault))

    def _on_sync(self, n: int) -> None:
        group = self._group
        if group is None:
            self._queue.put(("sync_state", self._clock_s, n, None, None, (), (), ()))
            return
        links = group.links
        elapsed = group.elapsed_syncs() if group.running else None
        programs = group.programs if elapsed is not None else None
        levels = tuple(f.level for f in group.feeders) if elapsed is not None else ()
        positions = tuple(lk.position for lk in links)
        words = tuple(lk.statusword for lk in links)
        self._queue.put(("sync_state", self._clock_s, n, elapsed, programs, positions, words, levels))

    def event(self, kind: str, message: str, joint: str | None = None, level: int | None = None) -> None:
        if level is None:
            level = _FAULT_LEVEL.get(str(kind), INFO)
        self._queue.put(("event", self._clock_s, str(kind), message, joint, level))

    def close(self, outcome: dict[str, Any] | None = None) -> None:
        """Everything queued written, the outcome as metadata, the summary; the file closed."""
        self.detach()
        if outcome is not None:
            self._queue.put(("outcome", outcome))
        self._queue.put(None)
        self._thread.join(timeout=30.0)
        if self._writer is None or self._file is None:
            return
        try:
            self._writer.finish()
        finally:
            self._file.close()

    # --- the writer thread -------------------------------------------------------------------------------
    def _drain(self) -> None:
        chunk_start_s: float | None = None
        flushed_wall = time.monotonic()
        unstamped: list[tuple[Any, ...]] = []  # queued before the bus's clock was known
        last_s = 0.0
        while True:
            try:
                item = self._queue.get(timeout=0.05)
            except queue.Empty:
                item = ()
            if item is None:
                for early in unstamped:
                    self._write_safely((early[0], last_s, *early[2:]))
                self._write_planned_until(float("inf"))
                self.writer_cpu_s = time.thread_time()
                return
            if item and len(item) > 1 and item[0] != "outcome" and item[1] is None:
                unstamped.append(item)
                continue
            if item:
                if len(item) > 1 and item[0] != "outcome":
                    for early in unstamped:
                        self._write_safely((early[0], item[1], *early[2:]))
                    unstamped.clear()
                stamp = self._write_safely(item)
                if stamp is not None:
                    last_s = max(last_s, stamp)
                    if chunk_start_s is None:
                        chunk_start_s = stamp
            now = time.monotonic()
            bus_due = chunk_start_s is not None and last_s - chunk_start_s >= self.chunk_ms / 1000.0
            if bus_due or (chunk_start_s is not None and now - flushed_wall >= CHUNK_WALL_S):
                if self._writer is not None:
                    self._writer.flush()
                chunk_start_s, flushed_wall = None, now

    def _write_safely(self, item: tuple[Any, ...]) -> float | None:
        try:
            return self._write(item)
        except Exception:  # a recording must never take the motion down
            log.exception("recording %s failed", item[0])
            return None

    def _write(self, item: tuple[Any, ...]) -> float | None:
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
                interval = None if self._last_sync_s is None else (stamp - self._last_sync_s) * 1000.0
                self._last_sync_s = stamp
                self._log("/sync", SYNC_SCHEMA, stamp, {"sync": self._sync_frames, "interval_ms": interval})
            return stamp
        if kind == "sync_state":
            self._sync_state(*item[1:])
            return item[1]
        if kind == "fault":
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
            return stamp
        if kind == "event":
            _, stamp, what, message, joint, level = item
            self._log_event(stamp, what, message, joint, level)
            return stamp
        if kind == "robot":
            self._log("/robot_description", ROBOT_DESCRIPTION_SCHEMA, item[1], {"data": item[2]})
            return item[1]
        if kind == "outcome" and self._writer is not None:
            self._writer.add_metadata("outcome", {"json": json.dumps(item[1])})
        return None

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

    def _sync_state(
        self,
        stamp: float,
        n: int,
        elapsed: int | None,
        programs: tuple[AxisProgram, ...] | None,
        positions: Sequence[int | None],
        words: Sequence[int],
        levels: Sequence[int | None],
    ) -> None:
        if not positions:
            return
        period = self.cell.bus.sync_period_ms
        if programs is not None and programs is not self._run_programs and programs != self._run_programs:
            self._run_programs = programs
            self._write_planned(programs, stamp - (elapsed or 0) * period / 1000.0)
        elapsed_ms = None if elapsed is None else elapsed * period
        if elapsed_ms is not None:
            self._write_planned_until(elapsed_ms + PLANNED_LEAD_MS)
        joint_positions: list[float | None] = []
        for i, joint in enumerate(self.joints):
            qc = positions[i]
            position = None if qc is None else float(self._scaling[i].qc_to_position(qc))
            joint_positions.append(position)
            planned = None
            if elapsed_ms is not None and self._run_cubics:
                planned = self._planned_at(i, elapsed_ms)
            self._log(
                f"/axis/{joint}/actual",
                ACTUAL_SCHEMA,
                stamp,
                {
                    "sync": n,
                    "elapsed_ms": elapsed_ms,
                    "position_qc": qc,
                    "position": position,
                    "planned_qc": planned,
                    "following_error_qc": None if planned is None or qc is None else planned - qc,
                    "statusword": words[i],
                    "state": decode_state(words[i]).value,
                },
            )
        if levels:
            self._log(
                "/buffers", BUFFERS_SCHEMA, stamp, {"sync": n, "joints": list(self.joints), "levels": list(levels)}
            )
        self._log(
            "/joint_states",
            JOINT_STATE_SCHEMA,
            stamp,
            {"header": {"stamp": _time(stamp), "frame_id": ""}, "name": list(self.joints), "position": joint_positions},
        )
        last_tf = getattr(self, "_last_tf_s", None)
        if None not in joint_positions and (last_tf is None or stamp - last_tf >= TF_EVERY_MS / 1000.0):
            self._last_tf_s = stamp
            self._log("/tf", FRAME_TRANSFORMS_SCHEMA, stamp, self._transforms(joint_positions, stamp))

    def _write_planned(self, programs: Sequence[AxisProgram], t0_s: float) -> None:
        """A new run: each axis's reconstruction sampled on the drive's grid, written ``PLANNED_LEAD_MS``
        ahead of the run (``_write_planned_until``) and the rest when the recording closes, so the
        writer never falls behind the bus with a whole plan at once."""
        self._write_planned_until(float("inf"))  # the rest of the run before
        self._run_cubics = [prog.reconstruction() for prog in programs]
        self._planned = []
        for cubic, scaling in zip(self._run_cubics, self._scaling, strict=True):
            t = cubic.sample_times(DRIVE_SAMPLE_MS)
            p = cubic.position(t)
            columns = (t, p, cubic.velocity(t), cubic.acceleration(t), scaling.qc_to_position(p))
            self._planned.append(tuple(np.asarray(c, dtype=float).tolist() for c in columns))
        self._planned_next = [0] * len(self._planned)
        self._planned_t0_s = t0_s

    def _planned_at(self, i: int, t_ms: float) -> float:
        """Axis i's planned position at program time t_ms: the sample of the drive's grid where t_ms is
        on it (a SYNC period of whole ms), else the reconstruction itself."""
        t, p = self._planned[i][0], self._planned[i][1]
        k = round(t_ms / DRIVE_SAMPLE_MS)
        if abs(k * DRIVE_SAMPLE_MS - t_ms) < 1e-9 and 0 <= k < len(t):
            return p[k]
        return float(self._run_cubics[i].position(t_ms))

    def _write_planned_until(self, t_ms: float) -> None:
        for i, (t, p, v, a, q) in enumerate(self._planned):
            stop = bisect.bisect_right(t, t_ms)
            topic = f"/axis/{self.joints[i]}/planned"
            for k in range(self._planned_next[i], stop):
                self._log(
                    topic,
                    PLANNED_SCHEMA,
                    self._planned_t0_s + t[k] / 1000.0,
                    {
                        "t_ms": t[k],
                        "position_qc": p[k],
                        "velocity_qc_per_ms": v[k],
                        "acceleration_qc_per_ms2": a[k],
                        "position": q[k],
                    },
                )
            self._planned_next[i] = max(self._planned_next[i], stop)

    def _transforms(self, q_by_joint: list[float | None], stamp: float) -> dict[str, Any]:
        import pinocchio as pin

        model = self.cell.model
        if self._pin_data is None:
            self._pin_data = model.model.createData()
        q = np.zeros(model.dof)
        for joint, value in zip(self.joints, q_by_joint, strict=True):
            q[model.index(joint)] = value
        pin.framesForwardKinematics(model.model, self._pin_data, q)
        out = []
        for fid, frame in enumerate(model.model.frames):
            if frame.type != pin.FrameType.BODY:
                continue
            placement = self._pin_data.oMf[fid]
            x, y, z, w = pin.Quaternion(placement.rotation).coeffs()
            tx, ty, tz = placement.translation
            out.append(
                {
                    "timestamp": _time(stamp),
                    "parent_frame_id": "world",
                    "child_frame_id": frame.name,
                    "translation": {"x": float(tx), "y": float(ty), "z": float(tz)},
                    "rotation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)},
                }
            )
        return {"transforms": out}

    # --- MCAP ----------------------------------------------------------------------------------------------
    def _write_header(self, kind: str) -> None:
        cell = self.cell
        urdf = cell.urdf.read_bytes()
        self._queue.put(("robot", None, urdf.decode()))  # at the bus time of the first frame
        if self._writer is None:
            return
        self._writer.add_metadata(
            "pvtflow",
            {
                "kind": kind,
                "cell": cell.name,
                "joints": ",".join(self.joints),
                "sync_period_ms": str(cell.bus.sync_period_ms),
                "wall_time_started": f"{time.time():.6f}",
            },
        )
        self._writer.add_attachment(time.time_ns(), 0, "robot.urdf", "application/xml", urdf)
        self._writer.flush()

    def _log(self, topic: str, schema: dict[str, Any], stamp_s: float, payload: dict[str, Any]) -> None:
        self._log_encoded(topic, schema, stamp_s, json.dumps(payload).encode())

    def _log_encoded(self, topic: str, schema: dict[str, Any], stamp_s: float, data: bytes) -> None:
        ns = max(0, round(stamp_s * 1e9))
        self.messages += 1
        if self.live is not None:
            self.live.log(topic, schema, ns, data)
        if self._writer is None:
            return
        channel = self._channels.get(topic)
        if channel is None:
            schema_id = self._writer.register_schema(
                name=str(schema["title"]), encoding="jsonschema", data=json.dumps(schema).encode()
            )
            channel = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
            self._channels[topic] = channel
        self._writer.add_message(channel, log_time=ns, publish_time=ns, data=data)


def _time(stamp_s: float) -> dict[str, int]:
    ns = max(0, round(stamp_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


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
