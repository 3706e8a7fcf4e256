"""Per-axis feeders: they turn a program's records into frames as the drive needs them.

Two kinds, both driven by events only (the SYNC answers and the status TPDO), never by a sleep:

- ``BufferFeeder`` (EPOS2 PVT): preloads the records of the first ``PRELOAD_MS`` of motion (at least
  two above the underflow warning level), then after every SYNC tops the FIFO up towards the
  overflow warning mark, ``TOP_UP_PER_SYNC`` records at a time. Every frame sent before the start
  SYNC delays the start (a full FIFO of six axes is ~45 ms of a 1 Mbit/s bus), and a burst of them
  on one SYNC would hold the bus as long: the FIFO fills during the first SYNCs of the motion
  instead, and stays deep from then on (depth is what rides out a stalled master). The EPOS2 does not PDO-map its
  FIFO level (0x60C4:02), so the level is *estimated*: records sent minus records consumed, a record
  being consumed once the drive's clock (one SYNC period per SYNC since the start SYNC) has passed
  its end time. The estimate counts the segment in progress as still buffered, so it is never
  below the true level; the warning bits of 0x20C4:01 correct it (overflow warning: the level is at
  least 0x20C4:03, stop; underflow warning: it is below 0x20C4:02, send). After the last record
  the time-0 end record goes out.
- ``SetpointFeeder`` (fixed-period profiles): one setpoint per SYNC, sent ahead by the profile's
  delay so that record k is reached at (k + 1) periods on the program's timeline. Its frames are
  packed before the start and go out right after each SYNC, from the thread that sends the SYNC
  (``after_sync``): a drive's answers never pace them, so on the wall clock a setpoint is never
  late for its SYNC (a missed one makes the drive hold, and the next asks for twice the step).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from axes.config import BufferConfig
from axes.objects import EPOS2_BUFFER_SIZE, BufferStatus

# plain ints: these are tested on every status frame
_UNDERFLOW_WARNING = int(BufferStatus.UNDERFLOW_WARNING)
_OVERFLOW_WARNING = int(BufferStatus.OVERFLOW_WARNING)
_UNDERFLOW_ERROR = int(BufferStatus.UNDERFLOW_ERROR)
_OVERFLOW_ERROR = int(BufferStatus.OVERFLOW_ERROR)
_IP_MODE_ACTIVE = int(BufferStatus.IP_MODE_ACTIVE)

FrameOf = Callable[[NDArray[np.int64]], tuple[int, bytes]]
Send = Callable[[int, bytes], None]

PRELOAD_MS = 50.0  # motion the records sent before the start SYNC cover (the first top-ups follow on SYNC)
TOP_UP_PER_SYNC = 4  # records per axis per SYNC at most (more while the level is at the underflow warning)


@dataclass
class FeedStats:
    """What a feeder saw: records sent, warnings and errors reported, the level it kept."""

    records: int = 0
    sent: int = 0
    underflow_warnings: int = 0
    overflow_warnings: int = 0
    underflows: int = 0  # buffer underflow errors reported by the drive
    overflows: int = 0  # buffer overflow errors reported by the drive (or sends past the FIFO)
    min_level: int | None = None  # lowest estimated level while records were still to be sent
    max_level: int | None = None

    def level(self, value: int) -> None:
        self.min_level = value if self.min_level is None else min(self.min_level, value)
        self.max_level = value if self.max_level is None else max(self.max_level, value)


class Feeder:
    """Common interface: ``preload`` before the start, ``after_sync(elapsed)`` right after each SYNC
    is sent and ``on_sync(elapsed)`` once the drives have answered it (``elapsed`` = SYNCs since the
    start SYNC, 0 at the start SYNC), ``on_status`` on a status TPDO."""

    def __init__(self, records: NDArray[np.int64], frame_of: FrameOf, send: Send, period_ms: float) -> None:
        self.records = np.asarray(records, dtype=np.int64)
        self.frame_of = frame_of
        self.send = send
        self.period_ms = period_ms
        self.next = 0  # index of the next record to send
        self.enabled = True
        self.stats = FeedStats(records=len(self.records))

    @property
    def all_sent(self) -> bool:
        return self.next >= len(self.records)

    def _send_next(self) -> None:
        cob, data = self.frame_of(self.records[self.next])
        self.send(cob, data)
        self.next += 1
        self.stats.sent = self.next

    def preload(self) -> int:
        raise NotImplementedError

    def after_sync(self, elapsed: int) -> None:
        """Right after the SYNC went out, in the sending thread (fixed-period setpoints)."""

    def on_sync(self, elapsed: int) -> None:
        """After the drives answered the SYNC (buffered drives top up)."""

    def on_status(self, buffer_status: int) -> None:
        """Buffered drives react to the buffer status; fixed-period drives have none."""

    def finished(self, elapsed: int, ip_active: bool) -> bool:
        raise NotImplementedError

    @property
    def level(self) -> int | None:
        return None


class BufferFeeder(Feeder):
    """EPOS2 PVT FIFO feeder (see the module docstring)."""

    def __init__(
        self,
        records: NDArray[np.int64],
        frame_of: FrameOf,
        send: Send,
        period_ms: float,
        buffer: BufferConfig,
        capacity: int = EPOS2_BUFFER_SIZE,
    ) -> None:
        r = np.asarray(records, dtype=np.int64)
        if r[-1, 2] != 0:  # the end record: time 0 ends interpolation without error
            r = np.vstack([r, [[r[-1, 0], 0, 0]]])
        super().__init__(r, frame_of, send, period_ms)
        self.buffer = buffer
        self.capacity = capacity
        # the mark the level is topped up to: just below the overflow warning, inside the FIFO
        self.high = max(2, min(capacity, buffer.overflow_warning - 1))
        self.low = min(buffer.underflow_warning, self.high - 2)  # the level the drive warns below
        # end time of each record (ms from the start SYNC); the end record ends with the last one
        self.end_ms = np.cumsum(self.records[:, 2])
        self._end = self.end_ms.tolist()
        self._consumed = 0
        self.duration_ms = int(self.end_ms[-1])
        self.elapsed_ms = 0.0
        self._hold = False  # overflow warning seen: wait for it to clear
        self._status = 0

    def consumed(self) -> int:
        """Records whose segment the drive has finished by its clock (the running one counts as buffered)."""
        while self._consumed < self.next and self._end[self._consumed] <= self.elapsed_ms:
            self._consumed += 1
        return self._consumed

    @property
    def level(self) -> int:
        return self.next - self.consumed()

    def _top_up(self) -> None:
        if not self.enabled or self._hold or self.all_sent:
            return
        self.stats.level(self.level)  # the low point the drive came down to, before refilling
        budget = TOP_UP_PER_SYNC
        while not self.all_sent and (level := self.level) < self.high and (budget > 0 or level <= self.low):
            self._send_next()
            budget -= 1
        self.stats.level(self.level)

    def preload(self) -> int:
        """Records for the first PRELOAD_MS of motion, and at least two above the underflow warning."""
        self.elapsed_ms = 0.0
        self._consumed = 0
        while (
            not self.all_sent
            and self.next < self.high
            and (self.next <= self.low + 1 or self._end[self.next - 1] < PRELOAD_MS)
        ):
            self._send_next()
        self.stats.level(self.level)
        return self.next

    def on_sync(self, elapsed: int) -> None:
        self.elapsed_ms = elapsed * self.period_ms
        self._top_up()

    def on_status(self, buffer_status: int) -> None:
        if buffer_status == self._status:
            return
        rising = buffer_status & ~self._status
        self._status = buffer_status
        if rising & _UNDERFLOW_WARNING:
            self.stats.underflow_warnings += 1
        if rising & _OVERFLOW_WARNING:
            self.stats.overflow_warnings += 1
        if rising & _UNDERFLOW_ERROR:
            self.stats.underflows += 1
        if rising & _OVERFLOW_ERROR:
            self.stats.overflows += 1
        self._hold = bool(buffer_status & _OVERFLOW_WARNING)
        if buffer_status & _UNDERFLOW_WARNING and buffer_status & _IP_MODE_ACTIVE:
            self._top_up()

    def finished(self, elapsed: int, ip_active: bool) -> bool:
        return self.all_sent and elapsed * self.period_ms >= self.duration_ms and not ip_active


class SetpointFeeder(Feeder):
    """One setpoint per SYNC: record k is validated by SYNC (start + k + 1 - lead).

    ``lead_periods`` is how many periods before its program time (k + 1) periods a setpoint must be
    validated: the drive's delay from validation to reached, less what the program's reconstruction
    already models. Records validated before the start SYNC (k < lead - 1) are the start position
    at rest, where the axis already is: they are not sent.
    """

    def __init__(
        self, records: NDArray[np.int64], frame_of: FrameOf, send: Send, period_ms: float, lead_periods: int
    ) -> None:
        super().__init__(records, frame_of, send, period_ms)
        if not 0 <= lead_periods <= 2:
            raise ValueError("a fixed-period drive is fed 0, 1 or 2 periods ahead")
        self.lead = lead_periods
        self.next = max(0, lead_periods - 1)
        self.frames = [frame_of(r) for r in self.records]  # packed before the start: sending is all that is left

    def _send_next(self) -> None:
        cob, data = self.frames[self.next]
        self.send(cob, data)
        self.next += 1
        self.stats.sent = self.next

    def preload(self) -> int:
        """The setpoint the start SYNC validates (record lead - 1) goes out with the start word."""
        if self.lead >= 1 and not self.all_sent:
            self._send_next()
            return 1
        return 0

    def after_sync(self, elapsed: int) -> None:
        # SYNC start+elapsed is out: the next SYNC validates record elapsed + lead
        k = elapsed + self.lead
        if self.enabled and self.next <= k < len(self.records):
            self.next = k  # a SYNC without a setpoint (none can be skipped here) would skip its record
            self._send_next()

    def finished(self, elapsed: int, ip_active: bool) -> bool:
        # record N-1 is reached at N periods
        return elapsed >= len(self.records) and (self.all_sent or not self.enabled)
