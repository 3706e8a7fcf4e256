"""A cell's traffic per SYNC period, computed from its configuration before anything opens.

``bus_budget(wiring) -> BusBudget``: every frame the cell puts on its bus in one SYNC period, costed in
bits (``axes.canbus.frame_time``), against what the bus carries in that period (bit rate x SYNC period):

- the SYNC (exact bits) and, with ``bus.time_stamp``, the master's 0x1013 time stamp after it;
- every RPDO and TPDO of every axis as its profile maps them (``Profile.rpdos`` / ``tpdos``, counted by
  ``PdoLayout.frames_per_sync``): a synchronous TPDO of transmission type n once every n SYNCs, an
  event-driven one once per inhibit time, a fixed-period setpoint every SYNC, the controlword once
  (the period of a start, a halt or an end has one on every axis);
- the EPOS2 records: the cell's record allowance per SYNC (``bus.records_per_sync``, or the room left
  under the limit, shared by every buffered axis: ``axes.master.group.feeder.RecordAllowance``), and never more
  than the master's transmit queue holds besides the SYNC, time stamp and setpoints it sends with
  them (``bus.tx_queue_frames``: SocketCAN refuses the rest with ENOBUFS);
- the heartbeats of every drive and of the master, per their periods;
- room for one EMCY and one SDO exchange (request and answer) in every window of ``WINDOW_PERIODS``
  periods. They are not scheduled, so no single period claims them: the frames they push out of a
  full period go out in the window's idle time.

Frames whose content is not known in advance are costed at their worst stuffing
(``worst_frame_bits``). Each item counts its frames three ways: on average per period
(``fraction``, what ``describe`` shows), at most in one period (``peak_fraction``: every synchronous
PDO due in it, a controlword on every axis, every heartbeat that can fall in it, a full record allowance)
and at most in a window of ``WINDOW_PERIODS`` consecutive periods (``window_fraction``: a TPDO of
type n ceil(10 / n) times, an event TPDO once per inhibit time, the controlword at most
``CONTROLWORDS_PER_WINDOW`` times per axis: start, halt, end).

A cell loads only if ``window_fraction`` <= ``LOAD_LIMIT`` (70 %: a CAN bus loaded beyond it delays
the low priority frames by whole periods; the remaining 30 % is where retransmissions after errors
go) and ``peak_fraction`` <= 1 (no period carries more than the bus, the start included: the feeders'
preload and top-up keep to the record allowance in every period, ``axes.master.group.feeder``), and only with
room for at least one record per buffered axis per period. The 70 % is a window's and not every
period's: a reserve for an SDO exchange in every period would by itself take 40 % of a 1 Mbit/s bus
at 1 ms. Whether a program's records are fed as fast as it runs is the program's question
(``axes.master.feed_check``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pvtflow.axes.canbus.frame_time import frame_bits, worst_frame_bits
from pvtflow.axes.drive.config import CellWiring
from pvtflow.axes.drive.objects import EPOS2_TIME_STAMP_RPDO, SYNC_COB_ID, PdoLayout, PdoRole
from pvtflow.axes.master.profiles import profile_class
from pvtflow.axes.master.tpdo_rates import with_rates

LOAD_LIMIT = 0.70
RECORD_BITS = worst_frame_bits(8)  # an EPOS2 record: 8 data bytes, any content
HEARTBEAT_BITS = worst_frame_bits(1)
EMCY_BITS = worst_frame_bits(8)
SDO_EXCHANGE_BITS = 2 * worst_frame_bits(8)  # an expedited request and its answer
WINDOW_PERIODS = 10  # the window the 70 % rule holds over
CONTROLWORDS_PER_WINDOW = 3  # per axis: a start, a halt and an end can fall in one window


@dataclass(frozen=True)
class BudgetItem:
    """One kind of frame: how many per SYNC period on average, at most in one period and at most in a
    window of ``WINDOW_PERIODS`` periods, bits each."""

    name: str
    frames: float
    peak_frames: float
    bits_per_frame: int
    window_frames: float

    @classmethod
    def every_period(cls, name: str, frames: float, bits_per_frame: int) -> BudgetItem:
        """As many frames in every period (SYNC, time stamp, setpoints, records)."""
        return cls(name, frames, frames, bits_per_frame, frames * WINDOW_PERIODS)

    @property
    def bits(self) -> float:
        return self.frames * self.bits_per_frame

    @property
    def peak_bits(self) -> float:
        return self.peak_frames * self.bits_per_frame

    @property
    def window_bits(self) -> float:
        return self.window_frames * self.bits_per_frame


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
    def record_allowance(self) -> int:
        """Records the run's feeders share per SYNC period: at least one per EPOS2 axis, never none."""
        return max(1, self.records_per_sync, self.buffered_axes)

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
    def window_bits(self) -> float:
        return sum(i.window_bits for i in self.items)

    @property
    def fraction(self) -> float:
        return self.total_bits / self.capacity_bits

    @property
    def window_fraction(self) -> float:
        return self.window_bits / (WINDOW_PERIODS * self.capacity_bits)

    @property
    def peak_fraction(self) -> float:
        return self.peak_bits / self.capacity_bits

    def problem(self) -> str | None:
        """Why the cell does not fit its bus, with the figure and what to change (None: it fits)."""
        what = (
            f"{self.window_bits:.0f} bits per {WINDOW_PERIODS} SYNC periods of {self.sync_period_ms:g} ms on a "
            f"{self.bitrate} bit/s bus"
        )
        biggest = ", ".join(
            f"{i.name} {i.window_bits:.0f}" for i in sorted(self.items, key=lambda i: -i.window_bits)[:4]
        )
        heaviest = ", ".join(f"{i.name} {i.peak_bits:.0f}" for i in sorted(self.items, key=lambda i: -i.peak_bits)[:4])
        fixes = "a longer bus.sync_period_ms, a higher bus.bitrate"
        if self.buffered_axes and not self.records_derived:
            fixes += ", fewer bus.records_per_sync"
        fixes += ", status TPDOs every n SYNCs (bus.status_every_syncs)"
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
        if self.window_fraction > LOAD_LIMIT:
            return (
                f"the cell's traffic takes {self.window_fraction:.0%} of the bus in a window of {WINDOW_PERIODS} "
                f"SYNC periods ({what}; {biggest}), above the {LOAD_LIMIT:.0%} a cell may use: needs {fixes}"
            )
        if self.peak_fraction > 1.0:
            return (
                f"one SYNC period can carry {self.peak_fraction:.0%} of the bus ({self.peak_bits:.0f} bits of "
                f"{self.capacity_bits:.0f} when every synchronous PDO, a controlword per axis and the records fall in "
                f"it; {heaviest}): needs {fixes}"
            )
        return None

    def describe(self) -> str:
        lines = [f"{i.name:36} {i.frames:7.2f} frames x {i.bits_per_frame:3d} bits = {i.bits:7.1f}" for i in self.items]
        lines.append(
            f"{'total':36} {self.total_bits:.0f} of {self.capacity_bits:.0f} bits per period: {self.fraction:.1%} "
            f"(worst {WINDOW_PERIODS}-period window {self.window_fraction:.1%}, worst period {self.peak_fraction:.1%})"
        )
        return "\n".join(lines)


def _pdo_item(name: str, layout: PdoLayout) -> BudgetItem:
    frames, peak = layout.frames_per_sync()
    window = layout.frames_in(WINDOW_PERIODS)
    if layout.role is PdoRole.CONTROLWORD:
        window = CONTROLWORDS_PER_WINDOW
        frames = window / WINDOW_PERIODS
    return BudgetItem(name, frames, peak, worst_frame_bits(layout.payload_bytes), window)


def bus_budget(wiring: CellWiring) -> BusBudget:
    """The cell's traffic per SYNC period (see the module docstring)."""
    bus = wiring.bus
    period = bus.sync_period_ms
    items = [BudgetItem.every_period("SYNC", 1, frame_bits(SYNC_COB_ID))]
    if bus.time_stamp:
        stamp_bits = worst_frame_bits(EPOS2_TIME_STAMP_RPDO.payload_bytes)
        items.append(BudgetItem.every_period("time stamp 0x1013", 1, stamp_bits))
    buffered = 0
    queued = 1 + int(bus.time_stamp)  # the master's frames right after a SYNC: SYNC, time stamp, setpoints
    for axis in wiring.axes:
        profile = profile_class(axis.profile)
        for kind, layouts in (("RPDO", profile.rpdos), ("TPDO", tuple(with_rates(t, bus) for t in profile.tpdos))):
            for layout in layouts:
                if layout.role is PdoRole.RECORD:
                    buffered += 1
                    continue
                if layout.role is PdoRole.SETPOINT:
                    queued += 1
                items.append(_pdo_item(f"node {axis.node_id} {kind}{layout.number} {layout.role}", layout))
    beats = len(wiring.axes) * period / bus.heartbeat_ms + period / bus.master_heartbeat_ms
    items.append(BudgetItem("heartbeats", beats, math.ceil(beats), HEARTBEAT_BITS, math.ceil(beats * WINDOW_PERIODS)))
    # unscheduled: room in every window, none claimed in a period (what they push out of one goes in
    # the window's idle time)
    items.append(BudgetItem("EMCY (reserved)", 1 / WINDOW_PERIODS, 0, EMCY_BITS, 1))
    items.append(BudgetItem("SDO exchange (reserved)", 1 / WINDOW_PERIODS, 0, SDO_EXCHANGE_BITS, 1))
    records, derived = 0, False
    if buffered:
        records, derived = bus.records_per_sync or 0, bus.records_per_sync is None
        if derived:
            capacity = bus.bitrate * period / 1000.0
            window_room = LOAD_LIMIT * WINDOW_PERIODS * capacity - sum(i.window_bits for i in items)
            period_room = capacity - sum(i.peak_bits for i in items)
            # as many as the bus carries in every window and in every period, and as the master's
            # transmit queue holds after the SYNC
            records = min(
                math.floor(window_room / (WINDOW_PERIODS * RECORD_BITS)),
                math.floor(period_room / RECORD_BITS),
                bus.tx_queue_frames - queued,
            )
            records = max(0, records)
        items.append(BudgetItem.every_period(f"records ({buffered} EPOS2 axes)", records, RECORD_BITS))
    return BusBudget(bus.bitrate, period, tuple(items), records, buffered, derived, queued, bus.tx_queue_frames)
