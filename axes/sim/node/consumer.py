"""The CiA 301 heartbeat consumer of a simulated drive (0x1016), on the wall clock.

A drive watches its master's heartbeat to stop by itself when the master is lost (0x6007 says
how). That must work when nothing else reaches the drive any more: no SYNC, no frame at all. So the
consumer has a thread of its own that sleeps until the earliest moment a watched heartbeat is due
and then judges it (the heartbeat producer, canopen's periodic task, is the drive's other
wall-clock part). CiA 301's rules: an entry (node id, time in ms) is inactive until the first
heartbeat of its node after it was configured; it fires when no heartbeat followed within its time,
once, and is inactive again until that node's next heartbeat.

The same thread can run the drive's motion clock on its own (``tick``): a simulated drive's clock
advances with SYNC, and a drive that reacts to a lost master brakes whether or not SYNC still comes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping

import canopen

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.clock import TICK_S  # one home: the drives' sampling step is the motion clock's step

LostCallback = Callable[[int, float], None]  # (node id, seconds since its last heartbeat)
TickCallback = Callable[[], bool]  # True: keep ticking


class HeartbeatConsumer:
    """Watches the heartbeats 0x1016 names; ``on_lost(node, silent_s)`` runs in this object's thread,
    never with its lock held, as does ``on_tick()`` every ``TICK_S`` while ticking is asked for."""

    def __init__(self, name: str, on_lost: LostCallback, on_tick: TickCallback) -> None:
        self.name = name
        self.on_lost = on_lost
        self.on_tick = on_tick
        self._cond = threading.Condition()
        self._times: dict[int, float] = {}  # watched node -> consumer time (s)
        self._heard: dict[int, float] = {}  # active entries: node -> time.monotonic() of its last heartbeat
        self._ticking = False
        self._stopping = False
        self._network: canopen.Network | None = None
        self._thread: threading.Thread | None = None
        self.last_heard: dict[int, float] = {}  # every node's last heartbeat (also of inactive entries)

    @property
    def watched(self) -> dict[int, float]:
        """Node id -> consumer time (s) of every configured entry."""
        with self._cond:
            return dict(self._times)

    def active(self, node_id: int) -> bool:
        """The entry of this node is armed: its first heartbeat came, and no silence fired since."""
        with self._cond:
            return node_id in self._heard

    # --- configuration ---------------------------------------------------------------------------
    def configure(self, entries: Mapping[int, int]) -> None:
        """0x1016 as it now is: node id -> time in ms (node 0 or time 0: an unused entry). An entry
        that changed is inactive until its node's next heartbeat."""
        times = {node: ms / 1000.0 for node, ms in entries.items() if node and ms}
        with self._cond:
            network = self._network
            if network is not None:
                for node in self._times.keys() - times.keys():
                    unsubscribe(network, od.HEARTBEAT_COB_ID_BASE + node, self._on_heartbeat)
                for node in times.keys() - self._times.keys():
                    subscribe(network, od.HEARTBEAT_COB_ID_BASE + node, self._on_heartbeat)
            for node in list(self._heard):
                if times.get(node) != self._times.get(node):
                    del self._heard[node]
            self._times = times
            self._cond.notify_all()

    def attach(self, network: canopen.Network) -> None:
        """Listen on this network and start the thread (the entries configured so far apply)."""
        with self._cond:
            self._network = network
            for node in self._times:
                subscribe(network, od.HEARTBEAT_COB_ID_BASE + node, self._on_heartbeat)
            self._stopping = False
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=f"sim-consumer-{self.name}", daemon=True)
                self._thread.start()

    def detach(self) -> None:
        """Stop listening and end the thread (call it without holding a lock ``on_lost`` takes)."""
        with self._cond:
            network, self._network = self._network, None
            if network is not None:
                for node in self._times:
                    unsubscribe(network, od.HEARTBEAT_COB_ID_BASE + node, self._on_heartbeat)
            self._heard.clear()
            self._ticking = False
            self._stopping = True
            self._cond.notify_all()
            thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def tick(self) -> None:
        """Run ``on_tick`` every ``TICK_S`` from now until it returns False."""
        with self._cond:
            self._ticking = True
            self._cond.notify_all()

    # --- the wall-clock part ---------------------------------------------------------------------
    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        node = can_id - od.HEARTBEAT_COB_ID_BASE
        now = time.monotonic()
        with self._cond:
            self.last_heard[node] = now
            if node in self._times:
                first = node not in self._heard
                self._heard[node] = now
                if first:  # the entry becomes active: the thread has a deadline to wait for
                    self._cond.notify_all()

    def _run(self) -> None:
        next_tick = 0.0
        while True:
            with self._cond:
                while True:
                    if self._stopping:
                        return
                    now = time.monotonic()
                    fired = [(n, now - t) for n, t in self._heard.items() if now - t >= self._times[n]]
                    for node, _ in fired:
                        del self._heard[node]  # inactive until the node's next heartbeat
                    tick = self._ticking and now >= next_tick
                    if fired or tick:
                        break
                    deadlines = [t + self._times[n] for n, t in self._heard.items()]
                    if self._ticking:
                        deadlines.append(next_tick)
                    self._cond.wait(min(deadlines) - now if deadlines else None)
            for node, silent in fired:
                self.on_lost(node, silent)
            if tick:
                next_tick = time.monotonic() + TICK_S
                if not self.on_tick():
                    with self._cond:
                        self._ticking = False
