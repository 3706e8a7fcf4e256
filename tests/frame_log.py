"""Every frame a python-can bus receives, waitable: the tests' listener on a master's bus."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import can


class FrameLog(can.Listener):
    """Every frame the master's bus receives, waitable."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self.cond = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        with self.cond:
            self.frames.append(msg)
            self.cond.notify_all()

    def of(self, can_id: int) -> list[can.Message]:
        with self.cond:
            return [m for m in self.frames if m.arbitration_id == can_id]

    def wait_for(
        self, can_id: int, count: int = 1, timeout: float = 5.0, where: Callable[[can.Message], bool] | None = None
    ) -> list[can.Message]:
        """Wait until ``count`` frames with this id (and ``where``) arrived; returns them."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                hits = [m for m in self.frames if m.arbitration_id == can_id and (where is None or where(m))]
                remaining = deadline - time.monotonic()
                if len(hits) >= count or remaining <= 0:
                    return hits
                self.cond.wait(remaining)

    def clear(self) -> None:
        with self.cond:
            self.frames.clear()
