"""The live view between motions: the cell at rest on the same channels as during a motion.

During a motion or a homing the recorder (service/recording) feeds the live server per SYNC.
Between them nothing runs on the bus that would, so a viewer opened then would see no robot.
``RestView`` publishes, every ``REST_PERIOD_S`` while the cell is not busy, what the drives last
reported: ``/axis/<joint>/actual`` (position and statusword, no plan), ``/joint_states``, ``/tf``
(the links by ``LinkTransforms``), and every ``DESCRIPTION_PERIOD_S`` the URDF on
``/robot_description``, encoded by the recorder's own functions. Nothing is sent on the bus.

Time stamps stay on the bus's clock, as the recorder's: the latest time stamp of a frame the master
received, and on the wall clock (no lockstep) that plus the wall time since it arrived; with SYNC in
lockstep the bus's time stands still between motions, and so do the stamps.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import can
import numpy as np

from pvtflow.axes.drive.cia402 import decode_state
from pvtflow.service.link_transforms import LinkTransforms
from pvtflow.service.recording.channels import (
    ACTUAL_SCHEMA,
    FRAME_TRANSFORMS_SCHEMA,
    JOINT_STATE_SCHEMA,
    ROBOT_DESCRIPTION_SCHEMA,
    encode_actual,
    encode_joint_states,
    encode_transforms,
)

if TYPE_CHECKING:
    from pvtflow.axes.master.bus.cell_bus import CellBus
    from pvtflow.axes.master.group.axis_group import AxisGroup
    from pvtflow.service.config import CellConfig
    from pvtflow.service.live import LiveServer

log = logging.getLogger("pvtflow.live")

REST_PERIOD_S = 0.1  # the cell's state at rest, 10 per second
DESCRIPTION_PERIOD_S = 1.0  # the URDF again, for a viewer that connected since


class RestView:
    """``RestView(live, cell, bus, group, busy).start()`` ... ``stop()``; ``busy()``: a motion or a
    homing runs (its recorder publishes then)."""

    def __init__(
        self, live: LiveServer, cell: CellConfig, bus: CellBus, group: AxisGroup, busy: Callable[[], bool]
    ) -> None:
        self.live, self.cell, self.bus, self.group, self.busy = live, cell, bus, group, busy
        self.joints = tuple(a.joint for a in cell.ordered_axes())
        self._joints_json = json.dumps(list(self.joints))
        self._scaling = [a.scaling for a in cell.ordered_axes()]
        self._links = LinkTransforms(cell.model, self.joints)
        self._urdf = json.dumps({"data": cell.urdf.read_text()}).encode()
        self._heard: tuple[float, float] | None = None  # the last received frame's bus time, wall time then
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pvtflow-live-rest", daemon=True)
        self.published = 0

    def start(self) -> RestView:
        self.bus.recorder.taps.append(self._on_frame)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        if self._on_frame in self.bus.recorder.taps:
            self.bus.recorder.taps.remove(self._on_frame)

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_rx:
            self._heard = (msg.timestamp, time.monotonic())

    def clock_s(self) -> float:
        heard = self._heard
        if heard is None:
            return 0.0
        return heard[0] if self.bus.sync.clock.lockstep else heard[0] + time.monotonic() - heard[1]

    def _run(self) -> None:
        next_description = 0.0
        while not self._stop.wait(REST_PERIOD_S):
            if self.busy():
                continue
            try:
                now = time.monotonic()
                self.publish(describe=now >= next_description)
                if now >= next_description:
                    next_description = now + DESCRIPTION_PERIOD_S
            except Exception:  # the live view must never take the service down
                log.exception("live view at rest")

    def publish(self, describe: bool = False) -> None:
        """One sample of the cell at rest on the live channels."""
        stamp = self.clock_s()
        ns = max(0, round(stamp * 1e9))
        live = self.live
        if describe:
            live.log("/robot_description", ROBOT_DESCRIPTION_SCHEMA, ns, self._urdf)
        links = self.group.links
        counts = [lk.position for lk in links]
        words = [lk.statusword for lk in links]
        statuses = [lk.status_sync for lk in links]
        sync = self.bus.sync.count
        positions: list[float | None] = []
        for i, joint in enumerate(self.joints):
            qc = counts[i]
            position = None if qc is None else float(self._scaling[i].qc_to_position(qc))
            positions.append(position)
            state = decode_state(words[i]).value
            data = encode_actual(sync, None, qc, position, None, None, words[i], state, statuses[i])
            live.log(f"/axis/{joint}/actual", ACTUAL_SCHEMA, ns, data)
        live.log("/joint_states", JOINT_STATE_SCHEMA, ns, encode_joint_states(stamp, self._joints_json, positions))
        if None not in positions:
            translations, rotations = self._links.compute(np.array([positions], dtype=float))
            data = encode_transforms(stamp, self._links.frames, translations[0], rotations[0])
            live.log("/tf", FRAME_TRANSFORMS_SCHEMA, ns, data)
        self.published += 1
