"""Changing a running program from a moment on: the records not yet sent are replaced (issue 37).

What a drive already holds cannot be taken back: an EPOS2 runs the records in its FIFO on its own clock, a
fixed-period drive the setpoints it was sent. So a change of the motion (an on-path stop, a pause, a speed
override) begins at ``t0``: the end of the last record every drive holds, at least ``lead_ms`` beyond the
drives' clock (the time the change's records take to compute), on the grid of every axis's records. Each
axis keeps its records that end by ``t0`` and gets new ones from the end of its last kept record on
(``SpliceAt.join_ms``): the EPOS2's FIFO joins them after the last one it holds, a fixed-period feeder
switches its source there. The feeders keep what the drives hold within the cell's ``max_lookahead_ms``
(``BufferFeeder.lookahead_ms``), so ``t0`` is at most that far ahead.

The group's lock is held while the new records are made: in lockstep the drives' clock waits for them; on
the wall clock the drives run on, and a change whose records come too late for a drive is refused
(``SpliceLateError``) before anything is replaced, the caller then stops the motion the quick way. With
``bus.cyclic_process`` the records go out from the cyclic process: it holds its feeders at t0 and says where
they stand (``CyclicProcess.hold``), and gets the new records as the master's mirrors of its feeders do.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import AxisProgram
from pvtflow.axes.master.bus.sync import CyclicPath
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, SetpointFeeder
from pvtflow.axes.master.group.run import Run

# how long a change waits for the cyclic process to say where its feeders stand (``CyclicProcess.hold``): a pipe
# message each way and a few arithmetic steps; on a host so loaded that it takes longer the change is refused
HOLD_ANSWER_S = 0.05


class SpliceRefusedError(Exception):
    """The running program cannot be changed (nothing runs, it is ending, or its feeders are elsewhere)."""


class SpliceLateError(SpliceRefusedError):
    """The new records were made too late for a drive: nothing was replaced."""


@dataclass(frozen=True)
class SpliceAt:
    """Where a running program changes: program times in ms from the start SYNC."""

    t0_ms: float  # the motion is the old one until here on every axis
    now_ms: float  # the drives' clock when the change was asked for
    first: tuple[int, ...]  # per axis: its first record replaced (the ones before it are kept)
    join_ms: tuple[float, ...]  # per axis: the end of its last kept record, where its new records begin
    programs: tuple[AxisProgram, ...]  # the axes' programs as they run, in axis order
    start_sync: int  # the SYNC the program started on
    sync_period_ms: float

    def sync_at(self, t_ms: float) -> int:
        """The SYNC at program time ``t_ms`` (rounded up to a whole SYNC)."""
        return self.start_sync + math.ceil(t_ms / self.sync_period_ms - 1e-9)


Make = Callable[[SpliceAt], Sequence[NDArray[np.int64]]]


def record_grid_ms(programs: Sequence[AxisProgram], sync_period_ms: float) -> int:
    """The grid every axis's records end on: whole ms, each fixed-period axis's period, and the SYNC period
    where it is whole ms (so that a change that ends the motion ends it on a SYNC)."""
    grid = 1
    periods = [int(p.records[0, 2]) for p in programs if p.profile.fixed_period]
    if float(sync_period_ms).is_integer():
        periods.append(int(sync_period_ms))
    for p in periods:
        grid = math.lcm(grid, max(1, p))
    return grid


def _held_end_ms(feeder: BufferFeeder | SetpointFeeder) -> float:
    """The end of the last record the drive holds (program time)."""
    return float(feeder.records[: feeder.next, 2].sum())


def splice_run(run: Run, make: Make, lead_ms: float | None = None) -> SpliceAt:
    """Replace the running program's records from ``t0`` on by ``make(at)`` (per axis: the records from
    ``at.first[i]`` on, beginning where the axis's record ``first[i] - 1`` ends); the point it was made at.

    ``lead_ms``: how far beyond the drives' clock ``t0`` lies at least (default: the cell's look-ahead
    bound). What ``make`` raises is raised from here, with nothing replaced."""
    bus = run.parts.bus
    sync = bus.sync
    period = float(bus.config.sync_period_ms)
    lead = float(bus.config.max_lookahead_ms if lead_ms is None else lead_ms)
    lock = run.parts.lock
    cyclic = sync.cyclic if sync.cyclic_producing else None  # the records go out from the cyclic process
    with sync.lock:
        lock.acquire()
        try:
            feeders = run.feeders
            if not run.live or run.ending is not None or run.start_sync is None:
                raise SpliceRefusedError("no motion runs")
            if cyclic is None and any(f.mirrored for f in feeders):
                raise SpliceRefusedError("the records are sent by a cyclic process that no longer runs")
            programs = tuple(
                AxisProgram.of(p, f.records[: len(f.records) - 1] if isinstance(f, BufferFeeder) else f.records)
                for p, f in zip(run.programs, feeders, strict=True)
            )  # as the feeders hold them (an EPOS2's long segments cut: ``split_long_records``)
            now = run.drive_clock_ms()
            grid = record_grid_ms(programs, period)
            held = max(_held_end_ms(f) for f in feeders)
            t0 = math.ceil(max(held, now + lead) / grid - 1e-9) * grid
        except BaseException:
            lock.release()
            raise
    try:
        if cyclic is not None:  # its feeders hold from t0 (later where it has sent more), the mirrors follow
            try:
                t0, _ = cyclic.hold(float(t0), grid, HOLD_ANSWER_S)
            except TimeoutError as exc:
                cyclic.splice(None)
                raise SpliceRefusedError(str(exc)) from None
        for f in feeders:
            f.hold_to(float(t0))
    except BaseException:
        lock.release()
        raise
    try:
        first: list[int] = []
        joins: list[float] = []
        for f in feeders:
            ends = np.cumsum(f.records[:, 2])
            j = int(np.searchsorted(ends, t0 + 1e-9, side="right"))  # the records ending by t0 are kept
            j = max(j, 1)
            if isinstance(f, BufferFeeder):
                j = min(j, len(f.records) - 1)  # the end record is never kept in place of the motion
            first.append(j)
            joins.append(float(ends[j - 1]))
        at = SpliceAt(float(t0), now, tuple(first), tuple(joins), programs, int(run.start_sync), period)
        try:
            rows = list(make(at))
        except BaseException:
            _release(feeders, cyclic)
            raise
        late = _too_late(run, at, feeders, period)
        if late is not None:
            _release(feeders, cyclic)
            raise SpliceLateError(late)
        if cyclic is not None:
            cyclic.splice(list(zip(at.first, rows, strict=True)))
        for i, (f, r) in enumerate(zip(feeders, rows, strict=True)):
            f.replace_from(at.first[i], r)
            kept = programs[i].records[: at.first[i]]
            run.take_program(i, AxisProgram.of(programs[i], np.concatenate((kept, r))))
        return at
    finally:
        lock.release()


def _release(feeders: Sequence[Feeder], cyclic: CyclicPath | None) -> None:
    """The change was not made: the held records go out as they were."""
    for f in feeders:
        f.hold_to(None)
    if cyclic is not None:
        cyclic.splice(None)


def _too_late(run: Run, at: SpliceAt, feeders: Sequence[Feeder], period: float) -> str | None:
    """Why the new records come too late for a drive (None: they are in time): an EPOS2 must get them
    a SYNC period before it runs out of records, a fixed-period drive its next setpoint before the
    SYNC that validates it."""
    now = run.drive_clock_ms()
    for f, join, prog in zip(feeders, at.join_ms, at.programs, strict=True):
        need = join - period
        if isinstance(f, SetpointFeeder):
            need = join - (f.lead + 1) * float(prog.records[0, 2])
        if now > need:
            return (
                f"{prog.joint}: the new records were ready at {now:.1f} ms, the drive needed them by {need:.1f} ms "
                f"(t0 {at.t0_ms:.0f} ms)"
            )
    return None
