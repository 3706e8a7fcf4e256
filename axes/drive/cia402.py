"""CiA 402 controlword and statusword, and the power state machine seen from the master.

The state table, the transition table and the operation-mode codes are python-canopen's
(``canopen.profiles.p402.State402`` / ``OperationMode``): they are imported, not restated.
``BaseNode402`` itself is not used because its state changes block on wall-clock timeouts and
poll the statusword by SDO; pvtflow drives every transition from the statusword that arrives in
a TPDO (event driven, so a simulated cell can run faster than real time). What is added here is
what p402 does not have: named bits, the interpolated-position-mode bits (4, 8, 12), the fault
reset on a rising bit 7, and decoding of the EPOS2's statusword patterns (bit 8 and the
manufacturer bits 14/15 set, which the p402 masks already ignore).
"""

from __future__ import annotations

from enum import IntFlag, StrEnum

from canopen.profiles.p402 import OperationMode, State402

__all__ = [
    "CONTROLWORD_DISABLE_VOLTAGE",
    "CONTROLWORD_ENABLE_OPERATION",
    "CONTROLWORD_FAULT_RESET",
    "CONTROLWORD_HALT",
    "CONTROLWORD_HALT_HOMING",
    "CONTROLWORD_QUICK_STOP",
    "CONTROLWORD_SHUTDOWN",
    "CONTROLWORD_START_HOMING",
    "CONTROLWORD_START_IP",
    "CONTROLWORD_SWITCH_ON",
    "Controlword",
    "OperationMode",
    "PowerState",
    "PowerStateSteering",
    "State402",
    "Statusword",
    "decode_state",
    "next_controlword",
    "statusword_of_state",
]


class Controlword(IntFlag):
    """Bits of 0x6040 (CiA 402; bit 4 and 8 as the interpolated position mode uses them)."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2  # active low: 0 requests a quick stop
    ENABLE_OPERATION = 1 << 3
    ENABLE_IP_MODE = 1 << 4  # mode specific: interpolated position mode enable
    HOMING_START = 1 << 4  # the same bit in homing mode (6): a rising edge starts homing, 0 interrupts it
    FAULT_RESET = 1 << 7  # acts on the rising edge only
    HALT = 1 << 8


class Statusword(IntFlag):
    """Bits of 0x6041 (CiA 402; EPOS2 uses 8, 14 and 15 for manufacturer facts)."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5  # active low: 0 while a quick stop is active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    MANUFACTURER_8 = 1 << 8  # EPOS2: offset current measured
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10  # ip mode: halt=1 -> velocity is 0
    INTERNAL_LIMIT_ACTIVE = 1 << 11
    IP_MODE_ACTIVE = 1 << 12  # mode specific: interpolation active
    HOMING_ATTAINED = 1 << 12  # the same bit in homing mode (6)
    FOLLOWING_ERROR = 1 << 13
    HOMING_ERROR = 1 << 13  # the same bit in homing mode (6)
    MANUFACTURER_14 = 1 << 14  # EPOS2: refresh cycle of power stage
    MANUFACTURER_15 = 1 << 15  # EPOS2: position referenced to home position


# Device control commands: python-canopen's values, named as CiA 402 names them.
CONTROLWORD_SHUTDOWN = State402.CW_SHUTDOWN  # 0x0006
CONTROLWORD_SWITCH_ON = State402.CW_SWITCH_ON  # 0x0007
CONTROLWORD_ENABLE_OPERATION = State402.CW_OPERATION_ENABLED  # 0x000F
CONTROLWORD_DISABLE_VOLTAGE = State402.CW_DISABLE_VOLTAGE  # 0x0000
CONTROLWORD_QUICK_STOP = State402.CW_QUICK_STOP  # 0x0002
CONTROLWORD_FAULT_RESET = State402.CW_SWITCH_ON_DISABLED  # 0x0080 (after a word with bit 7 clear)
CONTROLWORD_START_IP = int(CONTROLWORD_ENABLE_OPERATION | Controlword.ENABLE_IP_MODE)  # 0x001F
CONTROLWORD_HALT = int(CONTROLWORD_START_IP | Controlword.HALT)  # 0x011F: stop with profile deceleration
# homing mode (6): the same bit 4 starts homing on its rising edge
CONTROLWORD_START_HOMING = int(CONTROLWORD_ENABLE_OPERATION | Controlword.HOMING_START)  # 0x001F
CONTROLWORD_HALT_HOMING = int(CONTROLWORD_START_HOMING | Controlword.HALT)  # 0x011F


class PowerState(StrEnum):
    """The CiA 402 power states; the values are python-canopen's State402 names."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"

    @property
    def is_fault(self) -> bool:
        return self in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE)


def decode_state(statusword: int) -> PowerState:
    """The power state a statusword reports (State402.SW_MASK; EPOS2 patterns such as 0x0140,
    0x0121, 0x0123, 0x0137, 0x0117, 0x011F, 0x0108 decode like the plain CiA 402 ones)."""
    for name, (mask, value) in State402.SW_MASK.items():
        if statusword & mask == value:
            return PowerState(name)
    # the masks cover every combination of bits 0-3, 5, 6 except a few reserved ones
    return PowerState.NOT_READY_TO_SWITCH_ON


def statusword_of_state(state: PowerState) -> int:
    """The canonical statusword bits of a power state (for drives that compose a statusword)."""
    return State402.SW_MASK[state.value][1]


def next_controlword(current: PowerState, target: PowerState) -> int | None:
    """The controlword that moves ``current`` one step towards ``target`` (None: nothing to send).

    Direct transitions come from State402.TRANSITIONTABLE, the path otherwise from
    State402.next_state_indirect (which heads for OPERATION ENABLED, through SWITCH ON DISABLED
    out of a fault). The fault reset word 0x0080 only acts on a rising bit 7: see PowerStateSteering.
    """
    if current == target:
        return None
    key = (current.value, target.value)
    if key in State402.TRANSITIONTABLE:
        return State402.TRANSITIONTABLE[key]
    step = State402.next_state_indirect(current.value)
    if step is None or step == current.value:
        return None
    return State402.TRANSITIONTABLE.get((current.value, step))


class PowerStateSteering:
    """How the master steers one drive's power state by controlword (not the drive's own state machine,
    which the simulator plays): the last controlword sent, the last statusword seen.

    ``step(statusword, target)`` returns the controlword(s) to send now to progress towards the
    target power state. The fault reset is returned as two words (bit 7 low, then high) so that the
    drive sees a rising edge even if the previous controlword already had bit 7 set.
    """

    def __init__(self) -> None:
        self.controlword = 0
        self.statusword = 0

    @property
    def state(self) -> PowerState:
        return decode_state(self.statusword)

    def update(self, statusword: int) -> PowerState:
        self.statusword = statusword
        return self.state

    def step(self, statusword: int, target: PowerState = PowerState.OPERATION_ENABLED) -> list[int]:
        current = self.update(statusword)
        if current in (PowerState.FAULT_REACTION_ACTIVE, PowerState.NOT_READY_TO_SWITCH_ON):
            return []  # the drive leaves these by itself (transitions 14 and 1)
        word = next_controlword(current, target)
        if word is None:
            return []
        if word & Controlword.FAULT_RESET:
            rearm = bool(self.controlword & Controlword.FAULT_RESET)
            words = [word & ~Controlword.FAULT_RESET & 0xFFFF, word] if rearm else [word]
        else:
            words = [word]
        self.controlword = words[-1]
        return words

    def sent(self, controlword: int) -> None:
        """Record a controlword sent outside ``step`` (start, halt) so the next edge is known."""
        self.controlword = controlword
