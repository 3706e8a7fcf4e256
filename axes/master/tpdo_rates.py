"""How often the drives' status TPDOs go out: the cell's rates applied to a profile's layouts.

A profile's layouts (``axes.drive.objects``) say what each TPDO maps and whether it is synchronous or
event driven; the cell's bus (``BusConfig.status_every_syncs``, ``status_inhibit_ms``,
``status_event_timer_ms``) says how often. One function applies them, so that the PDO configuration
(``AxisLink.map_pdos``), the bus budget (``axes.master.budget``) and the master's answer counting
(``SyncClock.expect``) agree on the same figures.

A synchronous status TPDO of type n goes out on every n-th SYNC (CiA 301 7.5.2.35), counted from the
first SYNC after the drive entered OPERATIONAL or its PDO was configured: the drive answers SYNC n,
2n, ... of that count. The master takes an answer to SYNC k as the drive's word for SYNCs k to
k + n - 1 (its statusword and position are that old at most), and a drive that owes an answer is
waited for (lockstep) or reported lost (``lost_sync``) as with n = 1.
"""

from __future__ import annotations

import dataclasses

from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.drive.objects import ASYNCHRONOUS, PdoLayout, PdoRole

MAX_EVERY_SYNCS = 240  # CiA 301: transmission types 1..240 are synchronous, every n-th SYNC


def with_rates(layout: PdoLayout, bus: BusConfig) -> PdoLayout:
    """``layout`` at the cell's rates: a synchronous status TPDO every ``status_every_syncs`` SYNCs, an
    event-driven one with the cell's inhibit time and event timer. Other PDOs are returned as they are."""
    if layout.role is not PdoRole.STATUS:
        return layout
    if 1 <= layout.transmission_type <= MAX_EVERY_SYNCS:
        return dataclasses.replace(layout, transmission_type=bus.status_every_syncs)
    if layout.transmission_type >= ASYNCHRONOUS - 1:
        inhibit = layout.inhibit_periods
        if bus.status_inhibit_ms is not None:
            inhibit = bus.status_inhibit_ms / bus.sync_period_ms
        return dataclasses.replace(layout, inhibit_periods=inhibit, event_timer_ms=bus.status_event_timer_ms)
    return layout


def answer_every(layout: PdoLayout) -> int:
    """The SYNCs one answer of a synchronous TPDO stands for (its transmission type n; 1 for type 0)."""
    return layout.transmission_type if 1 <= layout.transmission_type <= MAX_EVERY_SYNCS else 1
