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
from collections.abc import Callable
from typing import Protocol

import canopen
from canopen.sdo import SdoAbortedError

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.node.dictionary import DriveDictionary
from pvtflow.axes.sim.node.master_loss import MasterLossReaction
from pvtflow.axes.sim.node.pdo import PdoEngine


class NmtHost(Protocol):
    """What NMT needs of its drive (a ``SimulatedDrive``): its node, lock and dictionary, its PDOs, its
    reaction to a lost master, and its reset and guard (an action under its lock)."""

    node: canopen.LocalNode
    lock: threading.RLock
    dictionary: DriveDictionary
    pdo: PdoEngine
    master_loss: MasterLossReaction

    def _reset_application(self) -> None: ...

    def _guard(self, action: Callable[[], None]) -> None: ...


class Nmt:
    """The NMT slave and heartbeat producer around a drive's ``LocalNode``, a part of its
    ``SimulatedDrive`` (given as ``drive``): it owns the network the drive is on, whether the heartbeat
    is silenced and the NMT state the last NMT command found."""

    def __init__(self, drive: NmtHost) -> None:
        self._drive = drive
        self.network: canopen.Network = canopen.network._UNINITIALIZED_NETWORK
        self._heartbeat_silenced = False
        self._left = "INITIALISING"  # the NMT state the last NMT command found (0x6007 on leaving OPERATIONAL)

    def join(self, network: canopen.Network) -> None:
        """Join a network: the node and its NMT commands (the drive subscribes its SYNC)."""
        node = self._drive.node
        subscribe(network, 0, self._note_state)  # before the node's own NMT handling: the state it leaves
        network.add_node(node)
        self.network = network
        subscribe(network, 0, self._on_nmt)

    def leave(self) -> None:
        """Leave the network (under the drive's lock)."""
        unsubscribe(self.network, 0, self._on_nmt)
        unsubscribe(self.network, 0, self._note_state)
        del self.network[self._drive.node.id]
        self.network = canopen.network._UNINITIALIZED_NETWORK

    def boot(self) -> None:
        """Power on: boot-up message, then pre-operational with the heartbeat of 0x1017."""
        drive = self._drive
        with drive.lock:
            drive.node.nmt.send_command(od.NmtCommand.RESET_NODE)  # initialising: sends the boot-up frame
            drive.node.nmt.send_command(od.NmtCommand.PRE_OPERATIONAL)  # pre-operational: starts the heartbeat
            if self._heartbeat_silenced:
                drive.node.nmt.stop_heartbeat()
            drive.pdo.reload()
            drive.master_loss.configure_consumer()

    @property
    def state(self) -> str:
        return self._drive.node.nmt.state

    @property
    def operational(self) -> bool:
        return self._drive.node.nmt.state == "OPERATIONAL"

    def stop_heartbeat(self) -> None:
        """The node goes quiet on 0x700 (as a node that lost power would); SDO/PDO still answer."""
        with self._drive.lock:
            self._heartbeat_silenced = True
            self._drive.node.nmt.stop_heartbeat()

    def resume_heartbeat(self) -> None:
        with self._drive.lock:
            self._heartbeat_silenced = False
            period = self._drive.dictionary.read(od.PRODUCER_HEARTBEAT_TIME)
            if period:
                self._drive.node.nmt.start_heartbeat(period)

    def heartbeat_time_written(self, period_ms: int) -> None:
        """0x1017 was written: the producer at the new period (0: none), unless silenced."""
        if period_ms == 0 or self._heartbeat_silenced:
            self._drive.node.nmt.stop_heartbeat()
        else:
            self._drive.node.nmt.start_heartbeat(period_ms)

    def _note_state(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) >= 2 and data[1] in (0, self._drive.node.id):
            self._left = self._drive.node.nmt.state

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        drive = self._drive
        if len(data) < 2 or data[1] not in (0, drive.node.id):
            return

        def act() -> None:
            if self._left == "OPERATIONAL" and drive.node.nmt.state == "STOPPED":
                drive.master_loss.on_nmt_stopped()
            if drive.node.nmt.state == "INITIALISING":  # reset node / reset communication
                if data[0] == od.NmtCommand.RESET_NODE:
                    drive._reset_application()
                else:
                    self._reset_communication()
                self.boot()
            drive.pdo.reload()
            if self.operational:
                drive.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            drive._guard(act)

    def _reset_communication(self) -> None:
        data_store = self._drive.node.data_store
        for index in [i for i in data_store if 0x1000 <= i <= 0x1FFF]:
            del data_store[index]
