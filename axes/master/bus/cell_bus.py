"""The cell's CAN bus as the master sees it: python-can bus, canopen Network, nodes, NMT, fault reports.

``CellBus`` opens the interface and ties the parts together: the network that records and retries
what it sends (``axes.master.bus.network``), SYNC (``axes.master.bus.sync``), the watch over heartbeats, EMCY, lost SYNC
and the wire (``axes.master.bus.watch``), the master's own heartbeat (``axes.master.bus.heartbeat``, started and
stopped with the bus, which every drive watches (0x1016) and stops on when it stops (0x6007)), and
the quick stop that needs no SYNC (``axes.master.bus.quick_stop``). Every failure any of them sees reaches the
callbacks of ``on_fault`` as one ``BusFault`` (``axes.master.bus.faults``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ObjectDictionary

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import hand_the_gil_on_often
from pvtflow.axes.drive.config import BusConfig, runs_cyclic, wire_options
from pvtflow.axes.drive.objects import time_stamp_cob_id
from pvtflow.axes.master.bus.faults import BusError, BusFault, FaultCallback
from pvtflow.axes.master.bus.heartbeat import MasterHeartbeat
from pvtflow.axes.master.bus.network import FrameLog, LoggingNetwork
from pvtflow.axes.master.bus.quick_stop import QuickStop, quick_stop_all
from pvtflow.axes.master.bus.sync import DEFAULT_MAX_GAP_PERIODS, SyncClock
from pvtflow.axes.master.bus.watch import BusWatch

# How long the master waits for one SDO answer. python-canopen's 0.3 s is tight for a simulated cell
# on a loaded 2-core host (a drive's thread may not run for that long); a real drive answers within
# milliseconds, so a longer wait only delays the report of a drive that is really gone.
SDO_RESPONSE_TIMEOUT_S = 1.0
NMT_STATE_PRE_OPERATIONAL = 127

log = logging.getLogger("pvtflow.bus")


class CellBus:
    """python-can bus + canopen Network of one cell, with NMT, SYNC, heartbeat and EMCY consumers."""

    def __init__(
        self,
        config: BusConfig,
        *,
        clock: Clock = Clock.LOCKSTEP,
        can_log: str | Path | None = None,
        lost_sync_timeout_s: float = 1.0,
        time_stamp: bool | None = None,
    ) -> None:
        self.config = config
        self.can_log = can_log
        self.recorder = FrameLog(can_log)
        self.network = LoggingNetwork(recorder=self.recorder)
        self.network.channel_name = config.channel
        stamp = config.time_stamp if time_stamp is None else time_stamp
        gap = config.max_sync_gap_periods if config.max_sync_gap_periods is not None else DEFAULT_MAX_GAP_PERIODS
        self.sync = SyncClock(
            self.network,
            self.report,
            config.sync_period_ms,
            clock,
            time_stamp_cob_id(config.master_node_id) if stamp else None,
            priority=config.sync_priority,
            max_gap_periods=gap,
            threads=self.threads,
        )
        self.sync.lift_bus_threads = config.lift_bus_threads
        self.network.tx_retry_s = config.tx_retry_ms / 1000.0
        self.lost_sync_timeout_s = lost_sync_timeout_s
        self.nodes: dict[int, canopen.RemoteNode] = {}
        self._fault_callbacks: list[FaultCallback] = []
        self.watch = BusWatch(config, self.network, self.report, self.sync, lost_sync_timeout_s)
        self.master_heartbeat = MasterHeartbeat(config, self.network, self.watch, self.nodes, self.sync)

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> CellBus:
        hand_the_gil_on_often()
        kwargs: dict[str, object] = {"interface": self.config.interface, "channel": self.config.channel}
        kwargs.update(wire_options(self.config, clock=self.sync.clock))
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            where = f"{self.config.interface}:{self.config.channel}"
            raise BusError(f"cannot open CAN bus {where}: {exc}") from None
        self.network.bus = bus
        self.network.notifier = can.Notifier(bus, [*self.network.listeners, self.recorder, self.watch.errors], 0.1)
        if runs_cyclic(self.config, self.sync.clock):
            from pvtflow.axes.master.cyclic.process import CyclicProcess  # a child process: only where asked for

            try:
                self.sync.cyclic = CyclicProcess(self.config, self.network, self.report, self.sync).open()
            except BusError:
                self.network.disconnect()
                raise
        self.watch.start()
        self.master_heartbeat.start()
        return self

    def threads(self) -> list[threading.Thread]:
        """The threads that serve this bus beside SYNC's: the notifier's reader (answers, feeders, SDO,
        heartbeats, EMCY), the watchdog and the master's heartbeat. Each may take the GIL the SYNC
        thread needs, so when SYNC runs at SCHED_FIFO they run just below it (``axes.master.bus.sync.lift``):
        one of them preempted by the host's other processes while holding the GIL would hold SYNC
        up for a scheduler slice (priority inversion through the GIL). Lifted, they stay so for the
        bus's life: between motions they sleep on their queues and timers."""
        notifier = self.network.notifier
        readers = [r for r in getattr(notifier, "_readers", ()) if isinstance(r, threading.Thread)]
        others = [self.watch.thread, self.master_heartbeat.thread]
        return readers + [t for t in others if t is not None]

    @property
    def is_open(self) -> bool:
        return self.network.bus is not None

    def close(self) -> None:
        self.sync.stop()
        if self.sync.cyclic is not None:
            self.sync.cyclic.close()
            self.sync.cyclic = None
        self.master_heartbeat.stop()
        self.watch.stop()
        if self.network.bus is not None:
            self.network.disconnect()
        self.recorder.stop()

    def __enter__(self) -> CellBus:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- nodes -----------------------------------------------------------------------------------
    def add_node(self, node_id: int) -> canopen.RemoteNode:
        """A remote node with an empty dictionary: pvtflow addresses objects by index, so the master
        does not need the drive's EDS (any EPOS2, Parker or simulated node will do)."""
        if node_id in self.nodes:
            return self.nodes[node_id]
        node = canopen.RemoteNode(node_id, ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = SDO_RESPONSE_TIMEOUT_S
        self.network.add_node(node)
        node.nmt.add_heartbeat_callback(lambda state, nid=node_id: self.watch.on_heartbeat(nid, state))
        node.emcy.add_callback(lambda err, nid=node_id: self.watch.on_emcy(nid, err))
        self.nodes[node_id] = node
        return node

    def on_fault(self, callback: FaultCallback) -> None:
        self._fault_callbacks.append(callback)

    def remove_fault_callback(self, callback: FaultCallback) -> None:
        if callback in self._fault_callbacks:
            self._fault_callbacks.remove(callback)

    def report(self, fault: BusFault) -> None:
        """Every callback hears of the fault; one that fails (a halt on a bus that has gone away)
        is logged, and neither stops the others nor the thread that reports (the watchdog)."""
        for cb in list(self._fault_callbacks):
            try:
                cb(fault)
            except Exception:  # the reporting thread (watchdog, SYNC) must live on
                log.exception("reporting %s of node %s failed", fault.kind, fault.node_id)

    # --- NMT -------------------------------------------------------------------------------------
    def nmt_broadcast(self, command: int) -> None:
        self.network.send_message(0, bytes([command, 0]))

    def nmt(self, node_id: int, command: int) -> None:
        self.network.send_message(0, bytes([command, node_id]))

    # --- the stop that does not need SYNC -------------------------------------------------------
    def quick_stop(
        self, node_ids: Iterable[int], reason: str, on_done: Callable[[QuickStop], None] | None = None
    ) -> QuickStop:
        """Quick stop these drives by SDO now, NMT stop for those that do not confirm
        (``axes.master.bus.quick_stop``); with a cyclic process, from its transmit queue too
        (``axes.master.cyclic.process``)."""
        nodes = list(node_ids)
        if self.sync.cyclic is not None:
            self.sync.cyclic.quick_stop(reason, nodes)
        return quick_stop_all(
            self.network,
            self.sync,
            self.config.quick_stop_confirm_ms,
            self.master_heartbeat.stop,
            nodes,
            reason,
            on_done,
        )
