"""Controlword / statusword and the master's power state machine (python-canopen's State402 tables)."""

from __future__ import annotations

import pytest
from canopen.profiles.p402 import State402

from pvtflow.axes.drive.cia402 import (
    CONTROLWORD_ENABLE_OPERATION,
    CONTROLWORD_HALT,
    CONTROLWORD_SHUTDOWN,
    CONTROLWORD_START_IP,
    CONTROLWORD_SWITCH_ON,
    Controlword,
    PowerState,
    PowerStateSteering,
    Statusword,
    decode_state,
    next_controlword,
    statusword_of_state,
)


@pytest.mark.parametrize(
    ("statusword", "state"),
    [
        # EPOS2 firmware patterns (bit 8 "offset current measured", bits 14/15 manufacturer specific)
        (0x0140, PowerState.SWITCH_ON_DISABLED),
        (0x0121, PowerState.READY_TO_SWITCH_ON),
        (0x0123, PowerState.SWITCHED_ON),
        (0x0137, PowerState.OPERATION_ENABLED),
        (0x1537, PowerState.OPERATION_ENABLED),  # ip mode active + target reached
        (0x8137, PowerState.OPERATION_ENABLED),
        (0x0117, PowerState.QUICK_STOP_ACTIVE),
        (0x011F, PowerState.FAULT_REACTION_ACTIVE),
        (0x0108, PowerState.FAULT),
        (0x0128, PowerState.FAULT),
        (0x0000, PowerState.NOT_READY_TO_SWITCH_ON),
        # plain CiA 402
        (0x0040, PowerState.SWITCH_ON_DISABLED),
        (0x0031, PowerState.READY_TO_SWITCH_ON),
        (0x0033, PowerState.SWITCHED_ON),
        (0x0037, PowerState.OPERATION_ENABLED),
    ],
)
def test_states_decode_from_statusword(statusword, state):
    assert decode_state(statusword) is state


def test_canonical_statusword_round_trips():
    for state in PowerState:
        assert decode_state(statusword_of_state(state)) is state


def test_device_control_commands():
    assert CONTROLWORD_SHUTDOWN == 0x0006
    assert CONTROLWORD_SWITCH_ON == 0x0007
    assert CONTROLWORD_ENABLE_OPERATION == 0x000F
    assert CONTROLWORD_START_IP == 0x001F
    assert CONTROLWORD_HALT == 0x011F
    assert Controlword.HALT == 1 << 8 and Controlword.FAULT_RESET == 1 << 7
    assert Statusword.IP_MODE_ACTIVE == 1 << 12 and Statusword.TARGET_REACHED == 1 << 10


def test_walk_to_operation_enabled_from_every_state():
    """Each state reaches OPERATION ENABLED by python-canopen's transition table."""
    for start in PowerState:
        state, seen = start, 0
        while state is not PowerState.OPERATION_ENABLED and seen < 6:
            word = next_controlword(state, PowerState.OPERATION_ENABLED)
            if state in (PowerState.FAULT_REACTION_ACTIVE, PowerState.NOT_READY_TO_SWITCH_ON):
                state = {
                    PowerState.FAULT_REACTION_ACTIVE: PowerState.FAULT,
                    PowerState.NOT_READY_TO_SWITCH_ON: PowerState.SWITCH_ON_DISABLED,
                }[state]
            else:
                assert word is not None
                state = next(
                    PowerState(b)
                    for (a, b), w in State402.TRANSITIONTABLE.items()
                    if a == state.value
                    and w == word
                    and b in ("SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED")
                )
            seen += 1
        assert state is PowerState.OPERATION_ENABLED, start


def test_fault_reset_is_a_rising_edge():
    psm = PowerStateSteering()
    psm.sent(0x0080)  # a previous reset attempt left bit 7 high
    words = psm.step(0x0108)
    assert words == [0x0000, 0x0080]
    assert psm.step(0x0108) == [0x0000, 0x0080]  # again: still needs an edge
    fresh = PowerStateSteering()
    assert fresh.step(0x0108) == [0x0080]


def test_sequence_from_switch_on_disabled():
    psm = PowerStateSteering()
    assert psm.step(0x0140) == [0x0006]
    assert psm.step(0x0121) == [0x0007]
    assert psm.step(0x0123) == [0x000F]
    assert psm.step(0x0137) == []
    assert psm.step(0x011F) == []  # fault reaction: the drive goes on by itself
