"""The cell file's ``bus`` section: the python-can interface, the bit rate, SYNC, heartbeats, the feed.

Each value is checked against what its CANopen object can hold (0x1016, 0x1800:03) and what the bus
needs to work.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from can.interfaces import VALID_INTERFACES

from pvtflow.axes.drive.config import BusConfig
from pvtflow.service.config.fields import Fields

# python-can's own list of interfaces (``udp_multicast`` among them: it sends to a multicast group,
# off this host, so the tests never name it).
PYTHON_CAN_INTERFACES: tuple[str, ...] = tuple(sorted(VALID_INTERFACES))
MAX_FIXED_PERIOD_HEADROOM = 0.5  # past half the drive's limits a headroom is a mistake, not a margin


def parse_bus(file: Path, data: Any) -> BusConfig:
    f = Fields(
        file,
        "bus",
        data,
        (
            "interface",
            "channel",
            "bitrate",
            "sync_period_ms",
            "time_stamp",
            "heartbeat_ms",
            "heartbeat_timeout_factor",
            "master_node_id",
            "master_heartbeat_ms",
            "max_sync_gap_periods",
            "sync_priority",
            "tx_retry_ms",
            "quick_stop_confirm_ms",
            "records_per_sync",
            "tx_queue_frames",
            "status_every_syncs",
            "status_inhibit_ms",
            "status_event_timer_ms",
            "fixed_period_headroom",
            "cyclic_process",
            "interface_sync",
            "max_lookahead_ms",
        ),
    )
    d = BusConfig()
    interface = f.get("interface", f.string, d.interface)
    if interface not in PYTHON_CAN_INTERFACES:
        raise f.error("interface", f"unknown python-can interface {interface!r}")
    channel = f.get("channel", lambda k, v: f.string(k, str(v)), d.channel)
    bitrate = f.get("bitrate", f.integer(10_000, 1_000_000), d.bitrate)
    sync = f.get("sync_period_ms", f.number(positive=True), d.sync_period_ms)
    if not 0.1 <= sync <= 255:
        raise f.error("sync_period_ms", f"{sync} ms is outside [0.1, 255]")
    factor = f.get("heartbeat_timeout_factor", f.number(positive=True), d.heartbeat_timeout_factor)
    if factor <= 1:
        raise f.error(
            "heartbeat_timeout_factor",
            f"{factor:g} would count a node lost between two of its heartbeats: must be above 1",
        )
    bus = BusConfig(
        interface=interface,
        channel=channel,
        bitrate=bitrate,
        sync_period_ms=sync,
        time_stamp=f.get("time_stamp", f.boolean, d.time_stamp),
        heartbeat_ms=f.get("heartbeat_ms", f.integer(1, 65535), d.heartbeat_ms),
        heartbeat_timeout_factor=factor,
        master_node_id=f.get("master_node_id", f.integer(1, 127), d.master_node_id),
        master_heartbeat_ms=f.get("master_heartbeat_ms", f.integer(1, 65535), d.master_heartbeat_ms),
        max_sync_gap_periods=f.get("max_sync_gap_periods", f.number(positive=True), d.max_sync_gap_periods),
        sync_priority=f.get("sync_priority", f.integer(0, 99), d.sync_priority),
        tx_retry_ms=f.get("tx_retry_ms", f.number(positive=True), d.tx_retry_ms),
        quick_stop_confirm_ms=f.get("quick_stop_confirm_ms", f.number(positive=True), d.quick_stop_confirm_ms),
        records_per_sync=f.get("records_per_sync", f.integer(1, 1000), d.records_per_sync),
        tx_queue_frames=f.get("tx_queue_frames", f.integer(2, 100000), d.tx_queue_frames),
        status_every_syncs=f.get("status_every_syncs", f.integer(1, 240), d.status_every_syncs),
        status_inhibit_ms=f.get("status_inhibit_ms", f.number(positive=True), d.status_inhibit_ms),
        status_event_timer_ms=f.get("status_event_timer_ms", f.integer(0, 65535), d.status_event_timer_ms),
        fixed_period_headroom=f.get("fixed_period_headroom", f.number(), d.fixed_period_headroom),
        cyclic_process=f.get("cyclic_process", f.boolean_or_auto, d.cyclic_process),
        interface_sync=f.get("interface_sync", f.boolean_or_auto, d.interface_sync),
        max_lookahead_ms=f.get("max_lookahead_ms", f.number(positive=True), d.max_lookahead_ms),
    )
    if not 0.0 <= bus.fixed_period_headroom <= MAX_FIXED_PERIOD_HEADROOM:
        raise f.error(
            "fixed_period_headroom",
            f"{bus.fixed_period_headroom:g} must be within [0, {MAX_FIXED_PERIOD_HEADROOM:g}] "
            "(the share of 0x607F / 0x60C5 kept out of the plans)",
        )
    if not 2.0 * bus.sync_period_ms <= bus.max_lookahead_ms <= 10_000.0:
        raise f.error(
            "max_lookahead_ms",
            f"{bus.max_lookahead_ms:g} ms: at least two SYNC periods ({2.0 * bus.sync_period_ms:g} ms: the feeder tops "
            "up once per period) and at most 10000 ms",
        )
    if bus.status_inhibit_ms is not None and bus.status_inhibit_ms > 6553.5:
        raise f.error("status_inhibit_ms", f"{bus.status_inhibit_ms:g} ms: 0x1800:03 holds at most 6553.5 ms")
    if bus.max_sync_gap_periods is not None and bus.max_sync_gap_periods < 1.5:
        raise f.error(
            "max_sync_gap_periods",
            f"{bus.max_sync_gap_periods:g} periods: a gap of one period is every SYNC; at least 1.5",
        )
    if bus.master_consumer_time_ms > 0xFFFF:
        raise f.error(
            "master_heartbeat_ms",
            f"the drives would wait {bus.master_consumer_time_ms} ms (master_heartbeat_ms x heartbeat_timeout_factor) "
            "for the master's heartbeat: 0x1016 holds at most 65535 ms",
        )
    return bus
