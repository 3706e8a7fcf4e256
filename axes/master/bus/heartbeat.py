"""The master's own CiA 301 heartbeat, which every drive watches (0x1016) to stop when the master is lost.

A beat must mean that the master still supervises the cell, so that a hung master falls silent as
a dead one does: the beats are judged on the bus machinery's progress (``MasterHeartbeat``), not
sent by a free-running timer. Started and stopped by ``CellBus.open`` / ``close``.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING

import can

from pvtflow.axes.drive import objects as od

if TYPE_CHECKING:
    import canopen

    from pvtflow.axes.drive.config import BusConfig
    from pvtflow.axes.master.bus.network import LoggingNetwork
    from pvtflow.axes.master.bus.sync import SyncClock
    from pvtflow.axes.master.bus.watch import BusWatch

log = logging.getLogger("pvtflow.bus")
WHERE_FRAMES = 4  # of a silent receive thread's stack, innermost first, in the reason a beat is withheld


class _ReceiveStamp(can.Listener):
    """Notes when the bus's receive thread last dispatched a frame (one assignment per frame), and
    which thread that is: a silent one is asked where it stands (``where``)."""

    def __init__(self) -> None:
        self.at = time.monotonic()
        self.thread_id: int | None = None

    def on_message_received(self, msg: can.Message) -> None:
        self.at = time.monotonic()
        self.thread_id = threading.get_ident()

    def where(self) -> str:
        """Where the receive thread stands now (its innermost frames), or why that is not known."""
        frame = sys._current_frames().get(self.thread_id) if self.thread_id is not None else None
        if frame is None:
            return "the receive thread is gone" if self.thread_id is not None else "no frame dispatched yet"
        stack = traceback.extract_stack(frame)[-WHERE_FRAMES:]
        return "; ".join(f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in reversed(stack))


class MasterHeartbeat:
    """The master's own CiA 301 heartbeat: 0x700 + ``master_node_id``, one byte 0x05 (OPERATIONAL),
    every ``master_heartbeat_ms``. Every drive watches it (0x1016) and stops when it stops (0x6007).

    A beat says that the master still supervises the cell, not merely that this thread runs: it goes
    out only while the bus machinery makes progress. (1) Whenever drives' heartbeats are due (the
    master has heard one), the receive thread dispatched a frame within ``stall_s``: a receive thread
    blocked in a callback, or on the SYNC clock's lock, dispatches nothing. (2) With SYNC on the wall
    clock and running, the SYNC count moved within ``stall_s``: a producer blocked, or its lock held,
    sends none. In lockstep a SYNC that waits for a drive's answer is no hang (``lost_sync`` deals
    with it), and a held lock stops the receive thread, so (2) is for real time only. ``stall_s`` is
    the window the master gives the drives' heartbeats (``heartbeat_ms x heartbeat_timeout_factor``):
    the master beats only while it would notice a drive falling silent. A dead process beats no more
    because its threads are gone (the thread is a daemon); a whole process stopped (SIGSTOP, a GIL
    held for good) stops this thread too.
    """

    def __init__(
        self,
        config: BusConfig,
        network: LoggingNetwork,
        watch: BusWatch,
        nodes: dict[int, canopen.RemoteNode],
        sync: SyncClock,
    ) -> None:
        # what the beat needs of the bus, handed in: ``nodes`` is the bus's own map (nodes added later count)
        self.network = network
        self.watch = watch
        self.nodes = nodes
        self.sync = sync
        self.node_id = config.master_node_id
        self.cob_id = od.HEARTBEAT_COB_ID_BASE + config.master_node_id
        self.period_s = config.master_heartbeat_ms / 1000.0
        self.stall_s = config.heartbeat_ms * config.heartbeat_timeout_factor / 1000.0
        self.beats = 0
        self.last_beat: float | None = None  # time.monotonic() of the last beat sent
        self.withheld: str | None = None  # why the last beat was not sent (None: it was)
        self._received = _ReceiveStamp()
        self._sync_count = -1
        self._sync_moved = time.monotonic()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Beat from now on (the bus is open: its notifier exists)."""
        if self._thread is not None:
            return
        self._received.at = time.monotonic()
        notifier = self.network.notifier
        if notifier is not None:
            notifier.add_listener(self._received)
        self._stopping.clear()
        self._thread = threading.Thread(target=self._run, name="pvtflow-master-heartbeat", daemon=True)
        self._thread.start()

    @property
    def thread(self) -> threading.Thread | None:
        """The thread that runs this (None: not started); ``CellBus.threads``."""
        return self._thread

    def stop(self) -> None:
        """No beat after this returns."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout=self.period_s + 1.0)
            self._thread = None
        notifier = self.network.notifier
        if notifier is not None and self._received in notifier.listeners:
            notifier.remove_listener(self._received)

    @property
    def running(self) -> bool:
        return self._thread is not None

    def stalled(self, now: float) -> str | None:
        """Why the bus machinery shows no progress (None: it does), by the two rules of the class."""
        heard = any(self.watch.heartbeat_state(n) is not None for n in list(self.nodes))
        silent = now - self._received.at
        if heard and silent > self.stall_s:
            return f"the receive thread has dispatched no frame for {silent:.3f} s (at {self._received.where()})"
        sync = self.sync
        if sync.clock.lockstep or not sync.running:
            self._sync_count = -1
            return None
        count = sync.count  # read without the lock: a held lock is what this looks for
        if count != self._sync_count:
            self._sync_count, self._sync_moved = count, now
        elif now - self._sync_moved > self.stall_s:
            return f"SYNC {count} has been the last for {now - self._sync_moved:.3f} s"
        return None

    def _run(self) -> None:
        deadline = time.monotonic()
        withheld = 0
        while not self._stopping.is_set():
            now = time.monotonic()
            why = self.stalled(now)
            if why is None:
                try:
                    self.network.send_message(self.cob_id, bytes([od.NMT_STATE_OPERATIONAL]))
                except (can.CanError, OSError, RuntimeError) as exc:
                    why = f"the heartbeat cannot be sent: {exc}"
                else:
                    self.beats += 1
                    self.last_beat = now
            if (why is None) != (self.withheld is None):  # log the changes, not every withheld beat
                if why is not None:
                    log.warning("master heartbeat (node %d) withheld: %s", self.node_id, why)
                else:
                    log.warning("master heartbeat (node %d) resumed after %d beats withheld", self.node_id, withheld)
            withheld = 0 if why is None else withheld + 1
            self.withheld = why
            deadline += self.period_s
            delay = deadline - time.monotonic()
            if delay < 0:  # this thread was held up: beat on from now, not in a burst of late beats
                deadline, delay = time.monotonic(), 0.0
            self._stopping.wait(delay)
