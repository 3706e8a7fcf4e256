"""The master's watch over the bus: the drives' heartbeats, NMT states and EMCY, lost SYNC, the wire.

One thread watches (``BusWatch.start``): heartbeat loss (no heartbeat for ``heartbeat_ms *
heartbeat_timeout_factor``), lost SYNC (no answered SYNC for ``lost_sync_timeout_s``), error frames
(``BUS_WARNING``, at most once a second) and the master's controller state, from the error frames
that announce it and python-can's ``bus.state`` (error-warning, error-passive: ``BUS_WARNING``;
bus-off: ``BUS_OFF``, nothing can be sent). A node's NMT state change and its EMCY
frames are reported as they arrive (the CAN ones in their words: 0x8110, 0x8120, 0x8140). The
watchdog polls: wall-clock time is used only to *detect* a failure, never to pace the motion.
It also remembers the boot-up messages each node sent: a drive that boots again has lost what it
knew (its homing, its configuration).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING

import can
from canopen.emcy import EmcyError

from pvtflow.axes.canbus.can_errors import FROM_BUS_STATE, ControllerState
from pvtflow.axes.drive.objects import CAN_EMCY_WORDS, NMT_STATE_OPERATIONAL, node_of_cob_id
from pvtflow.axes.master.bus.faults import BusFault, ErrorFrames, FaultCallback, FaultKind

if TYPE_CHECKING:
    from pvtflow.axes.drive.config import BusConfig
    from pvtflow.axes.master.bus.network import LoggingNetwork
    from pvtflow.axes.master.bus.sync import SyncClock

NMT_STATE_BOOT_UP = 0  # the boot-up message: a heartbeat frame with state 0
ERROR_FRAME_REPORT_S = 1.0  # error frames are reported at most this often (with the count since the last report)


class BusWatch:
    """The heartbeat, NMT and EMCY consumers of one ``CellBus`` and the thread that watches it."""

    def __init__(
        self,
        config: BusConfig,
        network: LoggingNetwork,
        report: FaultCallback,
        sync: SyncClock,
        lost_sync_timeout_s: float,
    ) -> None:
        # what the watch needs of the bus, handed in: it reports through ``report`` (``CellBus.report``)
        self.config = config
        self.network = network
        self.report = report
        self.sync = sync
        self.lost_sync_timeout_s = lost_sync_timeout_s
        self.errors = ErrorFrames()
        self.state = ControllerState.ERROR_ACTIVE  # the master's controller as last reported
        self._polled = ControllerState.ERROR_ACTIVE  # python-can's ``bus.state`` as last read
        self._heartbeat_seen: dict[int, float] = {}
        self._heartbeat_state: dict[int, int] = {}
        self._boots: dict[int, int] = {}  # boot-up messages seen per node (NMT reset, power-on)
        self._watched: set[int] = set()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self.watch_sync = False
        self._sync_reported = False

    def start(self) -> None:
        self._closing.clear()
        self._thread = threading.Thread(target=self._run, name="pvtflow-watchdog", daemon=True)
        self._thread.start()

    @property
    def thread(self) -> threading.Thread | None:
        """The thread that runs this (None: not started); ``CellBus.threads``."""
        return self._thread

    def stop(self) -> None:
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def watch_heartbeat(self, node_ids: Iterable[int]) -> None:
        """Start checking the heartbeats of these nodes (after their 0x1017 has been written)."""
        now = time.monotonic()
        with self._lock:
            for nid in node_ids:
                self._heartbeat_seen.setdefault(nid, now)
                self._watched.add(nid)

    def unwatch_heartbeat(self) -> None:
        with self._lock:
            self._watched.clear()

    def heartbeat_state(self, node_id: int) -> int | None:
        return self._heartbeat_state.get(node_id)

    def boot_count(self, node_id: int) -> int:
        """How many boot-up messages this node has sent since the bus opened: a drive that boots again
        (reset, power loss) has lost what it knew (its homing, its configuration)."""
        return self._boots.get(node_id, 0)

    def on_heartbeat(self, node_id: int, state: int) -> None:
        if state == NMT_STATE_BOOT_UP:
            self._boots[node_id] = self._boots.get(node_id, 0) + 1
        previous = self._heartbeat_state.get(node_id)
        self._heartbeat_seen[node_id] = time.monotonic()
        self._heartbeat_state[node_id] = state
        if node_id in self._watched and previous == NMT_STATE_OPERATIONAL and state != NMT_STATE_OPERATIONAL:
            self.report(BusFault(FaultKind.NMT, node_id, f"node {node_id} left OPERATIONAL (NMT state {state})"))

    def on_emcy(self, node_id: int, err: EmcyError) -> None:
        if err.code == 0:
            return  # error reset / no error
        words = CAN_EMCY_WORDS.get(err.code) or err.get_desc()
        text = f"EMCY 0x{err.code:04X} from node {node_id}: {words}".rstrip(": ")
        self.report(BusFault(FaultKind.EMCY, node_id, text, err.code))

    def _run(self) -> None:
        timeout = self.config.heartbeat_ms * self.config.heartbeat_timeout_factor / 1000.0
        poll = max(0.005, min(self.config.heartbeat_ms / 4000.0, self.lost_sync_timeout_s / 4))
        while not self._closing.wait(poll):
            now = time.monotonic()
            lost = []
            with self._lock:
                for nid in list(self._watched):
                    if now - self._heartbeat_seen.get(nid, now) > timeout:
                        lost.append(nid)
                        self._watched.discard(nid)
            for nid in lost:
                self.report(
                    BusFault(
                        FaultKind.HEARTBEAT,
                        nid,
                        f"no heartbeat from node {nid} for "
                        f"{now - self._heartbeat_seen[nid]:.3f} s (timeout {timeout:.3f} s)",
                    )
                )
            self._watch_wire(now)
            stalled = now - self.sync.last_progress > self.lost_sync_timeout_s
            if self.watch_sync and self.sync.running and not self._sync_reported and stalled:
                nodes = sorted({node_of_cob_id(cob) for cob in self.sync.behind()})
                self._sync_reported = True
                self.report(
                    BusFault(
                        FaultKind.LOST_SYNC,
                        nodes[0] if nodes else None,
                        f"SYNC {self.sync.count} not answered by node(s) {nodes} within "
                        f"{self.lost_sync_timeout_s:.3f} s",
                    )
                )

    def arm_sync_watch(self) -> None:
        self._sync_reported = False
        self.sync.progressed()
        self.watch_sync = True

    def disarm_sync_watch(self) -> None:
        """SYNC stops on purpose (a run or a homing ended): its silence is no fault."""
        self.watch_sync = False

    def _watch_wire(self, now: float) -> None:
        """Error frames (counted as they come, reported at most every ERROR_FRAME_REPORT_S) and the
        master's controller state, reported by name at every change: from the error frames that
        announce it (``axes.canbus.can_errors``; socketcan's only source: its python-can ``bus.state`` stays
        ACTIVE) and from python-can's ``bus.state`` where the interface reports one (pcan, simwire)."""
        frames = self.errors.take(now, ERROR_FRAME_REPORT_S)
        if frames:
            self.report(
                BusFault(
                    FaultKind.BUS_WARNING,
                    None,
                    f"{frames} CAN error frame(s) in the last {ERROR_FRAME_REPORT_S:g} s ({self.errors.count} in all)",
                    frames,
                )
            )
        for frame in self.errors.changes():
            assert frame.state is not None
            self._enter(frame.state, frame.counters())
        bus = self.network.bus
        if bus is None:
            return
        try:
            polled = FROM_BUS_STATE.get(bus.state, ControllerState.ERROR_ACTIVE)
        except (can.CanError, NotImplementedError, OSError):
            return
        if polled != self._polled:  # a change the interface reports (its error frame may have said so already)
            self._polled = polled
            self._enter(polled)

    def _enter(self, state: ControllerState, counters: str = "") -> None:
        """The master's controller is now in ``state``: reported when it changed. Bus-off halts the
        motion (``FaultKind.BUS_OFF``); the other states are warnings: the controller still sends."""
        if state == self.state:
            return
        previous, self.state = self.state, state
        said = f"the master's CAN controller is {state}{counters}"
        if state is ControllerState.BUS_OFF:
            self.report(
                BusFault(
                    FaultKind.BUS_OFF,
                    None,
                    f"{said}: it can send nothing (no SYNC, no quick stop); the drives stop on the master's "
                    "heartbeat loss",
                )
            )
        elif state is ControllerState.ERROR_PASSIVE:
            self.report(BusFault(FaultKind.BUS_WARNING, None, f"{said} (an error counter at 128 or more)"))
        elif state is ControllerState.ERROR_WARNING:
            self.report(BusFault(FaultKind.BUS_WARNING, None, f"{said} (an error counter at 96 or more)"))
        else:
            self.report(BusFault(FaultKind.BUS_WARNING, None, f"{said} again (was {previous})"))
