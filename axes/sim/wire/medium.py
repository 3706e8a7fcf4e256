"""The shared bus of one simulated-wire channel: who transmits when, at what bus time.

Pure scheduling logic under one lock: no thread of its own. On the ``lockstep`` clock a frame is
scheduled and delivered inside ``submit``; on the ``wall`` clock ``submit`` queues it in its node's
transmit FIFO and ``step(now)`` (called by ``axes.sim.wire.wall.WallDriver``, or by a test with
the time it chooses) puts the frames whose time has come on the wire. Deliveries happen under the
lock, so every node sees the frames in bus order. The semantics are the package docstring's. The
medium holds two parts under its lock: ``accounting`` (``accounting.py``: what the channel carried) and
``bus_states`` (``bus_states.py``: bus states and error frames, the test hooks).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from contextlib import AbstractContextManager

import can
from can import BusState

from pvtflow.axes.canbus.can_errors import CAN_ERR_PROT
from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.frame_time import frame_bits
from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.axes.sim.wire.accounting import DEFAULT_RECORD_LIMIT, Accounting, LateSync, WireStats
from pvtflow.axes.sim.wire.bus_states import BUS_OFF, BusStates
from pvtflow.axes.sim.wire.node import (
    DEFAULT_TXQUEUELEN,
    Cyclic,
    Deliver,
    Node,
    Pending,
    arbitration_priority,
    bus_off_error,
    transmit_queue_full,
)

SYNC_ID = SYNC_COB_ID
IDLE_S = 0.05  # lockstep: no SYNC for this long (wall time) and the bus is idle: bus time follows the wall clock


class WireConfigError(ValueError):
    """A bus asked for a medium that disagrees with the channel's (clock, bit rate, SYNC period)."""


class Medium:
    """One channel's bus: nodes, arbitration, bus time; its accounting and bus states as parts."""

    def __init__(
        self,
        channel: str = "simwire",
        *,
        bitrate: int = 1_000_000,
        clock: str = Clock.WALL,
        sync_period: float | None = None,
        sync_id: int = SYNC_ID,
        record_limit: int = DEFAULT_RECORD_LIMIT,
    ) -> None:
        if clock not in list(Clock):
            raise WireConfigError(f"simwire clock must be one of {', '.join(Clock)}, got {clock!r}")
        if not isinstance(bitrate, int) or bitrate <= 0:
            raise WireConfigError(f"simwire bitrate must be a positive integer (bit/s), got {bitrate!r}")
        if sync_period is not None and not sync_period > 0:
            raise WireConfigError(f"simwire sync_period must be positive seconds, got {sync_period!r}")
        if clock == Clock.LOCKSTEP and sync_period is None:
            raise WireConfigError("simwire clock lockstep needs sync_period (seconds): bus time advances with it")
        self.channel = channel
        self.bitrate = bitrate
        self.clock = Clock(clock)
        self.sync_period = sync_period
        self.sync_id = sync_id
        self.cond = threading.Condition(threading.RLock())
        self.nodes: list[Node] = []
        self._names = itertools.count(1)
        self.accounting = Accounting(
            channel=channel,
            clock=self.clock,
            bitrate=bitrate,
            sync_period=sync_period,
            cond=self.cond,
            nodes=self.nodes,
            record_limit=record_limit,
        )
        self.bus_end = 0.0  # end of the last frame on the bus
        self._last_sync_nominal: float | None = None  # lockstep
        self._idle_from = (0.0, time.monotonic())  # lockstep: (bus time, wall time) of the last SYNC
        self._on_wire: tuple[Node, Pending, float, float] | None = None  # wall: (node, frame, start, end)
        self._stepped = -math.inf  # wall: the bus time of the last step (every frame ending by then delivered)
        self._cyclic: list[Cyclic] = []  # wall: cyclic sends the medium times (``add_cyclic``)
        # wall: frames a node handed over to go at a bus time (``post_at``): (due, order, node, frame)
        self._scheduled: list[tuple[float, int, Node, Pending]] = []
        self._order = itertools.count()
        self._seconds_per_bit = 1.0 / bitrate
        self.epoch = self._epoch = time.time() - time.monotonic()  # wall: bus time = epoch + time.monotonic()
        self.closed = False
        # wraps a run of deliveries from one thread (the wall driver's step): the loopback server
        # writes a run's frames to each client's socket once, at its end
        self.delivery_batch: Callable[[], AbstractContextManager[None]] = contextlib.nullcontext
        # called (the medium's lock not held) before the wall driver delivers what ended by a time taken
        # before it: the frames other processes posted by then, taken in first (``WireServer.catch_up``)
        self.catch_up: Callable[[], None] = no_catch_up
        self.bus_states = BusStates(
            channel=channel,
            cond=self.cond,
            nodes=self.nodes,
            now=self.now,
            go_bus_off=self._go_bus_off,
            accounting=self.accounting,
        )

    # -- time ----------------------------------------------------------------------------------

    def now(self) -> float:
        """Bus time: wall clock as epoch seconds (monotonic-based); lockstep: the end of the last frame."""
        if self.clock is Clock.WALL:
            return self._epoch + time.monotonic()
        return self.bus_end

    def params(self) -> dict:
        return {"bitrate": self.bitrate, "clock": self.clock, "sync_period": self.sync_period}

    def check_agrees(self, *, bitrate: int | None, clock: str | None, sync_period: float | None) -> None:
        """Every opener of a channel must agree with its medium; None agrees with anything."""
        for name, asked, have in (
            ("bitrate", bitrate, self.bitrate),
            ("clock", clock, self.clock),
            ("sync_period", sync_period, self.sync_period),
        ):
            if asked is not None and asked != have:
                raise WireConfigError(
                    f"simwire channel {self.channel!r} runs with {name}={have!r}; this bus asked for {asked!r}"
                )

    # -- the parts' faces: the names a ``RemoteMedium`` answers to as well --------------------------

    def stats(self) -> WireStats:
        return self.accounting.stats()

    def late_syncs(self) -> list[LateSync]:
        return self.accounting.late_syncs()

    def sync_intervals(self) -> list[float]:
        return self.accounting.sync_intervals()

    def set_state(self, name: str, state: BusState) -> None:
        self.bus_states.set_state(name, state)

    def inject_error_frame(self, can_id: int = CAN_ERR_PROT, data: bytes = bytes(8)) -> None:
        self.bus_states.inject_error_frame(can_id, data)

    # -- nodes ---------------------------------------------------------------------------------

    def attach(
        self, deliver: Deliver, *, name: str | None = None, txqueuelen: int = DEFAULT_TXQUEUELEN, receive_own=False
    ) -> Node:
        if not isinstance(txqueuelen, int) or txqueuelen < 1:
            raise WireConfigError(f"simwire txqueuelen must be a positive integer, got {txqueuelen!r}")
        with self.cond:
            if name is None:
                name = f"node{next(self._names)}"
            if any(n.name == name for n in self.nodes):
                raise WireConfigError(f"simwire channel {self.channel!r} already has a node named {name!r}")
            node = Node(name=name, deliver=deliver, txqueuelen=txqueuelen, receive_own=bool(receive_own))
            if self.clock is Clock.LOCKSTEP:
                node.local_time = self.bus_end
            self.nodes.append(node)
            return node

    def detach(self, node: Node) -> None:
        """The node leaves: its queued frames with it (a frame on the wire finishes)."""
        with self.cond:
            if node in self.nodes:
                self.nodes.remove(node)
                self.accounting.departed(node)
            node.fifo = deque(p for p in node.fifo if self._on_wire and self._on_wire[1] is p)
            self._cyclic = [t for t in self._cyclic if t.node is not node]
            self._scheduled = [s for s in self._scheduled if s[2] is not node]
            heapq.heapify(self._scheduled)
            self.cond.notify_all()

    def node(self, name: str) -> Node:
        with self.cond:
            for n in self.nodes:
                if n.name == name:
                    return n
        raise KeyError(f"simwire channel {self.channel!r} has no node {name!r}")

    # -- transmit ------------------------------------------------------------------------------

    def submit(self, node: Node, msg: can.Message, *, timeout: float | None = None, now: float | None = None) -> None:
        """Queue ``msg`` for transmission; lockstep delivers it before returning. A full FIFO raises
        CanOperationError with ENOBUFS, at once or, with ``timeout`` > 0, when no room came within
        it (as socketcan's select on a writable socket); a bus-off node raises ENETDOWN."""
        if msg.is_fd or msg.dlc > 8 or len(msg.data) > 8:
            raise can.CanOperationError(f"simwire carries classic CAN frames (0..8 bytes), got {msg}")
        if msg.is_error_frame:
            raise can.CanOperationError("an error frame is not sent: it is what the controllers signal")
        bits = frame_bits(
            msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id, remote=msg.is_remote_frame, dlc=msg.dlc
        )
        deadline = None if timeout is None or timeout <= 0 else time.monotonic() + timeout
        with self.cond:
            while True:
                if node.state == BUS_OFF:
                    raise bus_off_error(node.name)
                try:
                    if self.clock is Clock.LOCKSTEP:
                        self._submit_lockstep(node, msg, bits, 0.0 if timeout is None else max(timeout, 0.0))
                    else:
                        self._submit_wall(node, msg, bits, self.now() if now is None else now)
                    return
                except can.CanOperationError:
                    # lockstep waited in bus time already (``_submit_lockstep``); wall time waits here
                    if self.clock is Clock.LOCKSTEP or deadline is None or not self.wait_for_room(node, deadline):
                        node.enobufs += 1
                        raise

    def _lockstep_now(self) -> float:
        """Lockstep bus time as every node sees it: the last SYNC's nominal time, or, once no SYNC
        has come for ``IDLE_S`` of wall time, that plus the wall time since. Bus time passes between
        SYNCs only with SYNC, except on an idle bus: heartbeats and SDO exchanges without SYNC
        would otherwise pile up in their senders' FIFOs at one instant of a bus time that never moves."""
        since, wall = self._idle_from
        idle = time.monotonic() - wall
        return since + idle if idle > IDLE_S else since

    def _is_sync(self, msg: can.Message) -> bool:
        return msg.arbitration_id == self.sync_id and not msg.is_extended_id and not msg.is_remote_frame

    def _submit_lockstep(self, node: Node, msg: can.Message, bits: int, wait: float = 0.0) -> None:
        """``wait``: bus time the sender may wait for room (``send(msg, timeout)``): a sender that
        waits lets its FIFO drain, so its local time moves on to when a slot frees, if within it."""
        sync = self._is_sync(msg)
        enqueue = max(node.local_time, self._lockstep_now())
        if sync and self._last_sync_nominal is not None:
            enqueue = max(enqueue, self._last_sync_nominal + self.sync_period)
        ends = node.ends
        while ends and ends[0] <= enqueue:
            ends.popleft()
        if len(ends) >= node.txqueuelen:
            room = ends[len(ends) - node.txqueuelen]  # the end of the frame that frees a slot
            if room - enqueue > wait:
                raise transmit_queue_full(node.name, node.txqueuelen)
            node.local_time = max(node.local_time, room)
            enqueue = max(enqueue, room)
            while ends and ends[0] <= enqueue:
                ends.popleft()
        if sync:
            self._last_sync_nominal = enqueue
            self._idle_from = (enqueue, time.monotonic())
        start = max(enqueue, node.last_end, self.bus_end)
        end = start + bits * self._seconds_per_bit
        ends.append(end)
        node.last_end = end
        node.max_depth = max(node.max_depth, len(ends))
        if sync:
            self.accounting.sync(enqueue, start)
        self._transmitted(node, msg, bits, start, end)

    def _submit_wall(self, node: Node, msg: can.Message, bits: int, now: float) -> None:
        if len(node.fifo) >= node.txqueuelen:
            # the FIFO is judged at ``now`` in bus time: frames whose last bit has left by then are
            # out of it, though the driver thread (held by its process) has not woken to say so yet
            self._step(now)
        if len(node.fifo) >= node.txqueuelen:
            raise transmit_queue_full(node.name, node.txqueuelen)
        node.fifo.append(Pending(msg, bits, now, arbitration_priority(msg)))
        node.max_depth = max(node.max_depth, len(node.fifo))
        self._rearbitrate(now)
        if self._on_wire is None:
            self.cond.notify_all()  # the driver sleeps while the bus is idle (or arbitrates again)

    def _rearbitrate(self, enqueued: float) -> None:
        """A frame queued at ``enqueued`` (bus time), no later than the start of the frame the medium has
        put on the wire but not delivered: that frame's arbitration is undone and run again with it.

        The medium learns of a frame when its post reaches it (the loopback and this process's
        scheduling delay it), but the frame was in its sender's controller from ``enqueued`` on. On a
        real bus every controller with a frame pending when the bus goes idle takes part in that
        arbitration (ISO 11898-1: bus access at the end of the interframe space, the lowest identifier
        wins bit by bit), so a frame pending before another's start either started first (the bus
        idle) or won or lost against it by identifier; it never waits behind a frame that started after
        it was pending. Nothing of the frame on the wire has reached a node (deliveries happen at a
        frame's end, ``_step``), so choosing again is exactly what the bus would have done. A frame
        already delivered cannot be taken back: a post that reaches the medium after frames that
        started later than its time were delivered still queues behind them (that part of the host's
        latency stays)."""
        on_wire = self._on_wire
        if on_wire is not None and enqueued <= on_wire[2]:  # pending at its start: in its arbitration
            self._on_wire = None  # its frame stays at its node's FIFO head; ``_step`` chooses again

    def add_cyclic(self, node: Node, msg: can.Message, period: float, start: float | None = None) -> Cyclic:
        """Wall clock: send ``msg`` from ``node`` every ``period`` seconds of bus time from ``start`` (bus
        time; None: now) on, timed by the medium (a frame whose node's FIFO is full at its due time is
        dropped, as the broadcast manager's is). A client's broadcast manager starts its timer when it is
        asked, as the kernel's does at the syscall; the medium hears of it through the loopback later,
        so the client's own time of asking is the start, as a post's is its time in the queue."""
        if self.clock is not Clock.WALL:
            raise WireConfigError("a cyclic send is timed by the wall-clock medium; lockstep has no time of its own")
        bits = frame_bits(
            msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id, remote=msg.is_remote_frame, dlc=msg.dlc
        )
        with self.cond:
            now = self.now()
            task = Cyclic(node, msg, bits, period, now if start is None else min(start, now))
            self._cyclic.append(task)
            self.cond.notify_all()
            return task

    def remove_cyclic(self, task: Cyclic) -> None:
        with self.cond:
            if task in self._cyclic:
                self._cyclic.remove(task)

    def post_at(self, node: Node, msgs: list[can.Message], due: float) -> None:
        """Wall clock: ``msgs`` go into ``node``'s transmit FIFO at bus time ``due``, in this order, each as
        a cyclic frame at its due time (``_queue_due``: its place in the FIFO, its arbitration, dropped
        where the FIFO is full then). A due time already past is queued at it when the medium gets to it.

        This is the transmit schedule real CAN interfaces keep so that a host's late wake does not make a
        frame late: SocketCAN's broadcast manager (a TX_SETUP of ``nframes`` frames with ``count`` and
        ``ival1``: frame i goes at the i-th timer expiry, timed by the kernel), IXXAT VCI's delayed
        transmit (a frame's delay in the controller's ticks), esd NTCAN's scheduling (``canIoctl``
        NTCAN_IOCTL_TX_OBJ_SCHEDULE). The frames are the sender's from the moment it hands them over
        (``cancel_posts`` takes back those not yet due: the broadcast manager's TX_DELETE)."""
        if self.clock is not Clock.WALL:
            raise WireConfigError("a transmit schedule is timed by the wall-clock medium; lockstep has no time")
        frames = []
        for msg in msgs:
            if msg.is_fd or msg.dlc > 8 or len(msg.data) > 8 or msg.is_error_frame:
                raise can.CanOperationError(f"simwire carries classic CAN data and remote frames, got {msg}")
            bits = frame_bits(
                msg.arbitration_id,
                bytes(msg.data),
                extended=msg.is_extended_id,
                remote=msg.is_remote_frame,
                dlc=msg.dlc,
            )
            frames.append(Pending(msg, bits, due, arbitration_priority(msg), reported=False))
        with self.cond:
            if node.state == BUS_OFF:
                raise bus_off_error(node.name)
            for pending in frames:
                heapq.heappush(self._scheduled, (due, next(self._order), node, pending))
            self.cond.notify_all()

    def cancel_posts(self, node: Node) -> int:
        """``node``'s scheduled frames not yet due are dropped (the broadcast manager's TX_DELETE); how many."""
        with self.cond:
            kept = [s for s in self._scheduled if s[2] is not node]
            dropped = len(self._scheduled) - len(kept)
            heapq.heapify(kept)
            self._scheduled = kept
            return dropped

    def _queue_cyclic(self, now: float) -> float | None:
        """Queue every cyclic and scheduled frame due by ``now`` at its due time; the next due time (None: none)."""
        for task in self._cyclic:
            while task.due <= now:
                # the interface's own frame: its sender never counted it, so it is not reported as left
                # (reported, it took one off the sender's count of its posts each period)
                pending = Pending(
                    task.msg, task.bits, task.due, arbitration_priority(task.msg), cyclic=True, reported=False
                )
                task.sent += 1
                self._queue_due(task.node, pending)
        scheduled = self._scheduled
        while scheduled and scheduled[0][0] <= now:
            _, _, node, pending = heapq.heappop(scheduled)
            self._queue_due(node, pending)
        return self._next_due()

    def _next_due(self) -> float | None:
        """The next cyclic or scheduled frame's due time (None: none)."""
        due = min((t.due for t in self._cyclic), default=None)
        if self._scheduled and (due is None or self._scheduled[0][0] < due):
            due = self._scheduled[0][0]
        return due

    def _queue_due(self, node: Node, pending: Pending) -> None:
        """A frame timed by the interface (a cyclic or scheduled one) into ``node``'s FIFO at its due time
        (``pending.enqueued``); dropped where that FIFO was full then, as the broadcast manager's is."""
        due = pending.enqueued
        # pending from its due time: in the arbitration of a frame placed to start after it
        self._rearbitrate(due)
        # its node's FIFO as it was at the due time: the frames posted after it were not in it yet
        queued = sum(1 for q in node.fifo if q.enqueued <= due)
        if node.state != BUS_OFF and node in self.nodes and queued < node.txqueuelen:
            # in the queue where its due time puts it: the kernel's timer queued it then, before
            # the frames its node posted later that this process happened to take in first
            place = len(node.fifo)
            first = 0 if self._on_wire is None or self._on_wire[0] is not node else 1
            while place > first and node.fifo[place - 1].enqueued > due:
                place -= 1
            node.fifo.insert(place, pending)
            node.max_depth = max(node.max_depth, len(node.fifo))
        else:
            node.dropped += 1

    def step(self, now: float) -> float | None:
        """Wall clock: deliver every frame whose last bit has left the wire by ``now`` and start the
        next by arbitration. Returns when the frame on the wire ends or a cyclic frame is due (None:
        the bus is idle)."""
        with self.cond:
            # the wire up to each due time in turn, then what is due then: a timed frame's node's FIFO is
            # judged as it was at its due time (frames that left the wire by then are out of it), also
            # on a bus idle since, where a medium held for several periods would otherwise find every
            # frame due meanwhile in the FIFO at once and drop the last ones (measured: a held drives'
            # process dropped a period's scheduled setpoints, bench/RESULTS.md)
            while (next_due := self._next_due()) is not None and next_due <= now:
                self._step(next_due)
                self._queue_cyclic(next_due)
            next_cyclic = self._next_due()
            due = self._step(now)
            self._stepped = max(self._stepped, now)
            if next_cyclic is None:
                return due
            return next_cyclic if due is None else min(due, next_cyclic)

    def delivered_until(self) -> float:
        """Wall clock: the bus time up to which every frame has been delivered to the nodes: the last
        step's, or now on a bus with nothing on it, queued or due (nothing was left to deliver)."""
        with self.cond:
            now = self.now()
            idle = self._on_wire is None and not any(n.fifo for n in self.nodes)
            due = self._next_due()
            if idle and (due is None or due > now):
                return now
            return self._stepped

    def next_event(self) -> float | None:
        """Wall clock: when ``step`` has something to do: the end of the frame on the wire, a cyclic
        frame's due time, at once (-inf) for frames queued on an idle bus; None: nothing until a
        frame is queued."""
        with self.cond:
            if self._on_wire is not None:
                due: float | None = self._on_wire[3]
            elif any(n.fifo for n in self.nodes):
                return float("-inf")
            else:
                due = None
            next_cyclic = self._next_due()
            if next_cyclic is None:
                return due
            return next_cyclic if due is None else min(due, next_cyclic)

    def _step(self, now: float) -> float | None:
        with self.cond:
            while True:
                if self._on_wire is not None:
                    node, pending, start, end = self._on_wire
                    if end > now:
                        return end
                    self._on_wire = None
                    node.fifo.popleft()
                    if node.on_done is not None and pending.reported:
                        node.on_done(1)
                    if self._is_sync(pending.msg):
                        self.accounting.sync(float("nan"), start)
                    self._transmitted(node, pending.msg, pending.bits, start, end, heard_by_sender=pending.cyclic)
                    self.cond.notify_all()  # room in a FIFO
                heads = [n for n in self.nodes if n.fifo]
                if not heads:
                    return None
                start = max(self.bus_end, min(n.fifo[0].enqueued for n in heads))
                next_due = self._next_due()
                if next_due is not None and next_due <= start:
                    # a timed frame due before it takes part (the kernel's timer): the earliest due first,
                    # then the wire again from there, so each one's FIFO is judged as it stood at its due
                    # time (a frame posted periods later must not find them all queued at once)
                    self._queue_cyclic(next_due)
                    continue
                winner = min((n for n in heads if n.fifo[0].enqueued <= start), key=lambda n: n.fifo[0].priority)
                pending = winner.fifo[0]
                self._on_wire = (winner, pending, start, start + pending.bits * self._seconds_per_bit)

    def _go_bus_off(self, node: Node) -> None:
        """``node`` went bus off (``bus_states``): its queued frames are lost, one on the wire is aborted
        (nothing of it reaches the wire)."""
        with self.cond:
            if self._on_wire is not None and self._on_wire[0] is node:
                self.bus_end = max(self.bus_end, self._on_wire[2])
                self._on_wire = None
            dropped = sum(1 for q in node.fifo if q.reported)
            node.fifo.clear()
            node.ends.clear()
            if dropped and node.on_done is not None:
                node.on_done(dropped)
            self.cond.notify_all()

    def wait_for_room(self, node: Node, deadline: float) -> bool:
        """Block (wall time) until ``node``'s FIFO has room or ``deadline`` (time.monotonic) passes."""
        with self.cond:
            node.waiters += 1
            try:
                while self._queued(node) >= node.txqueuelen and node.state != BUS_OFF:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or self.closed:
                        return False
                    self.cond.wait(remaining)
                return True
            finally:
                node.waiters -= 1

    def _queued(self, node: Node) -> int:
        if self.clock is Clock.WALL:
            return len(node.fifo)
        enqueue = max(node.local_time, self._lockstep_now())
        return sum(1 for e in node.ends if e > enqueue)

    def received(self, node: Node, timestamp: float) -> None:
        """Lockstep: a frame of another node was handed to ``node``'s reader; its local time follows."""
        if timestamp > node.local_time:
            node.local_time = timestamp
            if node.waiters:
                with self.cond:
                    self.cond.notify_all()

    def _transmitted(
        self, sender: Node, msg: can.Message, bits: int, start: float, end: float, heard_by_sender: bool = False
    ) -> None:
        """Account for the frame and hand it to every node (under the lock: bus order); a cyclic
        task's frame reaches its own node as a received one (``heard_by_sender``)."""
        self.bus_end = end
        sender.frames += 1
        self.accounting.frame(sender.name, msg.arbitration_id, msg.dlc, bits, start, end)
        for n in self.nodes:
            if n.state == BUS_OFF:
                continue
            own = n is sender and not heard_by_sender
            if own and not n.receive_own:
                continue
            if n.accepts is not None and not n.accepts(msg.arbitration_id):
                continue  # the node's acceptance filter: its reader is not woken for it
            n.deliver(
                can.Message(
                    timestamp=end,
                    arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id,
                    is_remote_frame=msg.is_remote_frame,
                    dlc=msg.dlc,
                    data=msg.data,
                    channel=self.channel,
                    is_rx=not own,
                    check=False,
                )
            )


def no_catch_up() -> None:
    """No frames reach this medium from other processes (``Medium.catch_up``)."""
