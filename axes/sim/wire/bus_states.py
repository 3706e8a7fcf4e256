"""Bus states and error frames on a simulated-wire channel, as a CAN controller signals them.

Test hooks on the medium: a node goes error passive, bus off or back to error active as its
controller would, and its reader gets the SocketCAN controller error frame that says so; an error
frame on the bus (a protocol violation) reaches every node that is not bus off. The codes are
linux/can/error.h's, as python-can's socketcan hands them over.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import can
from can import BusState

from pvtflow.axes.canbus.can_errors import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_PROT,
    CAN_ERR_RESTARTED,
)
from pvtflow.axes.sim.wire.accounting import Accounting
from pvtflow.axes.sim.wire.node import Node

BUS_OFF = BusState.ERROR  # python-can's name for a controller that left the bus
ERROR_PASSIVE = BusState.PASSIVE


class BusStates:
    """Bus states and error frames of one channel, a part of its ``Medium``: it hands the nodes their
    controller error frames and sets their state; the medium keeps the wire (``go_bus_off`` drops
    what a node going bus off had queued) and the time, under its lock (``cond``, given)."""

    def __init__(
        self,
        *,
        channel: str,
        cond: threading.Condition,
        nodes: list[Node],
        now: Callable[[], float],
        go_bus_off: Callable[[Node], None],
        accounting: Accounting,
    ) -> None:
        self.channel = channel
        self._cond = cond
        self._nodes = nodes  # the medium's own list: the nodes on the channel now
        self._now = now
        self._go_bus_off = go_bus_off
        self._accounting = accounting

    def set_state(self, name: str, state: BusState) -> None:
        """Put node ``name`` into ``state`` (ACTIVE, PASSIVE = error passive, ERROR = bus off), as
        its controller would; it receives the SocketCAN controller error frame that says so. A node
        going bus off loses its queued frames (one on the wire is aborted: nothing of it reaches the
        wire)."""
        if state not in (BusState.ACTIVE, BusState.PASSIVE, BusState.ERROR):
            raise ValueError(f"bus state must be ACTIVE, PASSIVE or ERROR (bus off), got {state!r}")
        with self._cond:
            node = next((n for n in self._nodes if n.name == name), None)
            if node is None:
                raise KeyError(f"simwire channel {self.channel!r} has no node {name!r}")
            before, node.state = node.state, state
            if state == BUS_OFF:
                node.deliver(self._error_frame(CAN_ERR_BUSOFF, bytes(8)))
                self._go_bus_off(node)
                return  # a bus-off controller hears nothing more
            if before == BUS_OFF:
                can_id, data = CAN_ERR_RESTARTED, bytes(8)
            elif state == ERROR_PASSIVE:
                can_id, data = CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE, *bytes(6)])
            else:
                can_id, data = CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_ACTIVE, *bytes(6)])
            node.deliver(self._error_frame(can_id, data))
            self._cond.notify_all()

    def inject_error_frame(self, can_id: int = CAN_ERR_PROT, data: bytes = bytes(8)) -> None:
        """An error frame on the bus (default: a protocol violation), delivered to every node that
        is not bus off, stamped with the bus time. It takes no bus time in the accounting."""
        with self._cond:
            self._accounting.error_frame()
            for n in self._nodes:
                if n.state != BUS_OFF:
                    n.deliver(self._error_frame(can_id, data))

    def _error_frame(self, can_id: int, data: bytes) -> can.Message:
        return can.Message(
            timestamp=self._now(),
            arbitration_id=can_id,
            is_extended_id=False,
            is_error_frame=True,
            dlc=len(data),
            data=data,
            channel=self.channel,
            is_rx=True,
            check=False,
        )
