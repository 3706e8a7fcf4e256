"""CAN error frames as the Linux kernel delivers them, decoded into the controller's state.

python-can's ``BusABC.state`` stays ACTIVE on socketcan (it has no query for it), so the error
frames are where the master learns that its controller is error-warning, error-passive or bus-off:
the kernel sends one at every state change (``can_change_state``, ``can_bus_off``) when the socket
takes error frames. python-can hands one over as ``Message(is_error_frame=True)`` whose
``arbitration_id`` is the error class bits (the CAN_ERR_FLAG taken off) and whose 8 data bytes are
the details. The constants are linux/can/error.h's; the simulated wire sends the same frames
(``axes.sim.wire.bus_states``), so one decoder serves every interface.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import can

# error classes (the CAN ID of an error frame), linux/can/error.h
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004  # controller problems: data[1]
CAN_ERR_PROT = 0x008  # protocol violations: data[2], data[3]
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100  # the controller restarted (after bus-off)
CAN_ERR_CNT = 0x200  # TX error counter in data[6], RX error counter in data[7]

# data[1] of a CAN_ERR_CRTL frame
CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_TX_OVERFLOW = 0x02
CAN_ERR_CRTL_RX_WARNING = 0x04  # reached the warning level for RX errors (96)
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10  # reached the error-passive level (128)
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40  # back to error-active

CAN_ERR_DLC = 8


class ControllerState(StrEnum):
    """A CAN controller's fault confinement state (ISO 11898-1), by its name."""

    ERROR_ACTIVE = "error-active"
    ERROR_WARNING = "error-warning"  # an error counter at 96 or more: still sends and acknowledges
    ERROR_PASSIVE = "error-passive"  # an error counter at 128 or more: sends passive error flags only
    BUS_OFF = "bus-off"  # the transmit counter past 255: takes no part in the bus

    @property
    def severity(self) -> int:
        return list(ControllerState).index(self)


# python-can's own report (interfaces that can tell: pcan, the simulated wire, ...)
FROM_BUS_STATE = {
    can.BusState.ACTIVE: ControllerState.ERROR_ACTIVE,
    can.BusState.PASSIVE: ControllerState.ERROR_PASSIVE,
    can.BusState.ERROR: ControllerState.BUS_OFF,
}


@dataclass(frozen=True)
class ErrorFrame:
    """What one error frame says: the controller's new state (None: the frame tells none, e.g. a
    protocol violation or an overflow), its error counters where it carries them."""

    classes: int
    state: ControllerState | None
    tx_errors: int | None = None
    rx_errors: int | None = None

    def counters(self) -> str:
        """' (TX errors n, RX errors m)' where the frame carries them, else ''."""
        if self.tx_errors is None or self.rx_errors is None:
            return ""
        return f" (TX errors {self.tx_errors}, RX errors {self.rx_errors})"


def decode(msg: can.Message) -> ErrorFrame:
    """The state an error frame announces. Bus-off wins over every other class in the frame; a
    restart is error-active; a controller frame says passive, warning or active in data[1] (passive
    before warning: the kernel sets the bits of the direction that changed, the other may still be
    at warning). The counters are read where the kernel says they are (CAN_ERR_CNT), and from a
    controller frame that has them (drivers filled data[6]/[7] there before CAN_ERR_CNT existed)."""
    classes = msg.arbitration_id
    data = bytes(msg.data)
    state: ControllerState | None = None
    if classes & CAN_ERR_BUSOFF:
        state = ControllerState.BUS_OFF
    elif classes & CAN_ERR_RESTARTED:
        state = ControllerState.ERROR_ACTIVE
    elif classes & CAN_ERR_CRTL and len(data) > 1:
        crtl = data[1]
        if crtl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            state = ControllerState.ERROR_PASSIVE
        elif crtl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING):
            state = ControllerState.ERROR_WARNING
        elif crtl & CAN_ERR_CRTL_ACTIVE:
            state = ControllerState.ERROR_ACTIVE
    filled = len(data) >= CAN_ERR_DLC and (classes & CAN_ERR_CNT or (classes & CAN_ERR_CRTL and any(data[6:8])))
    if filled:
        return ErrorFrame(classes, state, data[6], data[7])
    return ErrorFrame(classes, state)
