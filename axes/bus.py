"""The cell's CAN bus as the master sees it: python-can bus, canopen Network, NMT, SYNC, consumers, log.

SYNC has two modes (``CellBus(lockstep=...)``):

- real time: SYNC every ``sync_period_ms`` of wall-clock time. Without a time stamp or a traffic log
  it is canopen's ``network.sync.start(period)`` (python-can periodic send; the kernel's broadcast
  manager on socketcan, lowest jitter). With them, or with frames that must follow every SYNC (a
  fixed-period drive's setpoints: ``add_sender``), a master thread sends SYNC on absolute deadlines
  followed by the 0x1013 time stamp and those frames, so a setpoint is on the bus a whole period
  before the SYNC that validates it whatever the process does meanwhile, and all appear in the log.
- lockstep (simulation): the next SYNC goes out once every drive has answered the previous one with
  its synchronous TPDO and the SYNC listeners (the feeders) have run. Drive time advances one period
  per SYNC, so a simulated cell runs as fast as the bus and the CPU allow, and nothing depends on a
  sleep. The same answer counting runs in real time and gives the SYNC count there too.

Failures are watched by one thread: heartbeat loss (no heartbeat for ``heartbeat_ms *
heartbeat_timeout_factor``), lost SYNC (no answered SYNC for ``lost_sync_timeout_s``), NMT state
change of a node. EMCY frames are reported as they arrive. The watchdog polls: wall-clock time is
used only to *detect* a failure, never to pace the motion.

The master has a heartbeat of its own (``axes/heartbeat.py``), started and stopped with the bus,
that every drive watches (0x1016) and stops on when it stops (0x6007).
"""

from __future__ import annotations

import logging
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import can
import canopen
from canopen.emcy import EmcyError
from canopen.objectdictionary import ObjectDictionary

from axes.config import BusConfig
from axes.heartbeat import MasterHeartbeat
from axes.objects import NMT_STATE_OPERATIONAL, TIME_STAMP_COB_ID

SYNC_COB_ID = 0x80
# How long the master waits for one SDO answer. python-canopen's 0.3 s is tight for a simulated cell
# on a loaded 2-core host (a drive's thread may not run for that long); a real drive answers within
# milliseconds, so a longer wait only delays the report of a drive that is really gone.
SDO_RESPONSE_TIMEOUT_S = 1.0
NMT_OPERATIONAL = 0x01
NMT_STOPPED = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_COMMUNICATION = 0x82
NMT_STATE_PRE_OPERATIONAL = 127
NMT_STATE_BOOT_UP = 0  # the boot-up message: a heartbeat frame with state 0
SWITCH_INTERVAL_S = 0.0005  # the interpreter hands the GIL on at least this often while a bus is open

log = logging.getLogger("pvtflow.bus")


class BusError(RuntimeError):
    """The bus cannot be opened or a frame cannot be sent (one clear line for the user)."""


class FaultKind(StrEnum):
    """What the bus saw fail."""

    EMCY = "emcy"  # a node sent an emergency
    HEARTBEAT = "heartbeat"  # a node's heartbeat stopped
    NMT = "nmt"  # a node left OPERATIONAL (or booted)
    LOST_SYNC = "lost_sync"  # a node stopped answering SYNC


@dataclass(frozen=True)
class BusFault:
    """A failure seen on the bus."""

    kind: FaultKind
    node_id: int | None
    message: str
    code: int = 0


FaultCallback = Callable[[BusFault], None]
SyncCallback = Callable[[int], None]


class FrameRecorder(can.Listener):
    """Counts every frame (sent and received) and, with a log file, writes it through can.Logger."""

    def __init__(self, path: str | Path | None = None) -> None:
        self._lock = threading.Lock()
        self._logger: can.Listener | None = can.Logger(str(path)) if path is not None else None
        # BLF and ASC store a channel NUMBER (python-can takes the name's trailing digits): a
        # name like "cell-20260401" would not fit, and one cell is one bus anyway
        self._numbered = path is not None and Path(path).suffix.lower() in (".blf", ".asc")
        self.frames = 0
        self.frames_sent = 0
        self.taps: list[Callable[[can.Message], None]] = []  # see every frame (benchmarks, monitors)

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self.frames += 1
            if self._logger is not None:
                self._logger.on_message_received(self._for_log(msg))
            for tap in self.taps:
                tap(msg)

    def _for_log(self, msg: can.Message) -> can.Message:
        if not self._numbered:
            return msg
        number = can.util.channel2int(msg.channel)
        if number is not None and 0 <= number < 0xFFFF:
            return msg
        return can.Message(
            timestamp=msg.timestamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            dlc=msg.dlc,
            data=msg.data,
            is_rx=msg.is_rx,
            channel=0,
        )

    def on_message_sent(self, msg: can.Message) -> None:
        with self._lock:
            self.frames_sent += 1
        self.on_message_received(msg)

    def stop(self) -> None:
        with self._lock:
            if self._logger is not None:
                self._logger.stop()
                self._logger = None


class RecordingNetwork(canopen.Network):
    """A canopen Network whose own frames go to the recorder too (a bus does not hear itself)."""

    def __init__(self, bus: can.BusABC | None = None, recorder: FrameRecorder | None = None) -> None:
        super().__init__(bus)
        self.recorder = recorder
        self.channel_name: str | None = None  # written into the log with the frames we send

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        msg = can.Message(
            is_extended_id=can_id > 0x7FF,
            arbitration_id=can_id,
            data=data,
            is_remote_frame=remote,
            is_rx=False,
            channel=self.channel_name,
        )
        with self.send_lock:
            msg.timestamp = time.time()
            self.bus.send(msg)
        if self.recorder is not None:
            self.recorder.on_message_sent(msg)


class SyncClock:
    """SYNC producer and counter of the drives' answers (see the module docstring for the modes).

    ``count`` is the number of SYNCs sent, ``answered`` the number every expected node has answered.
    Listeners get the number of the SYNC just answered; in lockstep they run before the next SYNC.
    """

    def __init__(self, bus: CellBus, period_ms: float, lockstep: bool, time_stamp_cob_id: int | None = None):
        self.bus = bus
        self.period_ms = period_ms
        self.lockstep = lockstep
        self.time_stamp_cob_id = time_stamp_cob_id
        self.count = 0
        self.answered = 0
        self.last_progress = time.monotonic()
        self._answers: dict[int, int] = {}  # cob id -> SYNCs answered
        self._listeners: list[SyncCallback] = []
        self._senders: list[SyncCallback] = []  # run right after each SYNC goes out, by whoever sends it
        self.lock = threading.RLock()  # held while SYNC listeners run and while a SYNC goes out
        self._answered_changed = threading.Condition(self.lock)
        self.last_sent = time.monotonic()  # when the last SYNC went out
        self._running = False
        self._production = 0  # which start() the producing thread serves: a stale one stops by itself
        self._periodic = False
        self._t0_us = time.monotonic_ns() // 1000

    # --- answers ---------------------------------------------------------------------------------
    def expect(self, cob_ids: Iterable[int]) -> None:
        """The synchronous TPDOs that answer every SYNC (one per drive). Call it after the links have
        subscribed their TPDO decoders: an answer is then decoded before it is counted, so whoever
        waits for a SYNC's answers (``wait_answered``) reads what the drives said on it."""
        with self.lock:
            for cob in self._answers:
                self.bus.network.unsubscribe(cob, self._on_answer)
            self._answers = {cob: self.count for cob in cob_ids}
            self.answered = self.count
            for cob in self._answers:
                self.bus.network.subscribe(cob, self._on_answer)

    def add_listener(self, callback: SyncCallback) -> None:
        self._listeners.append(callback)

    def remove_listener(self, callback: SyncCallback) -> None:
        if callback in self._listeners:
            self._listeners.remove(callback)

    def add_sender(self, callback: SyncCallback) -> None:
        """``callback(n)`` right after SYNC number ``n`` is on the bus, in the thread that sent it and
        before the next SYNC can go out: what must be on the bus before SYNC n + 1 (a fixed-period
        drive's next setpoint) is sent there, never paced by the drives' answers, so the wall clock
        cannot make it late. Keep it to sending precomputed frames."""
        with self.lock:
            self._senders.append(callback)

    def remove_sender(self, callback: SyncCallback) -> None:
        with self.lock:
            if callback in self._senders:
                self._senders.remove(callback)

    def behind(self) -> list[int]:
        """COB-IDs of the answers still missing for the last SYNC sent."""
        with self.lock:
            return [cob for cob, n in self._answers.items() if n < self.count]

    def _on_answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            n = self._answers.get(can_id)
            if n is None or (self.lockstep and n >= self.count):
                return  # an answer without a SYNC (or a duplicate): nothing to count
            self._answers[can_id] = n + 1
            self._answered_changed.notify_all()
            done = min(self._answers.values())
            if done <= self.answered:
                return
            self.answered = done
            self.count = max(self.count, done)  # real time: the periodic task does not report its SYNCs
            self.last_progress = time.monotonic()
            for cb in list(self._listeners):
                cb(done)
            if self.lockstep and self._running and self.answered == self.count:
                self._transmit()

    # --- production ------------------------------------------------------------------------------
    def _transmit(self) -> None:
        with self.lock:
            self.count += 1
            self.last_sent = time.monotonic()
            self.bus.network.send_message(SYNC_COB_ID, b"")
            if self.time_stamp_cob_id is not None:
                stamp = (time.monotonic_ns() // 1000 - self._t0_us) & 0xFFFFFFFF
                self.bus.network.send_message(self.time_stamp_cob_id, struct.pack("<I", stamp))
            for send in self._senders:
                send(self.count)

    def start(self) -> None:
        """Send the first SYNC now and keep producing (lockstep: on answers; real time: periodic)."""
        with self.lock:
            if self._running:
                return
            self._running = True
            self.last_progress = time.monotonic()
            if self.lockstep:
                self._transmit()
                if not self._answers:  # nobody to wait for: a single SYNC
                    self._running = False
                return
        if (
            self.time_stamp_cob_id is None
            and not self._senders
            and not self.bus.recorder.taps
            and self.bus.can_log is None
        ):
            self._periodic = True
            with self.lock:
                self.count += 1  # the periodic task sends its first SYNC at once
            self.bus.network.sync.start(self.period_ms / 1000.0)
            target = self._count_periodic
        else:
            target = self._produce
        name = "pvtflow-sync-count" if self._periodic else "pvtflow-sync"
        threading.Thread(target=target, args=(self._production,), name=name, daemon=True).start()

    def _producing(self, production: int) -> bool:
        """Still the production this thread was started for (called with the lock held)."""
        return self._running and self._production == production

    def _produce(self, production: int) -> None:
        period = self.period_ms / 1000.0
        deadline = time.monotonic()
        while True:
            with self.lock:  # never a SYNC after stop(): it is judged under the lock stop() takes
                if not self._producing(production):
                    return
                self._transmit()
            deadline += period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def _count_periodic(self, production: int) -> None:
        # the periodic task does not tell us when it sends: count by wall clock for bookkeeping only
        t0 = time.monotonic()
        period = self.period_ms / 1000.0
        while True:
            time.sleep(period)
            with self.lock:
                if not self._producing(production):
                    return
                self.count = max(self.count, 1 + int((time.monotonic() - t0) / period))

    def step(self) -> dict[int, int]:
        """Send one SYNC by hand, outside production (e.g. the start's check: every drive answers it
        with its synchronous TPDO); what each drive's answer count will be once it has answered,
        for ``wait_answered`` (in real time ``count`` is a wall-clock estimate, not a SYNC's number)."""
        with self.lock:
            owed = {cob: n + 1 for cob, n in self._answers.items()}
            self._transmit()
            return owed

    def wait_answered(self, owed: dict[int, int], timeout_s: float) -> list[int]:
        """Wait until every drive has answered the SYNC ``step`` sent; the COB-IDs of the answers
        still missing then (empty: every drive answered in time)."""

        def missing() -> list[int]:
            return [cob for cob, n in owed.items() if self._answers.get(cob, 0) < n]

        with self.lock:
            self._answered_changed.wait_for(lambda: not missing(), timeout_s)
            return missing()

    def keep_period(self) -> None:
        """Real time: wait until one period after the last SYNC sent, so that the next one (``start``)
        keeps the cell's SYNC period after a SYNC sent by hand. Lockstep: nothing to wait for."""
        if not self.lockstep:
            delay = self.last_sent + self.period_ms / 1000.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def stop(self) -> None:
        """No SYNC after this returns. The producing thread is not joined: stop() is called from SYNC
        listeners, which hold the lock that thread needs to see it must end (joining there blocked
        the bus's receive thread, and every SDO answer with it, for the join's whole timeout)."""
        with self.lock:
            self._running = False
            self._production += 1
            if self._periodic:
                self.bus.network.sync.stop()
                self._periodic = False

    @property
    def running(self) -> bool:
        return self._running


class CellBus:
    """python-can bus + canopen Network of one cell, with NMT, SYNC, heartbeat and EMCY consumers."""

    def __init__(
        self,
        config: BusConfig,
        *,
        lockstep: bool = True,
        can_log: str | Path | None = None,
        lost_sync_timeout_s: float = 1.0,
        time_stamp: bool | None = None,
    ) -> None:
        self.config = config
        self.can_log = can_log
        self.recorder = FrameRecorder(can_log)
        self.network = RecordingNetwork(recorder=self.recorder)
        self.network.channel_name = config.channel
        stamp = config.time_stamp if time_stamp is None else time_stamp
        self.sync = SyncClock(self, config.sync_period_ms, lockstep, TIME_STAMP_COB_ID if stamp else None)
        self.lost_sync_timeout_s = lost_sync_timeout_s
        self.nodes: dict[int, canopen.RemoteNode] = {}
        self._fault_callbacks: list[FaultCallback] = []
        self._heartbeat_seen: dict[int, float] = {}
        self._heartbeat_state: dict[int, int] = {}
        self._boots: dict[int, int] = {}  # boot-up messages seen per node (NMT reset, power-on)
        self._watched: set[int] = set()
        self._lock = threading.Lock()
        self._watchdog: threading.Thread | None = None
        self._closing = threading.Event()
        self.watch_sync = False
        self._sync_reported = False
        self.master_heartbeat = MasterHeartbeat(self)

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> CellBus:
        # The bus is served by threads (SYNC answers, feeders, consumers; in a simulation the drives
        # too) that must get the GIL within a fraction of a SYNC period, not after CPython's 5 ms
        # switch interval: a process with a bus open keeps it at SWITCH_INTERVAL_S (not restored on
        # close: other buses of the process may still be open).
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        kwargs: dict[str, object] = {"interface": self.config.interface, "channel": self.config.channel}
        if self.config.interface != "virtual":
            kwargs["bitrate"] = self.config.bitrate
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            where = f"{self.config.interface}:{self.config.channel}"
            raise BusError(f"cannot open CAN bus {where}: {exc}") from None
        self.network.bus = bus
        self.network.notifier = can.Notifier(bus, [*self.network.listeners, self.recorder], 0.1)
        self._closing.clear()
        self._watchdog = threading.Thread(target=self._watch, name="pvtflow-watchdog", daemon=True)
        self._watchdog.start()
        self.master_heartbeat.start()
        return self

    @property
    def is_open(self) -> bool:
        return self.network.bus is not None

    def close(self) -> None:
        self.sync.stop()
        self.master_heartbeat.stop()
        self._closing.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=2.0)
            self._watchdog = None
        if self.network.bus is not None:
            self.network.disconnect()
        self.recorder.stop()

    def __enter__(self) -> CellBus:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- nodes -----------------------------------------------------------------------------------
    def add_node(self, node_id: int) -> canopen.RemoteNode:
        """A remote node with an empty dictionary: pvtflow addresses objects by index, so the master
        does not need the drive's EDS (any EPOS2, Parker or simulated node will do)."""
        if node_id in self.nodes:
            return self.nodes[node_id]
        node = canopen.RemoteNode(node_id, ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = SDO_RESPONSE_TIMEOUT_S
        self.network.add_node(node)
        node.nmt.add_heartbeat_callback(lambda state, nid=node_id: self._on_heartbeat(nid, state))
        node.emcy.add_callback(lambda err, nid=node_id: self._on_emcy(nid, err))
        self.nodes[node_id] = node
        return node

    def on_fault(self, callback: FaultCallback) -> None:
        self._fault_callbacks.append(callback)

    def remove_fault_callback(self, callback: FaultCallback) -> None:
        if callback in self._fault_callbacks:
            self._fault_callbacks.remove(callback)

    def _report(self, fault: BusFault) -> None:
        """Every callback hears of the fault; one that fails (a halt on a bus that has gone away)
        is logged, and neither stops the others nor the thread that reports (the watchdog)."""
        for cb in list(self._fault_callbacks):
            try:
                cb(fault)
            except (can.CanError, OSError, RuntimeError) as exc:
                log.error("reporting %s of node %s failed: %s", fault.kind, fault.node_id, exc)

    # --- NMT -------------------------------------------------------------------------------------
    def nmt_broadcast(self, command: int) -> None:
        self.network.send_message(0, bytes([command, 0]))

    def nmt(self, node_id: int, command: int) -> None:
        self.network.send_message(0, bytes([command, node_id]))

    # --- heartbeat / EMCY consumers --------------------------------------------------------------
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

    def _on_heartbeat(self, node_id: int, state: int) -> None:
        if state == NMT_STATE_BOOT_UP:
            self._boots[node_id] = self._boots.get(node_id, 0) + 1
        previous = self._heartbeat_state.get(node_id)
        self._heartbeat_seen[node_id] = time.monotonic()
        self._heartbeat_state[node_id] = state
        if node_id in self._watched and previous == NMT_STATE_OPERATIONAL and state != NMT_STATE_OPERATIONAL:
            self._report(BusFault(FaultKind.NMT, node_id, f"node {node_id} left OPERATIONAL (NMT state {state})"))

    def _on_emcy(self, node_id: int, err: EmcyError) -> None:
        if err.code == 0:
            return  # error reset / no error
        text = f"EMCY 0x{err.code:04X} from node {node_id}: {err.get_desc()}".rstrip(": ")
        self._report(BusFault(FaultKind.EMCY, node_id, text, err.code))

    def _watch(self) -> None:
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
                self._report(
                    BusFault(
                        FaultKind.HEARTBEAT,
                        nid,
                        f"no heartbeat from node {nid} for "
                        f"{now - self._heartbeat_seen[nid]:.3f} s (timeout {timeout:.3f} s)",
                    )
                )
            stalled = now - self.sync.last_progress > self.lost_sync_timeout_s
            if self.watch_sync and self.sync.running and not self._sync_reported and stalled:
                nodes = sorted({cob & 0x7F for cob in self.sync.behind()})
                self._sync_reported = True
                self._report(
                    BusFault(
                        FaultKind.LOST_SYNC,
                        nodes[0] if nodes else None,
                        f"SYNC {self.sync.count} not answered by node(s) {nodes} within "
                        f"{self.lost_sync_timeout_s:.3f} s",
                    )
                )

    def arm_sync_watch(self) -> None:
        self._sync_reported = False
        self.sync.last_progress = time.monotonic()
        self.watch_sync = True
