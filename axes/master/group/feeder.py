"""Per-axis feeders: they turn a program's records into frames as the drive needs them.

Two kinds, both driven by events only (the SYNC answers and the status TPDO), never by a sleep:

- ``BufferFeeder`` (EPOS2 PVT): preloads the records of the first ``PRELOAD_MS`` of motion (at least
  two above the underflow warning level), then after every SYNC tops the FIFO up towards the
  overflow warning mark. Every record comes out of the cell's ``RecordAllowance``: the records the
  bus budget (``axes.master.budget``) leaves room for in one SYNC period, shared by every buffered axis of
  the cell and handed out by need (``top_up_by_need``: one record at a time to the axis whose FIFO
  is lowest), so that no SYNC period carries more records than the budget, the start included: a
  preload larger than one period's allowance goes out over several periods before the start SYNC
  (``axes.master.group.axis_group``). The allowance is renewed once per SYNC *sent* (``RecordAllowance.at_sync``),
  whoever tops up first in that period. A feeder on its own (no cell) has an allowance of its own,
  ``TOP_UP_PER_SYNC``. Depth is what rides out a stalled master, so the FIFO is kept deep. The EPOS2
  does not PDO-map its FIFO level (0x60C4:02), so the level is *estimated*: records sent minus
  records consumed, a record being consumed once the drive's clock has passed its end time. That
  clock (``run_to``) is one SYNC period per SYNC since the start SYNC in lockstep; on the wall clock
  it is the wall time since the start SYNC went out (``axes.master.group.axis_group``): the drive runs its records on
  its own quartz from that SYNC, whether the next SYNCs are late and whether the other drives answer
  them, so a count of answered SYNCs would fall behind it and starve the FIFO (bench/RESULTS.md,
  "the buffered EPOS2 on the wall clock"). The master's time runs at or ahead of the drive's (the
  drive starts at the SYNC's arrival), which errs toward a lower estimate, never toward an
  underflow. The estimate counts the segment in progress as still buffered, so it is never below the
  true level; the warning bits of 0x20C4:01 correct it (overflow warning: the level is at least
  0x20C4:03, stop; underflow warning: it is below 0x20C4:02, send what is left of this period's
  allowance). After the last record the time-0 end record goes out.
- ``SetpointFeeder`` (fixed-period profiles): one setpoint per SYNC, sent ahead by the profile's
  delay so that record k is reached at (k + 1) periods on the program's timeline. Its frames are
  packed before the start and go out right after each SYNC, from the thread that sends the SYNC
  (``after_sync``): a drive's answers never pace them, so on the wall clock a setpoint is never
  late for its SYNC. Where the interface sends SYNC, a held follower leaves SYNCs without a setpoint:
  the drive holds through them and the feeder goes on with the next record (never a jump). Where the
  interface also keeps a transmit schedule, the cyclic process asks for a SYNC's setpoint several SYNCs
  ahead and the interface times it (``axes.master.cyclic.loop``): what went out is then committed ahead.
  A stop of a drive without a ramp of its own replaces the records not yet sent by the master's
  braking ramp (``decelerate``, ``axes.drive.stop_ramp``); the feeder sends them as it sent the program.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.objects import EPOS2_BUFFER_SIZE, BufferStatus

# plain ints: these are tested on every status frame
_UNDERFLOW_WARNING = int(BufferStatus.UNDERFLOW_WARNING)
_OVERFLOW_WARNING = int(BufferStatus.OVERFLOW_WARNING)
_UNDERFLOW_ERROR = int(BufferStatus.UNDERFLOW_ERROR)
_OVERFLOW_ERROR = int(BufferStatus.OVERFLOW_ERROR)
_IP_MODE_ACTIVE = int(BufferStatus.IP_MODE_ACTIVE)

FrameOf = Callable[[NDArray[np.int64]], tuple[int, bytes]]
Send = Callable[[int, bytes], None]

PRELOAD_MS = 50.0  # motion the records sent before the start SYNC cover (the first top-ups follow on SYNC)
TOP_UP_PER_SYNC = 4  # the allowance of a feeder on its own (a cell's comes from its bus budget)
MIN_HELD = 3  # records a look-ahead-bound FIFO holds at least (its level counts the segment running)


class RecordAllowance:
    """The records the master may still send in the present SYNC period, shared by a cell's buffered axes."""

    def __init__(self, per_sync: int) -> None:
        if per_sync < 1:
            raise ValueError(f"a record allowance is at least one record per SYNC period, got {per_sync}")
        self.per_sync = per_sync
        self.left = per_sync
        self.periods = 0  # periods begun
        self.most = 0  # the most records sent in one period so far

        self.sync = -1  # the SYNC whose period ``left`` is for (``at_sync``)

    def new_period(self, sync: int | None = None) -> None:
        """A SYNC went out: the next period's records (``sync``: its number, when known)."""
        self.left = self.per_sync
        self.periods += 1
        if sync is not None:
            self.sync = sync

    def at_sync(self, sync: int) -> None:
        """The period after SYNC ``sync`` (the last one sent): renewed once per SYNC, by whichever top-up
        comes first in it (a SYNC's answers, or a buffered drive's own status frame)."""
        if sync > self.sync:
            self.new_period(sync)

    def take(self) -> bool:
        """One record, if this period has room for it."""
        if self.left <= 0:
            return False
        self.left -= 1
        self.most = max(self.most, self.per_sync - self.left)
        return True


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


@dataclass(frozen=True)
class Extension:
    """A feeder's records continued by another program's (``Feeder.extension``): ``ready()`` while the
    feeder is as it was when the extension was made and has records left to send; ``apply()`` puts it
    in place."""

    ready: Callable[[], bool]
    apply: Callable[[], None]


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
        # another process sends this feeder's frames (axes.master.cyclic.process): this one only mirrors it
        self.mirrored = False
        self.horizon_ms: float | None = None  # no record ending after it goes out (axes.master.splice)
        self.stats = FeedStats(records=len(self.records))

    @property
    def all_sent(self) -> bool:
        return self.next >= len(self.records)

    def hold_to(self, horizon_ms: float | None) -> None:
        """No record ending after ``horizon_ms`` goes out while a change from there is made
        (``axes.master.splice``); None: no bound."""
        self.horizon_ms = horizon_ms

    def disable(self) -> None:
        """Send nothing more (a halt: the drive brakes on its own ramp)."""
        self.enabled = False

    def hand_over(self) -> None:
        """Another process sends this feeder's frames from now on (``axes.master.cyclic.process``)."""
        self.mirrored = True

    def resume_at(self, next_record: int) -> None:
        """This feeder goes on where another left off (the cyclic process takes a run over)."""
        self.next = next_record

    def sent_elsewhere(self, sent: int) -> None:
        """Another process has sent the first ``sent`` records (the one this feeder hands over to, or
        the one it mirrors)."""
        if sent > self.next:
            self.next = sent
            self.stats.sent = sent

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

    def extension(self, records: NDArray[np.int64]) -> Extension:
        """The next program's records continuing this run where the last ends, on the same time line
        (``axes.master.run_queue``): made now, without a lock (arrays joined, frames packed), put in
        place by ``Extension.apply`` under the SYNC lock, while records are left to send."""
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
        allowance: RecordAllowance | None = None,
        lookahead_ms: float | None = None,
    ) -> None:
        super().__init__(_with_end_record(records), frame_of, send, period_ms)
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
        self._own = allowance is None  # a feeder on its own begins its periods itself
        self.allowance = RecordAllowance(TOP_UP_PER_SYNC) if allowance is None else allowance
        # the records held reach at most this far beyond the drive's clock (axes.master.splice), and
        # none ends after ``horizon_ms`` while a splice is prepared (``Feeder.hold_to``)
        self.lookahead_ms = lookahead_ms
        # the end record waits until the drive's clock is this close to the end (None: it goes with the
        # others), so that a queued program can still take its place (axes.master.run_queue)
        self.hold_end_ms: float | None = None

    def consumed(self) -> int:
        """Records whose segment the drive has finished by its clock (the running one counts as buffered)."""
        while self._consumed < self.next and self._end[self._consumed] <= self.elapsed_ms:
            self._consumed += 1
        return self._consumed

    @property
    def level(self) -> int:
        return self.next - self.consumed()

    @property
    def reserve(self) -> int:
        """The level below which a record that cannot go out now ends the run (the drive would soon run
        dry): the underflow warning level (0x20C4:02), or under a look-ahead bound ``MIN_HELD``, the least
        the bound keeps (``within_lookahead``: it gives the FIFO's depth below the warning level up for
        what a change of the motion cannot take back, so a FIFO at ``MIN_HELD`` stands where the bound
        keeps it, not short of records)."""
        return self.low if self.lookahead_ms is None else min(self.low, MIN_HELD)

    @property
    def wants(self) -> bool:
        """A record would go out now if the allowance had one: the FIFO is below its mark."""
        return (
            self.enabled
            and not self._hold
            and not self.all_sent
            and self.level < self.high
            and not self.end_held
            and (self.lookahead_ms is None or within_lookahead(self))
        )

    def replace_from(self, first: int, rows: NDArray[np.int64]) -> None:
        """Records ``first`` on (none of them sent) become ``rows`` (axes.master.splice), then the end record."""
        assert first >= self.next, "a record the drive holds cannot be replaced"
        self.records = _with_end_record(np.concatenate((self.records[:first], np.asarray(rows, dtype=np.int64))))
        self.end_ms = np.cumsum(self.records[:, 2])
        self._end = self.end_ms.tolist()
        self.duration_ms = int(self.end_ms[-1])
        self.stats.records = len(self.records)
        self.horizon_ms = None

    def hold_end(self, hold_ms: float | None) -> None:
        """The end record waits until the drive's clock is ``hold_ms`` from the end (axes.master.run_queue)."""
        self.hold_end_ms = hold_ms

    @property
    def end_held(self) -> bool:
        """The end record is next and the drive's clock is not yet within ``hold_end_ms`` of the end."""
        hold = self.hold_end_ms
        return hold is not None and self.next == len(self.records) - 1 and self.elapsed_ms < self.duration_ms - hold

    def extension(self, records: NDArray[np.int64]) -> Extension:
        """The next program's records take the end record's place (it follows them): the drive runs on
        from one program into the next in its FIFO, on its own clock. Its first record, the dwell at
        its start, begins where the last record of this one ends. Possible until the end record is out."""
        base = self.records
        r = np.asarray(records, dtype=np.int64)
        if r[-1, 2] != 0:
            r = np.vstack([r, [[r[-1, 0], 0, 0]]])
        joined = np.concatenate((base[:-1], r))
        end_ms = np.cumsum(joined[:, 2])
        end = end_ms.tolist()

        def apply() -> None:
            self.records, self.end_ms, self._end = joined, end_ms, end
            self.duration_ms = int(end_ms[-1])
            self.stats.records = len(joined)

        return Extension(lambda: self.records is base and not self.all_sent, apply)

    def _top_up(self) -> None:
        if not self.wants or self.mirrored:
            return
        self.stats.level(self.level)  # the low point the drive came down to, before refilling
        while self.wants and self.allowance.take():
            self._send_next()
        self.stats.level(self.level)

    @property
    def preloaded(self) -> bool:
        """The records of the first PRELOAD_MS of motion (at least two above the underflow warning; under a
        look-ahead bound, MIN_HELD and the bound's time at most) are out."""
        if self.lookahead_ms is not None:
            covered = self.next >= MIN_HELD and self._end[self.next - 1] >= min(PRELOAD_MS, self.lookahead_ms)
            return self.all_sent or self.next >= self.high or covered
        return (
            self.all_sent
            or self.next >= self.high
            or (self.next > self.low + 1 and self._end[self.next - 1] >= PRELOAD_MS)
        )

    def preload(self, most: int | None = None, *, whole: bool = False) -> int:
        """Send what this period's allowance permits of the preload (a feeder on its own, or
        ``whole``: all of it, no SYNC running yet), ``most`` records at most (``preloaded`` says when
        it is all out); the records sent so far."""
        self.elapsed_ms = 0.0
        self._consumed = 0
        sent = 0
        while not self.preloaded and (most is None or sent < most) and (whole or self._own or self.allowance.take()):
            self._send_next()
            sent += 1
        if self.preloaded:  # the level the start begins with (not the levels on the way there)
            self.stats.level(self.level)
        return self.next

    def run_to(self, elapsed_ms: float) -> None:
        """The drive's clock is at ``elapsed_ms`` from the start SYNC (it never runs back)."""
        self.elapsed_ms = max(self.elapsed_ms, elapsed_ms)

    def on_sync(self, elapsed: int) -> None:
        """The drive's clock moves on; a feeder on its own tops up (a cell's: ``top_up_by_need``)."""
        self.run_to(elapsed * self.period_ms)
        if self._own:
            self.allowance.new_period()
            self._top_up()
        elif self.wants:
            self.stats.level(self.level)

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


def _with_end_record(records: NDArray[np.int64]) -> NDArray[np.int64]:
    """The records and the end record (time 0 ends interpolation without error)."""
    r = np.asarray(records, dtype=np.int64)
    return r if r[-1, 2] == 0 else np.vstack([r, [[r[-1, 0], 0, 0]]])


def within_lookahead(feeder: BufferFeeder) -> bool:
    """The next record may go out: the records held end short of the look-ahead bound beyond the drive's
    clock, or the FIFO would hold less than the segment running and two more (``MIN_HELD``: the drive
    interpolates towards the next record; a record is never held back from a drive that needs it, so a
    splice's ``t0`` is the later of the two), and no record ends after a splice's horizon. Below its
    underflow warning level the drive only warns (0x20C4:02): the bound is what a change of the motion
    cannot take back, and the FIFO's depth is given up for it."""
    end = feeder._end[feeder.next]
    if feeder.horizon_ms is not None and end > feeder.horizon_ms:
        return False
    held = feeder._end[feeder.next - 1] if feeder.next else 0.0
    return held < feeder.elapsed_ms + feeder.lookahead_ms or feeder.level < MIN_HELD


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
        self.held_syncs = 0  # SYNCs that went out without this axis's setpoint: the drive held a period each
        self._last_elapsed = -1
        self.frames = [frame_of(r) for r in self.records]  # packed before the start: sending is all that is left

    def _send_next(self) -> None:
        cob, data = self.frames[self.next]
        self.send(cob, data)
        self.next += 1
        self.stats.sent = self.next

    def last_commanded(self) -> tuple[int, int]:
        """(last setpoint sent, the one before it), qc: where the drive is headed and its last step
        (before the first one: the program's start, at rest)."""
        last = self.records[max(self.next - 1, 0), 0]
        previous = self.records[max(self.next - 2, 0), 0]
        return int(last), int(previous)

    def decelerate(self, rows: NDArray[np.int64]) -> None:
        """The records not yet sent are replaced by ``rows`` (a stop ramp), sent one per SYNC as the
        program's were; after them, nothing: the drive holds the last."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
        self.records = np.concatenate((self.records[: self.next], rows))
        self.frames = self.frames[: self.next] + [self.frame_of(r) for r in rows]
        self.stats.records = len(self.records)

    def extension(self, records: NDArray[np.int64]) -> Extension:
        """The next program's setpoints follow this one's, one per SYNC: its record k is reached
        (k + 1) periods after this program's last. Possible until the last setpoint is out (the drive
        holds it: a setpoint after that would come a SYNC late)."""
        base = self.records
        rows = np.asarray(records, dtype=np.int64).reshape(-1, 3)
        joined = np.concatenate((base, rows))
        frames = [self.frame_of(r) for r in rows]  # packed here, not under the SYNC lock

        def apply() -> None:
            self.records, self.frames = joined, self.frames + frames
            self.stats.records = len(joined)

        return Extension(lambda: self.records is base and not self.all_sent, apply)

    def preload(self) -> int:
        """The setpoint the start SYNC validates (record lead - 1) goes out with the start word."""
        if self.lead >= 1 and not self.all_sent:
            self._send_next()
            return 1
        return 0

    def after_sync(self, elapsed: int) -> None:
        """SYNC start + elapsed is out: the next SYNC validates record elapsed + lead, or, where SYNCs
        went out without a setpoint (the interface sends SYNC and its follower was held:
        ``axes.master.bus.sync_follower``), the next record not sent: the drive held through those SYNCs, and
        the record after its last would ask it for several periods' step in one (a multiple of the
        planned speed). One record per SYNC, never ahead of its SYNC."""
        if elapsed > self._last_elapsed + 1 and self.next < len(self.records):
            self.held_syncs += elapsed - self._last_elapsed - 1  # the program runs that much later
        self._last_elapsed = max(self._last_elapsed, elapsed)
        if (
            self.enabled
            and not self.mirrored
            and self.next <= elapsed + self.lead
            and self.next < len(self.records)
            and (self.horizon_ms is None or self.records[: self.next + 1, 2].sum() <= self.horizon_ms)
        ):
            self._send_next()

    def replace_from(self, first: int, rows: NDArray[np.int64]) -> None:
        """Records ``first`` on (none of them sent) become ``rows`` (axes.master.splice)."""
        assert first >= self.next, "a setpoint the drive holds cannot be replaced"
        kept = self.records[self.next : first]
        self.decelerate(np.concatenate((kept, np.asarray(rows, dtype=np.int64).reshape(-1, 3))))
        self.horizon_ms = None

    def finished(self, elapsed: int, ip_active: bool) -> bool:
        # record N-1 is reached at N periods, plus one for each SYNC the drive held through
        return elapsed >= len(self.records) + self.held_syncs and (self.all_sent or not self.enabled)


class RecordRefusedError(Exception):
    """A ``send`` that offers a record once: the transmit queue has no room for it now."""


def top_up_by_need(feeders: Sequence[Feeder], allowance: RecordAllowance) -> BufferFeeder | None:
    """Hand this period's allowance out one record at a time, each to the buffered axis whose FIFO is
    lowest (after ``on_sync`` moved every feeder's clock), until it is spent or every FIFO is at its mark.
    A record its ``send`` refuses (``RecordRefusedError``: offered once, the queue full) stays the next one
    and its allowance is given back: it goes at a later top-up; the feeder it belongs to is returned
    (None: nothing refused), so that the caller judges its FIFO against the reserve."""
    wanting = [f for f in feeders if isinstance(f, BufferFeeder) and f.wants and not f.mirrored]
    while wanting and allowance.take():
        feeder = min(wanting, key=lambda f: f.level)
        try:
            feeder._send_next()
        except RecordRefusedError:
            allowance.left += 1
            return feeder
        feeder.stats.level(feeder.level)
        wanting = [f for f in wanting if f.wants]
    return None


def preload_shared(feeders: Sequence[Feeder], allowance: RecordAllowance) -> bool:
    """This period's share of every buffered axis's preload, one record each in turn while the
    allowance lasts; True once every preload is out."""
    pending = [f for f in feeders if isinstance(f, BufferFeeder) and not f.preloaded]
    while pending and allowance.left > 0:
        for feeder in pending:
            feeder.preload(1)
        pending = [f for f in pending if not f.preloaded]
    return not pending
