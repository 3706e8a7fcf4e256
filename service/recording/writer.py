"""The recorder's writer thread: what the bus's threads queued, turned into messages in batches.

Every ``BATCH_S`` the writer takes what the recorder's callbacks appended (service/recording/recorder.py)
and writes it as one batch: the unit conversions, the planned positions (service/recording/planned.py)
and the link transforms (service/link_transforms.py) over all the batch's SYNCs at once, each message
encoded once (service/recording/channels.py), written to the MCAP file and handed to the live server.

It keeps its normal scheduling priority: it holds the interpreter's lock while it works, and a thread
of lower priority that is preempted while holding it would keep the SYNC thread waiting for the lock
(priority inversion); what keeps it off the SYNC thread's way is its small cost per SYNC and the
switch interval (``axes.canbus.threads.SWITCH_INTERVAL_S``), which makes it hand the lock over within 0.1 ms.

A kill -9 loses at most the chunk being built: a chunk is closed every ``chunk_ms`` of bus time,
every ``CHUNK_WALL_S`` of wall time (checked after each batch) and at the file's chunk size,
whichever comes first.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from pvtflow.axes.drive.cia402 import decode_state
from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.service.link_transforms import LinkTransforms
from pvtflow.service.live import new_channel
from pvtflow.service.recording.channels import (
    ACTUAL_SCHEMA,
    BUFFERS_SCHEMA,
    CAN_SCHEMA,
    ERROR,
    FAULT_LEVEL,
    FAULT_SCHEMA,
    FRAME_TRANSFORMS_SCHEMA,
    JOINT_STATE_SCHEMA,
    LOG_SCHEMA,
    ROBOT_DESCRIPTION_SCHEMA,
    SYNC_SCHEMA,
    encode_actual,
    encode_buffers,
    encode_can,
    encode_joint_states,
    encode_sync,
    encode_transforms,
    log_time,
)
from pvtflow.service.recording.planned import PLANNED_LEAD_MS, PlannedRun

if TYPE_CHECKING:
    from pvtflow.service.config import CellConfig
    from pvtflow.service.live import LiveServer
    from pvtflow.service.recording.mcap_file import McapFile

log = logging.getLogger("pvtflow.recording")

CHUNK_MS = 250.0  # bus time a chunk spans at most
CHUNK_WALL_S = 0.25  # wall time a chunk stays open at most (a lockstep cell runs faster than the wall)
TF_EVERY_MS = 20.0
BATCH_S = 0.05  # the writer takes what the bus's threads appended this often


class RecordWriter:
    """``RecordWriter(cell, items, mcap, live, chunk_ms).start(kind)`` ... ``close(outcome)``.

    ``items`` is the queue the recorder's callbacks append to: tuples whose first member says what
    they are (``can``, ``fault``, ``sync_state``, ``event``, ``robot``, ``outcome``) and whose second
    is the bus time, None where the bus's clock was not known yet (written at the next one known)."""

    def __init__(
        self,
        cell: CellConfig,
        items: deque[tuple[Any, ...]],
        mcap: McapFile | None,
        live: LiveServer | None,
        chunk_ms: float = CHUNK_MS,
    ) -> None:
        self.cell = cell
        self.live = live
        self.chunk_ms = chunk_ms
        self.joints = tuple(a.joint for a in cell.ordered_axes())
        self._joints_json = json.dumps(list(self.joints))
        self._node_joint = {a.node_id: a.joint for a in cell.axes}
        self._scaling = [a.scaling for a in cell.ordered_axes()]
        self._mcap = mcap
        self._context: Any = mcap.context if mcap is not None else None
        self._channels: dict[str, Any] = {}  # topic -> the native log call of its channel
        self._items = items
        self._closing = threading.Event()
        self._held: list[tuple[Any, ...]] = []  # appended before the bus's clock was known
        self._last_s = 0.0  # the latest bus time written
        self._last_sync_s: float | None = None
        self._last_tf_s: float | None = None
        self._sync_frames = 0
        self._states: dict[int, str] = {}  # statusword -> its power state's name
        self._links: LinkTransforms | None = None
        self._plan: PlannedRun | None = None
        self.messages = 0
        self.cpu_s: float | None = None  # the thread's CPU time, once closed (bench/record_cost.py)
        self._thread = threading.Thread(target=self._drain, name="pvtflow-recorder", daemon=True)

    def start(self, kind: str) -> None:
        """The file's header (the cell's facts, the URDF), then the thread."""
        self._write_header(kind)
        self._thread.start()

    def close(self, outcome: dict[str, Any] | None = None) -> None:
        """Everything queued written, the outcome as metadata; the file closed."""
        if outcome is not None:
            self._items.append(("outcome", None, outcome))
        self._closing.set()
        self._thread.join(timeout=30.0)
        if self._mcap is not None:
            self._mcap.close()
            self._mcap = None

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
                if self._plan is not None:
                    self._safely("planned", self._plan.write_until, float("inf"), self._log_encoded)
                self.cpu_s = time.thread_time()
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
            self._log_encoded("/can", CAN_SCHEMA, stamp, encode_can(msg))
            if msg.arbitration_id == SYNC_COB_ID and not msg.is_error_frame:
                self._sync_frames += 1
                interval = None if self._last_sync_s is None else (stamp - self._last_sync_s) * 1000.0
                self._last_sync_s = stamp
                self._log_encoded("/sync", SYNC_SCHEMA, stamp, encode_sync(self._sync_frames, interval))
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
            self._log_event(stamp, str(fault.kind), fault.message, joint, FAULT_LEVEL.get(str(fault.kind), ERROR))
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
                "timestamp": log_time(stamp),
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
            run = self._plan.programs if self._plan is not None else None
            if programs is not None and programs is not run and programs != run:
                self._sync_run_part(items[begin:k])
                begin = k
                if self._plan is not None:
                    self._plan.write_until(float("inf"), self._log_encoded)  # the rest of the run before
                t0_s = it[1] - (it[3] or 0) * self.cell.bus.sync_period_ms / 1000.0
                self._plan = PlannedRun(programs, self._scaling, self.joints, t0_s)
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
        if in_run and self._plan is not None:
            self._plan.write_until(max(elapsed_ms[k] for k in in_run) + PLANNED_LEAD_MS, self._log_encoded)  # type: ignore[operator]
            # each status against the plan at the SYNC it is as of: SYNC n's elapsed less the status's age
            t = np.array([elapsed_ms[k] for k in in_run], dtype=float)
            syncs = np.array([items[k][2] for k in in_run], dtype=float)
            status_syncs = np.array([items[k][8] for k in in_run], dtype=float)
            ages_ms = (syncs[:, None] - status_syncs) * period
            for i in range(len(self.joints)):
                planned[in_run, i] = self._plan.position_at(i, t - ages_ms[:, i])
        following = planned - counts
        position_rows, planned_rows, following_rows = positions.tolist(), planned.tolist(), following.tolist()
        states = self._states
        for k, it in enumerate(items):
            stamp, n, qcs, words, levels, status_syncs = it[1], it[2], it[5], it[6], it[7], it[8]
            e = elapsed_ms[k]
            for i, joint in enumerate(self.joints):
                word = words[i]
                state = states.get(word)
                if state is None:
                    state = states[word] = decode_state(word).value
                data = encode_actual(
                    n,
                    e,
                    qcs[i],
                    position_rows[k][i],
                    planned_rows[k][i],
                    following_rows[k][i],
                    word,
                    state,
                    status_syncs[i],
                )
                self._log_encoded(f"/axis/{joint}/actual", ACTUAL_SCHEMA, stamp, data)
            if levels:
                self._log_encoded("/buffers", BUFFERS_SCHEMA, stamp, encode_buffers(n, self._joints_json, levels))
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

    # --- the file and the live server ------------------------------------------------------------------
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
