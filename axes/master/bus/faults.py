"""What the master sees fail on the bus, in one vocabulary for every reporter.

The SYNC producer, the watchdog (``axes.master.bus.watch``) and the EMCY consumer all report a ``BusFault``
of one ``FaultKind``; the group, the homing and the recording decide what a kind means for them
(``warning``: the motion goes on; ``sync_failed``: a halt must not wait for SYNC). Error frames are
counted here as they arrive and reported by the watchdog at most once a second; the controller
states they announce (``axes.canbus.can_errors``) are kept in order for the watchdog, every one reported.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

import can

from pvtflow.axes.canbus.can_errors import ErrorFrame, decode


class BusError(RuntimeError):
    """The bus cannot be opened or a frame cannot be sent (one clear line for the user)."""


class FaultKind(StrEnum):
    """What the bus saw fail."""

    EMCY = "emcy"  # a node sent an emergency
    HEARTBEAT = "heartbeat"  # a node's heartbeat stopped
    NMT = "nmt"  # a node left OPERATIONAL (or booted)
    LOST_SYNC = "lost_sync"  # a node stopped answering SYNC
    SYNC_GAP = "sync_gap"  # the master sent no SYNC for longer than the drives ride out (the gap in ms)
    SYNC_STOPPED = "sync_stopped"  # the thread that sends SYNC ended by an error
    TX_FAILED = "tx_failed"  # the interface refused a frame past the retries (queue full, an error)
    BUS_OFF = "bus_off"  # the master's CAN controller is bus-off: it can send nothing
    BUS_WARNING = "bus_warning"  # error frames on the bus, or the master's controller error passive

    @property
    def warning(self) -> bool:
        """Reported, but the motion goes on: the bus still carries every frame."""
        return self is FaultKind.BUS_WARNING

    @property
    def sync_failed(self) -> bool:
        """The master cannot keep SYNC: a halt must not wait for one (``axes.master.bus.quick_stop``)."""
        return self in (FaultKind.SYNC_GAP, FaultKind.SYNC_STOPPED, FaultKind.TX_FAILED, FaultKind.BUS_OFF)


@dataclass(frozen=True)
class BusFault:
    """A failure seen on the bus."""

    kind: FaultKind
    node_id: int | None
    message: str
    code: int = 0


FaultCallback = Callable[[BusFault], None]


class ErrorFrames(can.Listener):
    """Counts the error frames the interface delivers (``is_error_frame``) and keeps those that
    announce a controller state (``changes``): a bus-off and the restart after it may both come
    between two looks of the watchdog, and each must be reported."""

    def __init__(self) -> None:
        self.count = 0
        self._reported = 0
        self._reported_at = 0.0
        self._lock = threading.Lock()
        self._states: deque[ErrorFrame] = deque()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.count += 1
            frame = decode(msg)
            if frame.state is not None:
                with self._lock:
                    self._states.append(frame)

    def changes(self) -> list[ErrorFrame]:
        """The error frames that announced a controller state since the last call, in order."""
        with self._lock:
            frames = list(self._states)
            self._states.clear()
        return frames

    def take(self, now: float, every_s: float) -> int:
        """Error frames since the last report, when one is due (0: none, or not yet)."""
        new = self.count - self._reported
        if new <= 0 or now - self._reported_at < every_s:
            return 0
        self._reported, self._reported_at = self.count, now
        return new
