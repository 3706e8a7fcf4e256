"""When a simulated drive's event-driven TPDO may go out: inhibit time and event timer (CiA 301).

0x1800+n:03, the inhibit time (100 us units), is the least time between two frames of the TPDO: a
change within it is held and sent, with the data of that moment, once the inhibit time has passed
(the drive looks at its TPDOs on every SYNC, every change, and when a held change's inhibit time
ends: ``axes.sim.node.pdo`` sets a timer). 0x1800+n:05, the event timer (ms), sends the TPDO when that
long passed without a frame, changed or not. Both run on the drive's own clock
(``SimulatedDrive.time_us``: one SYNC period per SYNC in lockstep, its quartz on the wall clock), so
in lockstep an inhibit time of one SYNC period allows one frame per period. A lockstep drive's
clock stands still between SYNCs, and between motions no SYNC comes: while it stands still since
the last frame, the inhibit time is counted on the wall clock, as a real drive's would be (a change
made by SDO between motions goes out once the inhibit time has passed). Synchronous TPDOs (types
1..240: every n-th SYNC, counted from the last reload of the PDO, ``axes.sim.node.pdo``) have neither.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

INHIBIT_UNIT_US = 100  # 0x1800:03
EVENT_TIMER_UNIT_US = 1000  # 0x1800:05


@dataclass
class TpdoTiming:
    """One event-driven TPDO's inhibit time and event timer, and when it last went out."""

    inhibit_us: int = 0
    event_timer_us: int = 0
    last_sent_us: float | None = None
    last_sent_wall: float = 0.0  # time.monotonic() of the last frame

    @classmethod
    def from_objects(cls, inhibit: int, event_timer: int) -> TpdoTiming:
        """From the raw 0x1800+n:03 and :05 values."""
        return cls(inhibit * INHIBIT_UNIT_US, event_timer * EVENT_TIMER_UNIT_US)

    def may_send(self, now_us: float) -> bool:
        """The inhibit time has passed since the last frame (or there was none): on the drive's clock,
        or on the wall clock while the drive's clock has not moved since that frame."""
        if self.last_sent_us is None or now_us - self.last_sent_us >= self.inhibit_us:
            return True
        return now_us == self.last_sent_us and self.wall_left() <= 0.0

    def wall_left(self) -> float:
        """Seconds of wall time until the inhibit time has passed since the last frame."""
        return self.last_sent_wall + self.inhibit_us / 1e6 - time.monotonic()

    def timer_due(self, now_us: float) -> bool:
        """The event timer asks for a frame, changed or not."""
        if self.event_timer_us <= 0:
            return False
        return self.last_sent_us is None or now_us - self.last_sent_us >= self.event_timer_us

    def sent(self, now_us: float) -> None:
        self.last_sent_us = now_us
        self.last_sent_wall = time.monotonic()
