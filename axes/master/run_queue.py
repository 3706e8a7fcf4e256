"""Programs queued on a running run: the next one starts where the last ends, on the same time line.

A queued program is not a new start: no halt, no cleanup, no start word. Every feeder goes on with
its records (``Feeder.extend``): an EPOS2 runs on from the last record of one program into the
first of the next in its FIFO, on its own clock; a fixed-period drive gets the next setpoints on the
SYNCs that follow. So the axes stand still between two queued programs only as long as the programs
themselves say (their end at rest, the EPOS2's start dwell), never for a SYNC period more.

The one thing that cannot be taken back is the EPOS2's end record (time 0: the drive ends
interpolation there). Each buffered feeder holds it until the drive's clock is ``end_hold_ms`` from
the end: the drives' own watch of the master's heartbeat (0x1016, ``master_consumer_time_ms``) plus
two SYNC periods. A master silent for longer than that is lost to the drives anyway (they quick stop
on it), so the hold costs a run nothing a stalled master would not cost it; it is the time until
which a program can still be queued.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.master.group.feeder import BufferFeeder, Extension, Feeder
from pvtflow.axes.master.group.outcome import GroupError

OnStart = Callable[[int], None]  # called with the run's elapsed SYNCs when the queued program's t = 0 is passed


def end_hold_ms(bus: BusConfig) -> float:
    """How long before the end the EPOS2's end record goes out (the module docstring says why)."""
    return float(bus.master_consumer_time_ms) + 2.0 * bus.sync_period_ms


@dataclass
class QueuedProgram:
    """A program appended to the run: where its t = 0 is on the run's time line."""

    program: PvtProgram
    start_ms: int  # from the run's start SYNC
    start_syncs: int  # the SYNC (elapsed since the start SYNC) on or after its t = 0
    on_start: OnStart | None
    started: bool = False


class RunQueue:
    """The programs of one run after its first, in order, and where the last one ends."""

    def __init__(self, bus: BusConfig) -> None:
        self.bus = bus
        self.hold_ms = end_hold_ms(bus)
        self.entries: list[QueuedProgram] = []
        self.last: list[AxisProgram] = []  # the last program's axes, in axis order
        self.end_ms = 0

    def begin(self, programs: Sequence[AxisProgram], feeders: Sequence[Feeder]) -> None:
        """A new run: no queue; its buffered feeders hold their end record (the module docstring)."""
        self.entries = []
        self.last = list(programs)
        self.end_ms = max((p.duration_ms for p in programs), default=0)
        for feeder in feeders:
            if isinstance(feeder, BufferFeeder):
                feeder.hold_end(self.hold_ms)

    def refusal(self, programs: Sequence[AxisProgram], feeders: Sequence[Feeder], elapsed_ms: float) -> str | None:
        """Why ``programs`` (axis order) cannot follow the last program of the run now (None: they can)."""
        ends = {p.duration_ms for p in self.last}
        if len(ends) != 1:
            return "the running program's axes end at different times: nothing can follow it on one time line"
        left = self.end_ms - elapsed_ms
        if left <= self.hold_ms or any(f.all_sent for f in feeders):
            return (
                f"the run ends in {max(left, 0.0):.0f} ms: a program is queued at least {self.hold_ms:.0f} ms "
                "before the end (the drives' end record goes out then); execute it once the run has ended"
            )
        for last, nxt in zip(self.last, programs, strict=True):
            end, start = int(last.records[-1, 0]), int(nxt.records[0, 0])
            if start != end:
                return (
                    f"axis {last.node_id}: the queued program starts at {start} qc, "
                    f"the one before it ends at {end} qc: it must start where that one ends"
                )
            if int(last.records[-1, 1]) != 0 or int(nxt.records[0, 1]) != 0:
                return f"axis {last.node_id}: the programs must meet at rest (velocity 0 at the end and at the start)"
        return None

    def append(
        self,
        programs: Sequence[AxisProgram],
        program: PvtProgram,
        feeders: Sequence[Feeder],
        extensions: Sequence[Extension],
        elapsed_ms: float,
        on_start: OnStart | None,
        joined_elsewhere: bool = False,
    ) -> QueuedProgram:
        """Every feeder goes on with ``programs`` (axis order) after what it has, by its ``extensions``
        (made from these programs); GroupError (nothing changed) when they cannot follow now (``refusal``).
        ``joined_elsewhere``: the cyclic process that sends the records has joined them to its feeders (it
        judged them, ``refusal`` passed before it was asked): these feeders only mirror it and follow."""
        why = None if joined_elsewhere else self.refusal(programs, feeders, elapsed_ms)
        if why is None and not joined_elsewhere and not all(e.ready() for e in extensions):
            why = "the run changed while the queued program was being joined to it (a halt, another queue)"
        if why is not None:
            raise GroupError(why)
        for extension in extensions:
            extension.apply()
        period = self.bus.sync_period_ms
        entry = QueuedProgram(program, self.end_ms, math.ceil(self.end_ms / period - 1e-9), on_start)
        self.entries.append(entry)
        self.last = list(programs)
        self.end_ms += max(p.duration_ms for p in programs)
        return entry

    def at_sync(self, elapsed: int) -> None:
        """SYNC ``elapsed`` (since the start SYNC) was answered: the queued programs whose t = 0 it has
        reached are announced, in order (the group's lock held: ``on_start`` hands over, never blocks)."""
        for entry in self.entries:
            if not entry.started and elapsed >= entry.start_syncs:
                entry.started = True
                if entry.on_start is not None:
                    entry.on_start(elapsed)
