"""Whether the bus feeds a program's records as fast as the drives run them, known before the start.

An EPOS2 runs its records on its own clock; the master sends at most the cell's record allowance
per SYNC period (``axes.master.budget``, shared by the buffered axes: ``axes.master.group.feeder.top_up_by_need``). A
program whose records are shorter than that allowance lasts empties the drive's FIFO (64 records)
mid-motion: an underflow error, the axis faults while the others move. ``feed_shortfall`` replays
the start and the feed with the feeders themselves (``BufferFeeder``, ``RecordAllowance``,
``preload``, ``top_up_by_need``: the same code the run uses, nothing sent) against the drives'
clocks, one SYNC period per SYNC, and says where a FIFO would run dry. The replay is exact for the
master's own schedule; the drives' warnings (which only correct the master's estimate) play no part.
A program none of whose records past the preload is shorter than its axis's even share of the
allowance (period x buffered axes / allowance) needs no replay: the allowance covers every period.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.master.group.feeder import PRELOAD_MS, BufferFeeder, RecordAllowance, top_up_by_need

LOOK_BACK_MS = 100.0  # the stretch of records before a shortfall the message averages


@dataclass(frozen=True)
class BufferedAxis:
    """One EPOS2 axis of a program: its name, its records (position, velocity, time ms), its FIFO marks."""

    name: str
    records: NDArray[np.int64]
    buffer: BufferConfig


def _within_share(records: NDArray[np.int64], share_ms: float) -> bool:
    """Every record past the preload lasts at least ``share_ms``: the axis never needs more than its
    even share of the allowance in a period, so no replay is needed (the common case)."""
    times = records[:, 2].astype(float)
    starts = np.cumsum(times) - times
    later = (starts >= PRELOAD_MS) & (times > 0)
    return bool(np.all(times[later] >= share_ms))


def _send_nothing(cob_id: int, data: bytes) -> None:
    """The replay's frames go nowhere."""


def _no_frame(record: NDArray[np.int64]) -> tuple[int, bytes]:
    return 0, b""


def feed_shortfall(axes: Sequence[BufferedAxis], per_sync: int, period_ms: float) -> str | None:
    """Why the bus cannot feed these axes' records in time (which axis, when, its records' time
    against what the allowance gives it), or None: every FIFO keeps a record ahead to the end."""
    if not axes or all(_within_share(a.records, period_ms * len(axes) / per_sync) for a in axes):
        return None
    allowance = RecordAllowance(per_sync)
    feeders = [
        BufferFeeder(a.records, _no_frame, _send_nothing, period_ms, a.buffer, allowance=allowance) for a in axes
    ]
    for feeder in feeders:
        feeder.preload(whole=True)
    longest = max(f.duration_ms for f in feeders)
    periods = int(np.ceil(longest / period_ms)) + 1
    for k in range(periods + 1):
        for feeder in feeders:
            feeder.on_sync(k)
        for axis, feeder in zip(axes, feeders, strict=True):
            if not feeder.all_sent and feeder.level < 1:
                return _message(axis, feeder, k * period_ms, per_sync, len(axes), period_ms)
        if all(f.all_sent for f in feeders):
            return None
        allowance.new_period()
        top_up_by_need(feeders, allowance)
    return None


def _message(
    axis: BufferedAxis, feeder: BufferFeeder, t_ms: float, per_sync: int, buffered: int, period_ms: float
) -> str:
    times = axis.records[:, 2].astype(float)
    ends = np.cumsum(times)
    recent = (ends > t_ms - LOOK_BACK_MS) & (ends <= t_ms)
    mean = float(times[recent].mean()) if recent.any() else float(times[feeder.next - 1])
    share = period_ms * buffered / per_sync
    return (
        f"axis {axis.name}: its records last {mean:.2g} ms on average in the {LOOK_BACK_MS:g} ms before t = "
        f"{t_ms:g} ms, where its buffer would run dry: the bus feeds {per_sync} record(s) per {period_ms:g} ms "
        f"SYNC period shared by {buffered} EPOS2 axis/axes (a record per {share:.2g} ms each); plan with longer "
        "records (a coarser knot spacing), or give the cell more records per SYNC (bus.records_per_sync, a "
        "higher bus.bitrate, a longer bus.tx_queue_frames)"
    )
