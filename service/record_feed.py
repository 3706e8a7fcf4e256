"""Whether the cell's bus feeds a plan's EPOS2 records as fast as the drives run them, at plan time.

The start checks it too (``axes.master.feed_check`` through ``AxisGroup.check_program``) and refuses a
program whose FIFO would run dry; the planner asks first, so that where the time-optimal plan needs
more records than the bus carries it can give motion time for fewer records (``planner.speed_band``)
and say so, and nowhere else (``CellPlanner.plan``).
"""

from __future__ import annotations

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.budget import bus_budget
from pvtflow.axes.master.feed_check import BufferedAxis, feed_shortfall
from pvtflow.service.config import CellConfig


class RecordFeed:
    """The cell's record allowance per SYNC period and its EPOS2 axes' FIFOs, fixed when it is built."""

    def __init__(self, cell: CellConfig) -> None:
        self.per_sync = bus_budget(cell).record_allowance  # as the run's AxisGroup takes it
        self.period_ms = float(cell.bus.sync_period_ms)
        self.buffers = {a.joint: a.buffer for a in cell.axes}

    def shortfall(self, program: PvtProgram) -> str | None:
        """Where a FIFO of ``program``'s buffered axes would run dry (``axes.master.feed_check``), or None."""
        buffered = [
            BufferedAxis(a.joint, a.records, self.buffers[a.joint]) for a in program.axes if not a.profile.fixed_period
        ]
        return feed_shortfall(buffered, self.per_sync, self.period_ms)
