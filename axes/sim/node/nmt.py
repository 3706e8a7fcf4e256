"""NMT of a simulated drive: joining a network, boot-up, the NMT commands and the heartbeat producer.

python-canopen's ``LocalNode`` keeps the NMT state; the drive adds what CiA 301 says around it: a
boot-up message and pre-operational at power-on, the heartbeat of 0x1017 (which a test may silence
as a node that lost power would), reset node and reset communication, PDOs only when operational,
and the NMT state an NMT command left (leaving OPERATIONAL for STOPPED is an abort connection
event: ``axes/sim/node/master_loss.py``).
"""

from __future__ import annotations

import contextlib
import threading
import time

import canopen
from canopen.sdo import SdoAbortedError

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.clock import MotionClock, Quartz
from pvtflow.axes.sim.node.master_loss import MasterLossReaction
from pvtflow.axes.sim.node.pdo import PdoEngine


class NmtNode:
    """The NMT slave and heartbeat producer as part of a ``SimulatedDrive`` (which owns the state
    below and gives it the object dictionary access, the resets and its SYNC callback)."""

    node: canopen.LocalNode
    network: canopen.Network
    lock: threading.RLock
    clock: Clock
    quartz: Quartz
    motion_clock: MotionClock | None
    time_us: int
    pdo: PdoEngine
    master_loss: MasterLossReaction
    _heartbeat_silenced: bool
    _nmt_left: str

    @property
    def node_id(self) -> int:
        return self.node.id

    def attach(self, network: canopen.Network) -> None:
        """Join a network (not yet booted: call ``boot`` once the network is connected)."""
        subscribe(network, 0, self._note_nmt_state)  # before the node's own NMT handling: the state it leaves
        network.add_node(self.node)
        self.network = network
        if self.clock is Clock.WALL:
            with self.lock:
                self.motion_clock = MotionClock(self.quartz, float(self.time_us), time.monotonic())
        subscribe(network, od.SYNC_COB_ID, self._on_sync)
        subscribe(network, 0, self._on_nmt)
        self.master_loss.consumer.attach(network)

    def detach(self) -> None:
        self.master_loss.consumer.detach()  # joins its thread, which takes the lock: before taking it
        with self.lock:
            if not self.node.has_network():
                return
            self.node.nmt.stop_heartbeat()
            self.pdo.unsubscribe()
            unsubscribe(self.network, od.SYNC_COB_ID, self._on_sync)
            unsubscribe(self.network, 0, self._on_nmt)
            unsubscribe(self.network, 0, self._note_nmt_state)
            del self.network[self.node.id]
            self.network = canopen.network._UNINITIALIZED_NETWORK

    def boot(self) -> None:
        """Power on: boot-up message, then pre-operational with the heartbeat of 0x1017."""
        with self.lock:
            self.node.nmt.send_command(od.NmtCommand.RESET_NODE)  # initialising: sends the boot-up frame
            self.node.nmt.send_command(od.NmtCommand.PRE_OPERATIONAL)  # pre-operational: starts the heartbeat
            if self._heartbeat_silenced:
                self.node.nmt.stop_heartbeat()
            self.pdo.reload()
            self.master_loss.configure_consumer()

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    def stop_heartbeat(self) -> None:
        """The node goes quiet on 0x700 (as a node that lost power would); SDO/PDO still answer."""
        with self.lock:
            self._heartbeat_silenced = True
            self.node.nmt.stop_heartbeat()

    def resume_heartbeat(self) -> None:
        with self.lock:
            self._heartbeat_silenced = False
            period = self.read(od.PRODUCER_HEARTBEAT_TIME)
            if period:
                self.node.nmt.start_heartbeat(period)

    def _note_nmt_state(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) >= 2 and data[1] in (0, self.node.id):
            self._nmt_left = self.node.nmt.state

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node.id):
            return

        def act() -> None:
            if self._nmt_left == "OPERATIONAL" and self.node.nmt.state == "STOPPED":
                self.master_loss.on_nmt_stopped()
            if self.node.nmt.state == "INITIALISING":  # reset node / reset communication
                if data[0] == od.NmtCommand.RESET_NODE:
                    self._reset_application()
                else:
                    self._reset_communication()
                self.boot()
            self.pdo.reload()
            if self.operational:
                self.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
            del self.node.data_store[index]
