"""The thread that runs a wall-clock medium in real time.

It sleeps on the medium's condition until the frame on the wire is due to end (or, on an idle
bus, until a frame is queued), then lets ``Medium.step`` deliver every frame whose end has passed
and start the next: a late wake delivers a batch, each frame still stamped with its exact end. A
batch's writes to other processes go out after the medium's lock is released.
No busy wait: the sleep is a condition wait (sub-millisecond where the OS gives it).
"""

from __future__ import annotations

import threading

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import ask_wire_priority
from pvtflow.axes.sim.wire.medium import Medium


class WallDriver:
    def __init__(self, medium: Medium) -> None:
        if medium.clock is not Clock.WALL:
            raise ValueError(f"a wall driver runs a wall-clock medium, not {medium.clock}")
        self.medium = medium
        self._stop = False
        self.thread = threading.Thread(target=self._run, name=f"simwire-{medium.channel}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        ask_wire_priority()
        medium = self.medium
        cond = medium.cond
        while True:
            # what a step delivers to another process is written once the medium's lock is released:
            # a socket write under it held up every sender (the loopback server's POSTs, the drives)
            # what ended by ``now`` is delivered only once every frame posted elsewhere by ``now`` is in:
            # a delivered frame cannot be taken back, and a post stamped before it would have been
            # arbitrated with it on a real bus (``Medium._rearbitrate``)
            now = medium.now()
            medium.catch_up()
            with medium.delivery_batch(), cond:
                if self._stop:
                    return
                medium.step(now)
            with cond:
                if self._stop:
                    return
                due = medium.next_event()  # what came meanwhile counts: no notify is missed
                if due is None:
                    cond.wait()
                else:
                    remaining = due - medium.now()
                    if remaining > 0:
                        cond.wait(remaining)

    def close(self) -> None:
        with self.medium.cond:
            self._stop = True
            self.medium.cond.notify_all()
        if threading.current_thread() is not self.thread:
            self.thread.join(timeout=2.0)
