"""One opener of a simulated-wire channel: its transmit FIFO, its counters, and what its send raises.

A node is what python-can's socketcan gives a process that opens the interface: a bounded transmit
FIFO of ``txqueuelen`` frames (SocketCAN's default 10), a receive callback, and the errors a full
FIFO (ENOBUFS) or a controller off the bus (ENETDOWN) raise. Among the FIFO heads the medium puts on
the wire the one that wins arbitration (``arbitration_priority``). A cyclic send (SocketCAN's
broadcast manager) is a node's too.
"""

from __future__ import annotations

import errno
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import can
from can import BusState

DEFAULT_TXQUEUELEN = 10  # SocketCAN's default txqueuelen for a CAN interface

Deliver = Callable[[can.Message], None]


def transmit_queue_full(node: str, txqueuelen: int) -> can.CanOperationError:
    """The error a full transmit FIFO raises, with ENOBUFS as python-can's socketcan carries it."""
    return can.CanOperationError(
        f"Failed to transmit: No buffer space available (node {node}: {txqueuelen} frames queued)", errno.ENOBUFS
    )


def bus_off_error(node: str) -> can.CanOperationError:
    return can.CanOperationError(f"Failed to transmit: node {node} is bus off", errno.ENETDOWN)


@dataclass(slots=True)
class Pending:
    """A frame in a wall-clock transmit FIFO."""

    msg: can.Message
    bits: int
    enqueued: float
    priority: tuple[int, int, int]
    cyclic: bool = False  # sent by a cyclic task: heard by its own node too, as a broadcast manager's
    # a post its sender counts in flight until told it left (``Node.on_done``); a cyclic or scheduled frame
    # (``Medium.add_cyclic``, ``Medium.post_at``) is the interface's, not counted against the sender's queue
    reported: bool = True


@dataclass(slots=True)
class Cyclic:
    """A cyclic send the wall-clock medium times by itself (SocketCAN's broadcast manager): each
    frame is queued at its due bus time, whenever the simulation gets to it. Frame k is due ``k``
    periods after ``start``, counted, never summed: bus time is epoch seconds (about 1.8e9, a
    resolution of 0.24 us), where adding 2 ms per SYNC put each SYNC 95 ns late and SYNC 1000 95 us
    behind its schedule (measured: bench/RESULTS.md); the kernel's timer counts in integer ns."""

    node: Node
    msg: can.Message
    bits: int
    period: float
    start: float
    sent: int = 0  # frames queued so far: the next is due ``sent`` periods after ``start``

    @property
    def due(self) -> float:
        return self.start + self.sent * self.period


@dataclass(slots=True)
class Node:
    """One opener of the channel: its receive callback, its transmit FIFO, its counters."""

    name: str
    deliver: Deliver
    txqueuelen: int
    receive_own: bool
    state: BusState = BusState.ACTIVE
    local_time: float = 0.0  # lockstep: the latest time stamp among frames it received
    last_end: float = 0.0  # lockstep: end of its previous frame
    ends: deque[float] = field(default_factory=deque)  # lockstep: end times of its frames still queued
    fifo: deque[Pending] = field(default_factory=deque)  # wall: queued frames, the one on the wire first
    enobufs: int = 0
    dropped: int = 0  # frames timed by the medium (cyclic, scheduled) dropped: the FIFO full at their due time
    max_depth: int = 0
    frames: int = 0
    waiters: int = 0  # senders waiting for room (send with a timeout)
    on_done: Callable[[int], None] | None = None  # wall: told how many frames left the FIFO (sent or dropped)
    accepts: Callable[[int], bool] | None = None  # acceptance filter on the identifier (None: every frame)


def arbitration_priority(msg: can.Message) -> tuple[int, int, int]:
    """Arbitration order, smallest wins: the 11 base bits, then base before extended (SRR/IDE
    recessive), then the 18 extension bits, then data before remote (RTR recessive)."""
    if msg.is_extended_id:
        return ((msg.arbitration_id >> 18) & 0x7FF, 1, ((msg.arbitration_id & 0x3FFFF) << 1) | msg.is_remote_frame)
    return (msg.arbitration_id & 0x7FF, 0, int(msg.is_remote_frame))
