"""Quick stop of every drive by a path that does not need SYNC: SDO, then NMT stop.

The run's own halt is the synchronous RPDO controlword, which acts at the next SYNC: useless when
SYNC itself is what failed (its thread died, its frame cannot be sent, a gap the drives cannot ride
out). Then every drive gets the CiA 402 quick stop command (0x6040 = 0x0002) by an expedited SDO
download, which a drive acts on when it arrives. The requests go to all drives first, the answers
are waited for after: one round trip for the cell, not one per axis. The request frames are built
here rather than through python-canopen's ``SdoClient`` (which waits for each answer, and serialises
behind a transfer already running on that node): a drive's SDO server answers a download with
0x60 (confirmed) or 0x80 (abort), which this module reads beside the client, whose next transfer
drops the stray answer (``SdoClient.request_response`` empties its queue first).

A drive that has not confirmed within ``BusConfig.quick_stop_confirm_ms`` (10 ms: an SDO round trip
on a 1 Mbit/s bus is well under 1 ms, a drive answers within a few ms; waiting the SDO client's own
timeout, 1 s, would let an axis run on for a second) is sent NMT stop, addressed to it (the other
nodes on the bus are not ours to stop): CiA 402 makes entering NMT STOPPED one of the events of the
abort connection option code 0x6007, which pvtflow sets to quick stop on every drive
(``Profile.supervise_master``). A frame that cannot be sent at all (bus-off, a dead interface) leaves
one stop: the master's heartbeat stops with the master, and every drive stops on its loss (0x1016).

Nothing avoidable lies between the failure and the requests: they are sent in the thread that saw
the failure (the SYNC thread, at SCHED_FIFO when granted) before anything else of the halt (the
run's event, the end of SYNC production); a refused request is tried again for ``tx_retry_ms``, and
once one is refused the others get one try each and are tried again by the confirming thread every
0.2 ms (the queue is full: retrying each node in turn would delay the last by N bounds); that thread
runs just below SYNC's priority as the bus's others do (``axes.master.bus.sync.lift``), and the cyclic collector
stays off until the confirmations are in (a full collection takes longer than the bound).
"""

from __future__ import annotations

import contextlib
import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import can

from pvtflow.axes.canbus import collector
from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import CONTROLWORD_QUICK_STOP
from pvtflow.axes.master.bus.network import TX_RETRY_PAUSE_S
from pvtflow.axes.master.bus.sync import lift

if TYPE_CHECKING:
    from pvtflow.axes.master.bus.network import LoggingNetwork
    from pvtflow.axes.master.bus.sync import SyncClock

SDO_DOWNLOAD_2_BYTES = 0x2B  # expedited download, size indicated, 2 bytes
SDO_DOWNLOAD_CONFIRMED = 0x60
SDO_ABORT = 0x80
_MULTIPLEXER = struct.pack("<HB", od.CONTROLWORD, 0)


def quick_stop_request(controlword: int = CONTROLWORD_QUICK_STOP) -> bytes:
    """The expedited SDO download of 0x6040:00 = ``controlword``."""
    return bytes([SDO_DOWNLOAD_2_BYTES]) + _MULTIPLEXER + struct.pack("<H", controlword) + b"\0\0"


@dataclass
class QuickStop:
    """One quick stop of a set of drives; ``done`` is set once every drive confirmed or was sent NMT stop."""

    node_ids: tuple[int, ...]
    reason: str
    started: float = field(default_factory=time.monotonic)  # time.monotonic() when the requests went out
    confirmed: dict[int, float] = field(default_factory=dict)  # node -> time.monotonic() of its confirmation
    refused: dict[int, str] = field(default_factory=dict)  # node -> why (an SDO abort, a request not sent)
    nmt_stopped: list[int] = field(default_factory=list)  # nodes sent NMT stop
    unsent: list[str] = field(default_factory=list)  # frames that could not be sent at all, with the error
    done: threading.Event = field(default_factory=threading.Event)

    @property
    def missing(self) -> list[int]:
        return [n for n in self.node_ids if n not in self.confirmed]

    @property
    def latency_s(self) -> float | None:
        """From the requests to the last confirmation (None: not every drive confirmed)."""
        if self.missing:
            return None
        return max(self.confirmed.values()) - self.started if self.confirmed else 0.0

    def describe(self) -> str:
        """One line: what each drive did with the quick stop."""
        parts = []
        if self.confirmed:
            parts.append(f"quick stop by SDO confirmed by node(s) {sorted(self.confirmed)}")
        if self.refused:
            parts.append("; ".join(f"node {n}: {why}" for n, why in sorted(self.refused.items())))
        if self.nmt_stopped:
            parts.append(f"NMT stop sent to node(s) {sorted(self.nmt_stopped)}")
        if self.unsent:
            parts.append(f"not sent ({'; '.join(self.unsent)}): those drives stop on the master's heartbeat loss")
        return "; ".join(parts)


def quick_stop_all(
    network: LoggingNetwork,
    sync: SyncClock,
    confirm_ms: float,
    fall_silent: Callable[[], None],
    node_ids: Iterable[int],
    reason: str,
    on_done: Callable[[QuickStop], None] | None = None,
) -> QuickStop:
    """Send the quick stop request to every drive now (the calling thread: a few frames, no wait);
    a thread of its own waits for the answers (``confirm_ms``), sends NMT stop to the drives that did
    not confirm, then calls ``on_done``; when even that could not be sent, ``fall_silent`` stops the
    master's heartbeat. Never raises: what could not be sent is in ``QuickStop.unsent``."""
    stop = QuickStop(tuple(node_ids), reason)
    lock = threading.Lock()
    answered = threading.Condition(lock)

    def on_response(can_id: int, data: bytearray, timestamp: float) -> None:
        node = can_id - od.SDO_RESPONSE_COB_ID_BASE
        if len(data) < 4 or bytes(data[1:4]) != _MULTIPLEXER:
            return
        with answered:
            if node in stop.confirmed or node in stop.refused:
                return
            if data[0] == SDO_DOWNLOAD_CONFIRMED:
                stop.confirmed[node] = time.monotonic()
            elif data[0] == SDO_ABORT:
                code = struct.unpack_from("<I", data, 4)[0] if len(data) >= 8 else 0
                stop.refused[node] = f"quick stop refused (SDO abort 0x{code:08X})"
            answered.notify_all()

    for node in stop.node_ids:
        subscribe(network, od.SDO_RESPONSE_COB_ID_BASE + node, on_response)
    request = quick_stop_request()
    stop.started = time.monotonic()
    unsent: dict[int, str] = {}  # requests the interface refused: sent again until the deadline

    def send_requests(nodes: Iterable[int], patient: bool) -> None:
        for node in nodes:
            try:
                # once a request was refused, the others get one try each: the queue is full, and
                # a node's own retries would hold the next node's request back by as long
                with contextlib.nullcontext() if patient and not unsent else network.patient(0.0):
                    network.send_message(od.SDO_REQUEST_COB_ID_BASE + node, request)
                unsent.pop(node, None)
            except (can.CanError, OSError, RuntimeError) as exc:
                unsent[node] = f"quick stop not sent: {exc}"

    collector.hold()  # no collection pause between the requests and their confirmations (axes/canbus/collector.py)
    send_requests(stop.node_ids, patient=True)
    confirm_s = confirm_ms / 1000.0

    def answered_all() -> bool:
        return all(n in stop.refused for n in stop.missing)

    def finish() -> None:
        if sync.realtime and sync.lift_bus_threads:  # as the bus's other threads (CellBus.threads)
            lift([threading.current_thread()], sync.priority - 1)
        try:
            confirm_and_stop()
        finally:
            collector.release()

    def confirm_and_stop() -> None:
        deadline = stop.started + confirm_s
        while (left := deadline - time.monotonic()) > 0:
            with answered:
                # a refused request is tried again as often as a refused frame is (axes.master.bus.network);
                # else woken by the answers alone (no polling: in a simulation the drives share
                # this interpreter, and every wake of this thread takes the GIL from them)
                if answered.wait_for(answered_all, min(left, TX_RETRY_PAUSE_S) if unsent else left):
                    break
            send_requests(list(unsent), patient=False)
        for node in stop.node_ids:
            unsubscribe(network, od.SDO_RESPONSE_COB_ID_BASE + node, on_response)
        with answered:
            for node, why in unsent.items():
                stop.refused.setdefault(node, why)
        for node in stop.missing:
            try:
                network.send_message(0, bytes([od.NmtCommand.STOP, node]))
                stop.nmt_stopped.append(node)
            except (can.CanError, OSError, RuntimeError) as exc:
                stop.unsent.append(f"NMT stop of node {node}: {exc}")
        if stop.unsent:  # nothing reaches them: the master falls silent, and they stop on its heartbeat's loss
            fall_silent()
        stop.done.set()
        if on_done is not None:
            on_done(stop)

    threading.Thread(target=finish, name="pvtflow-quick-stop", daemon=True).start()
    return stop
