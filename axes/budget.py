"""A cell's traffic per SYNC period, computed from its configuration before anything opens.

``bus_budget(wiring) -> BusBudget``: every frame the cell puts on its bus in one SYNC period, costed in
bits (``axes.frame_time``), against what the bus carries in that period (bit rate x SYNC period):

- the SYNC (exact bits) and, with ``bus.time_stamp``, the master's 0x1013 time stamp after it;
- every RPDO and TPDO of every axis as its profile maps them (``Profile.rpdos`` / ``tpdos``, counted by
  ``PdoLayout.frames_per_sync``): a synchronous TPDO of transmission type n once every n SYNCs, an
  event-driven one once per inhibit time, a fixed-period setpoint every SYNC, the controlword once
  (the period of a start, a halt or an end has one on every axis);
- the EPOS2 records: the cell's record allowance per SYNC (``bus.records_per_sync``, or the room left
  under the limit, shared by every buffered axis: ``axes.feeder.RecordAllowance``), and never more
  than the master's transmit queue holds besides the SYNC, time stamp and setpoints it sends with
  them (``bus.tx_queue_frames``: SocketCAN refuses the rest with ENOBUFS);
- the heartbeats of every drive and of the master, per their periods;
- room for one EMCY and one SDO exchange (request and answer) in every period.

Frames whose content is not known in advance are costed at their worst stuffing
(``worst_frame_bits``). ``fraction`` is the average over the PDOs' transmission types (what a window of
periods carries), ``peak_fraction`` the most one period can carry (every synchronous PDO in it).

A cell loads only if ``fraction`` <= ``LOAD_LIMIT`` (70 %: a CAN bus loaded beyond it delays the low
priority frames by whole periods; the remaining 30 % is where retransmissions after errors go) and
``peak_fraction`` <= 1, and only with room for at least one record per buffered axis per period (a
program whose records last at least a SYNC period on average is then fed as fast as it runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from axes.config import CellWiring
from axes.frame_time import frame_bits, worst_frame_bits
from axes.objects import EPOS2_TIME_STAMP_RPDO, SYNC_COB_ID, PdoLayout, PdoRole
from axes.profiles import profile_class

LOAD_LIMIT = 0.70
RECORD_BITS = worst_frame_bits(8)  # an EPOS2 record: 8 data bytes, any content
HEARTBEAT_BITS = worst_frame_bits(1)
EMCY_BITS = worst_frame_bits(8)
SDO_EXCHANGE_BITS = 2 * worst_frame_bits(8)  # an expedited request and its answer


@dataclass(frozen=True)
class BudgetItem:
    """One kind of frame: how many per SYNC period (on average, and at most in one period), bits each."""

    name: str
    frames: float
    peak_frames: float
    bits_per_frame: int

    @property
    def bits(self) -> float:
        return self.frames * self.bits_per_frame

    @property
    def peak_bits(self) -> float:
        return self.peak_frames * self.bits_per_frame


@dataclass(frozen=True)
class BusBudget:
    """A cell's bus traffic per SYNC period, item by item, against what the bus carries in one."""

    bitrate: int
    sync_period_ms: float
    items: tuple[BudgetItem, ...]
    records_per_sync: int  # the cell's record allowance (0: no buffered axis)
    buffered_axes: int  # axes fed records (EPOS2)
    records_derived: bool  # the allowance is the room the limit leaves (not the cell's own figure)
    queued_after_sync: int = 0  # the master's frames right after a SYNC besides records
    tx_queue_frames: int = 10  # the master's transmit queue

    @property
    def capacity_bits(self) -> float:
        return self.bitrate * self.sync_period_ms / 1000.0

    @property
    def total_bits(self) -> float:
        return sum(i.bits for i in self.items)

    @property
    def peak_bits(self) -> float:
        return sum(i.peak_bits for i in self.items)

    @property
    def fraction(self) -> float:
        return self.total_bits / self.capacity_bits

    @property
    def peak_fraction(self) -> float:
        return self.peak_bits / self.capacity_bits

    def problem(self) -> str | None:
        """Why the cell does not fit its bus, with the figure and what to change (None: it fits)."""
        what = f"{self.total_bits:.0f} bits per {self.sync_period_ms:g} ms SYNC period on a {self.bitrate} bit/s bus"
        biggest = ", ".join(f"{i.name} {i.bits:.0f}" for i in sorted(self.items, key=lambda i: -i.bits)[:4])
        fixes = "a longer bus.sync_period_ms, a higher bus.bitrate"
        if self.buffered_axes and not self.records_derived:
            fixes += ", fewer bus.records_per_sync"
        if self.buffered_axes and self.records_per_sync < self.buffered_axes:
            return (
                f"no room for one record per EPOS2 axis per SYNC period: {self.records_per_sync} record(s) for "
                f"{self.buffered_axes} axes within {LOAD_LIMIT:.0%} of the bus ({what} before records; {biggest}): "
                f"needs {fixes}"
            )
        burst = self.queued_after_sync + self.records_per_sync
        if burst > self.tx_queue_frames:
            return (
                f"the master sends {burst} frames right after a SYNC ({self.records_per_sync} records, "
                f"{self.queued_after_sync} SYNC, time stamp and setpoints), more than its transmit queue holds "
                f"(bus.tx_queue_frames {self.tx_queue_frames}): needs fewer bus.records_per_sync or a longer queue"
            )
        if self.fraction > LOAD_LIMIT:
            return (
                f"the cell's traffic takes {self.fraction:.0%} of the bus ({what}; {biggest}), above the "
                f"{LOAD_LIMIT:.0%} a cell may use: needs {fixes}"
            )
        if self.peak_fraction > 1.0:
            return (
                f"one SYNC period can carry {self.peak_fraction:.0%} of the bus ({self.peak_bits:.0f} bits when every "
                f"synchronous PDO falls in it; {biggest}): needs {fixes}"
            )
        return None

    def describe(self) -> str:
        lines = [f"{i.name:36} {i.frames:7.2f} frames x {i.bits_per_frame:3d} bits = {i.bits:7.1f}" for i in self.items]
        lines.append(
            f"{'total':36} {self.total_bits:.0f} of {self.capacity_bits:.0f} bits per period: {self.fraction:.1%} "
            f"(peak {self.peak_fraction:.1%})"
        )
        return "\n".join(lines)


def _pdo_item(name: str, layout: PdoLayout) -> BudgetItem:
    frames, peak = layout.frames_per_sync()
    return BudgetItem(name, frames, peak, worst_frame_bits(layout.payload_bytes))


def bus_budget(wiring: CellWiring) -> BusBudget:
    """The cell's traffic per SYNC period (see the module docstring)."""
    bus = wiring.bus
    period = bus.sync_period_ms
    items = [BudgetItem("SYNC", 1, 1, frame_bits(SYNC_COB_ID))]
    if bus.time_stamp:
        items.append(BudgetItem("time stamp 0x1013", 1, 1, worst_frame_bits(EPOS2_TIME_STAMP_RPDO.payload_bytes)))
    buffered = 0
    queued = 1 + int(bus.time_stamp)  # the master's frames right after a SYNC: SYNC, time stamp, setpoints
    for axis in wiring.axes:
        profile = profile_class(axis.profile)
        for kind, layouts in (("RPDO", profile.rpdos), ("TPDO", profile.tpdos)):
            for layout in layouts:
                if layout.role is PdoRole.RECORD:
                    buffered += 1
                    continue
                if layout.role is PdoRole.SETPOINT:
                    queued += 1
                items.append(_pdo_item(f"node {axis.node_id} {kind}{layout.number} {layout.role}", layout))
    beats = len(wiring.axes) * period / bus.heartbeat_ms + period / bus.master_heartbeat_ms
    items.append(BudgetItem("heartbeats", beats, math.ceil(beats), HEARTBEAT_BITS))
    items.append(BudgetItem("EMCY (reserved)", 1, 1, EMCY_BITS))
    items.append(BudgetItem("SDO exchange (reserved)", 1, 1, SDO_EXCHANGE_BITS))
    records, derived = 0, False
    if buffered:
        records, derived = bus.records_per_sync or 0, bus.records_per_sync is None
        if derived:
            room = LOAD_LIMIT * bus.bitrate * period / 1000.0 - sum(i.bits for i in items)
            # as many as the bus carries, and as the master's transmit queue holds after the SYNC
            records = max(0, min(math.floor(room / RECORD_BITS), bus.tx_queue_frames - queued))
        items.append(BudgetItem(f"records ({buffered} EPOS2 axes)", records, records, RECORD_BITS))
    return BusBudget(bus.bitrate, period, tuple(items), records, buffered, derived, queued, bus.tx_queue_frames)
