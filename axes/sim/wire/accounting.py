"""What a simulated-wire channel carried: per frame its time on the bus, the bus load, the SYNCs.

The medium keeps a record of every frame (start, end, identifier, DLC, sender; the last
``DEFAULT_RECORD_LIMIT`` of them) and of every SYNC's start (and, in lockstep, its nominal time);
from them come the bus load over any interval and per SYNC period, the late SYNCs (lockstep: started
more than ``LATE_FRACTION`` of the period after their nominal time; wall: after the previous SYNC's
start + period) and the intervals between SYNCs. ``WireStats`` gathers them with each node's FIFO
figures, JSON-able so a wire server hands them to its clients.
"""

from __future__ import annotations

import itertools
import threading
from collections import deque
from dataclasses import asdict, dataclass, field

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.axes.sim.wire.node import Node

DEFAULT_RECORD_LIMIT = 500_000  # frames kept for the accounting (about three minutes at 3000 frames/s)
RPDO_COB_IDS = (0x200, 0x57F)  # RPDO1 to RPDO4 of nodes 0-127 (CiA 301 predefined connection set)
LATE_FRACTION = 0.05  # a SYNC later than its nominal time by more than this share of the period is late


@dataclass(frozen=True, slots=True)
class WireFrame:
    start: float
    end: float
    can_id: int
    dlc: int
    sender: str


@dataclass(frozen=True, slots=True)
class LateSync:
    nominal: float  # lockstep: when it was due; wall: the previous SYNC's start + period
    start: float
    lateness: float  # start - nominal, seconds


@dataclass
class WireStats:
    """The medium's accounting, JSON-able (``asdict``) so a server can hand it to a client."""

    channel: str
    clock: str
    bitrate: int
    sync_period: float | None
    frames: int
    bits: int
    first_start: float | None
    last_end: float | None
    mean_load: float  # busy time / (last_end - first_start)
    period_loads: list[float]  # load of each SYNC period from the first frame on (empty without a period)
    late_syncs: list[LateSync]
    sync_intervals: list[float]  # between consecutive SYNC starts
    enobufs: dict[str, int]
    max_fifo_depth: dict[str, int]
    error_frames: int
    # per receive-PDO COB-ID (hex, RPDO1-4: 0x200-0x57F, what a master sends its drives after SYNC):
    # each frame's end, when the drives have it, after the start of the SYNC before it, in seconds
    rpdo_after_sync: dict[str, list[float]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> WireStats:
        return cls(**{**data, "late_syncs": [LateSync(**s) for s in data["late_syncs"]]})


class Accounting:
    """What one channel carried, owned by its ``Medium``: the medium tells it each frame as it leaves
    the wire (``frame``), each SYNC as it starts (``sync``), each error frame and each node that
    leaves; it keeps the records and counts, under the medium's lock (``cond``, given)."""

    def __init__(
        self,
        *,
        channel: str,
        clock: Clock,
        bitrate: int,
        sync_period: float | None,
        cond: threading.Condition,
        nodes: list[Node],
        record_limit: int = DEFAULT_RECORD_LIMIT,
    ) -> None:
        self.channel = channel
        self.clock = clock
        self.bitrate = bitrate
        self.sync_period = sync_period
        self._cond = cond
        self._nodes = nodes  # the medium's own list: the nodes on the channel now
        self._records: deque[WireFrame] = deque(maxlen=record_limit)
        self._syncs: deque[tuple[float, float]] = deque(maxlen=record_limit)  # (nominal or nan, start)
        self._frames = 0
        self._bits = 0
        self._error_frames = 0
        self._departed: dict[str, tuple[int, int]] = {}  # name: (ENOBUFS, max FIFO depth) of nodes that left

    # -- what the medium tells it (under its lock) ------------------------------------------------

    def frame(self, sender: str, can_id: int, dlc: int, bits: int, start: float, end: float) -> None:
        self._frames += 1
        self._bits += bits
        self._records.append(WireFrame(start, end, can_id, dlc, sender))

    def sync(self, nominal: float, start: float) -> None:
        """A SYNC started at ``start``; ``nominal``: when it was due (lockstep), nan on the wall clock."""
        self._syncs.append((nominal, start))

    def error_frame(self) -> None:
        self._error_frames += 1

    def departed(self, node: Node) -> None:
        """``node`` left the channel: its FIFO figures stay in the accounting."""
        enobufs, depth = self._departed.get(node.name, (0, 0))
        self._departed[node.name] = (enobufs + node.enobufs, max(depth, node.max_depth))

    # -- what it tells ------------------------------------------------------------------------------

    def records(self) -> list[WireFrame]:
        with self._cond:
            return list(self._records)

    def load(self, t0: float, t1: float) -> float:
        """Share of [t0, t1) the bus was busy (frames clipped to the interval)."""
        return _load(self.records(), t0, t1)

    def period_loads(self, period: float | None = None) -> list[float]:
        """Load of each consecutive ``period`` (default the SYNC period) from the first frame on."""
        return _period_loads(self.records(), period or self.sync_period)

    def sync_intervals(self) -> list[float]:
        with self._cond:
            starts = [s for _, s in self._syncs]
        return [b - a for a, b in itertools.pairwise(starts)]

    def late_syncs(self, fraction: float = LATE_FRACTION) -> list[LateSync]:
        """Lockstep: SYNCs that started more than ``fraction`` of the period after their nominal time.
        Wall: SYNCs that started more than that after the previous SYNC's start + period."""
        period = self.sync_period
        with self._cond:
            syncs = list(self._syncs)
        if period is None:
            return []
        late: list[LateSync] = []
        for i, (nominal, start) in enumerate(syncs):
            if self.clock is Clock.WALL:
                if i == 0:
                    continue
                nominal = syncs[i - 1][1] + period
            if start - nominal > fraction * period:
                late.append(LateSync(nominal, start, start - nominal))
        return late

    def stats(self) -> WireStats:
        records = self.records()
        with self._cond:
            frames, bits, error_frames = self._frames, self._bits, self._error_frames
            enobufs = {name: count for name, (count, _) in self._departed.items()}
            depth = {name: most for name, (_, most) in self._departed.items()}
            for n in self._nodes:
                enobufs[n.name] = enobufs.get(n.name, 0) + n.enobufs
                depth[n.name] = max(depth.get(n.name, 0), n.max_depth)
        first = records[0].start if records else None
        last = records[-1].end if records else None
        return WireStats(
            channel=self.channel,
            clock=self.clock.value,
            bitrate=self.bitrate,
            sync_period=self.sync_period,
            frames=frames,
            bits=bits,
            first_start=first,
            last_end=last,
            mean_load=_load(records, first, last) if records and last > first else 0.0,
            period_loads=_period_loads(records, self.sync_period),
            late_syncs=self.late_syncs(),
            sync_intervals=self.sync_intervals(),
            enobufs=enobufs,
            max_fifo_depth=depth,
            error_frames=error_frames,
            rpdo_after_sync=_rpdo_after_sync(records),
        )


def _rpdo_after_sync(records: list[WireFrame]) -> dict[str, list[float]]:
    after: dict[str, list[float]] = {}
    sync_start: float | None = None
    for r in records:
        if r.can_id == SYNC_COB_ID:
            sync_start = r.start
        elif RPDO_COB_IDS[0] <= r.can_id <= RPDO_COB_IDS[1] and sync_start is not None:
            after.setdefault(f"0x{r.can_id:03X}", []).append(r.end - sync_start)
    return after


def _load(records: list[WireFrame], t0: float, t1: float) -> float:
    if t1 <= t0:
        raise ValueError(f"an interval needs t1 > t0, got [{t0}, {t1})")
    busy = sum(max(0.0, min(r.end, t1) - max(r.start, t0)) for r in records)
    return busy / (t1 - t0)


def _period_loads(records: list[WireFrame], period: float | None) -> list[float]:
    if not records or period is None:
        return []
    origin = records[0].start
    count = int((records[-1].end - origin) / period) + 1
    busy = [0.0] * count
    for r in records:
        i = int((r.start - origin) / period)
        t = r.start
        while t < r.end and i < count:  # a frame may straddle a period boundary
            edge = origin + (i + 1) * period
            busy[i] += min(r.end, edge) - t
            t, i = edge, i + 1
    return [b / period for b in busy]
