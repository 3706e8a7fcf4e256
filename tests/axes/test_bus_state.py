"""The master's CAN controller state from the error frames, on every interface (issue 34, item 6).

python-can's ``BusABC.state`` stays ACTIVE on socketcan: the kernel's error frames are what tells the
master it is error-warning, error-passive or bus-off. The frames here are built exactly as python-can's
socketcan hands them over (``is_error_frame``, the error class bits as ``arbitration_id``, 8 data
bytes: linux/can/error.h), sent by another node of a virtual bus, whose ``state`` stays ACTIVE as
socketcan's does; on the simulated wire the medium's own bus states.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import can
import pytest
from axes_programs import program
from axes_rig import unique_channel, with_profiles

from pvtflow.axes.canbus.can_errors import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CNT,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_CRTL_RX_OVERFLOW,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_CRTL_RX_WARNING,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_CRTL_TX_WARNING,
    CAN_ERR_PROT,
    CAN_ERR_RESTARTED,
    ControllerState,
    decode,
)
from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.axes.sim.wire import BUS_OFF, ERROR_PASSIVE


def error_frame(classes: int, crtl: int = 0, tx: int = 0, rx: int = 0) -> can.Message:
    """An error frame as python-can's socketcan delivers it (CAN_ERR_FLAG taken off the CAN ID)."""
    return can.Message(
        arbitration_id=classes,
        is_error_frame=True,
        is_extended_id=False,
        dlc=8,
        data=bytes([0, crtl, 0, 0, 0, 0, tx, rx]),
    )


@pytest.mark.parametrize(
    ("frame", "state", "counters"),
    [
        (
            error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_TX_WARNING, 96, 0),
            ControllerState.ERROR_WARNING,
            (96, 0),
        ),
        (
            error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_RX_WARNING, 3, 100),
            ControllerState.ERROR_WARNING,
            (3, 100),
        ),
        (
            error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_TX_PASSIVE | CAN_ERR_CRTL_RX_WARNING, 128, 97),
            ControllerState.ERROR_PASSIVE,
            (128, 97),
        ),
        (error_frame(CAN_ERR_CRTL, CAN_ERR_CRTL_RX_PASSIVE, 0, 130), ControllerState.ERROR_PASSIVE, (0, 130)),
        (error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_ACTIVE, 90, 0), ControllerState.ERROR_ACTIVE, (90, 0)),
        (error_frame(CAN_ERR_BUSOFF), ControllerState.BUS_OFF, None),
        (error_frame(CAN_ERR_BUSOFF | CAN_ERR_CRTL, CAN_ERR_CRTL_TX_PASSIVE), ControllerState.BUS_OFF, None),
        (error_frame(CAN_ERR_RESTARTED), ControllerState.ERROR_ACTIVE, None),
        (error_frame(CAN_ERR_CRTL, CAN_ERR_CRTL_RX_OVERFLOW), None, None),  # an overflow: no state
        (error_frame(CAN_ERR_PROT), None, None),
    ],
)
def test_an_error_frame_says_the_controller_state_and_its_counters(frame, state, counters) -> None:
    decoded = decode(frame)
    assert decoded.state is state
    got = None if decoded.tx_errors is None else (decoded.tx_errors, decoded.rx_errors)
    assert got == counters


def wait_for(predicate: Callable[[], bool], timeout_s: float = 3.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_a_bus_whose_state_stays_active_reports_every_state_its_error_frames_announce_by_name() -> None:
    channel = unique_channel("errframes")
    kernel = can.Bus(interface="virtual", channel=channel)  # delivers the frames as the kernel would
    bus = CellBus(BusConfig(channel=channel, time_stamp=False), clock=Clock.LOCKSTEP).open()
    faults: list[BusFault] = []
    bus.on_fault(faults.append)

    def states() -> list[BusFault]:
        return [f for f in faults if "the master's CAN controller" in f.message]

    try:
        sent = [
            error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_TX_WARNING, 96, 0),
            error_frame(CAN_ERR_CRTL | CAN_ERR_CNT, CAN_ERR_CRTL_TX_PASSIVE, 128, 0),
            error_frame(CAN_ERR_BUSOFF | CAN_ERR_CNT, 0, 0, 0),
            error_frame(CAN_ERR_RESTARTED),  # a bus-off and its restart between two looks: both told
        ]
        for msg in sent:
            kernel.send(msg)
        assert wait_for(lambda: len(states()) == 4), [f.message for f in faults]
        told = states()
        assert [f.kind for f in told] == [
            FaultKind.BUS_WARNING,
            FaultKind.BUS_WARNING,
            FaultKind.BUS_OFF,
            FaultKind.BUS_WARNING,
        ]
        assert "is error-warning (TX errors 96, RX errors 0)" in told[0].message
        assert "is error-passive (TX errors 128, RX errors 0)" in told[1].message
        assert "is bus-off" in told[2].message and "can send nothing" in told[2].message
        assert "is error-active again (was bus-off)" in told[3].message
        assert bus.network.bus.state is can.BusState.ACTIVE  # python-can knew nothing of it
        assert bus.watch.state is ControllerState.ERROR_ACTIVE
    finally:
        bus.close()
        kernel.shutdown()


@pytest.mark.wall
def test_the_simulated_wire_s_bus_states_are_reported_once_each_by_name() -> None:
    """simwire says a state twice (its ``bus.state`` and the error frame): one report per change."""
    channel = f"simwire-{unique_channel('state')}"
    bus = CellBus(BusConfig(interface="simwire", channel=channel, time_stamp=False), clock=Clock.LOCKSTEP).open()
    faults: list[BusFault] = []
    bus.on_fault(faults.append)
    medium, name = bus.network.bus.medium, bus.network.bus.node_name
    try:
        medium.set_state(name, ERROR_PASSIVE)
        assert wait_for(lambda: any("error-passive" in f.message for f in faults))
        medium.set_state(name, BUS_OFF)
        assert wait_for(lambda: any(f.kind is FaultKind.BUS_OFF for f in faults))
        medium.set_state(name, can.BusState.ACTIVE)
        assert wait_for(lambda: any("error-active again" in f.message for f in faults))
        time.sleep(0.1)  # the watchdog looks again: nothing more to tell
        told = [f.message.split(" (")[0].split(":")[0] for f in faults if "CAN controller" in f.message]
        assert told == [
            "the master's CAN controller is error-passive",
            "the master's CAN controller is bus-off",
            "the master's CAN controller is error-active again",
        ]
    finally:
        bus.close()


def test_a_bus_off_error_frame_halts_the_motion_as_a_bus_off_does(arm6) -> None:
    profile = {"profile": "cia402_ip_linear", "period_ms": 5}
    cell = with_profiles(arm6, {a.joint: profile for a in arm6.axes}, sync_period_ms=5.0)
    channel = unique_channel()
    cell = sharing_the_interpreter(dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=channel)))
    sim = SimulatedCell(cell, channel=channel, interface="virtual").start()
    bus = CellBus(dataclasses.replace(cell.bus, interface="virtual"), clock=Clock.LOCKSTEP).open()
    group = AxisGroup(bus, cell.ordered_axes())
    kernel = can.Bus(interface="virtual", channel=channel)
    try:
        prog = program(cell.ordered_axes(), 1500, fraction=0.3)

        def bus_off(n: int) -> None:
            start = group.start_sync
            if start is not None and n == start + 40:
                kernel.send(error_frame(CAN_ERR_BUSOFF))

        bus.sync.add_listener(bus_off)
        assert group.start(prog) is None
        result = group.wait(30.0)
        assert result.result is Result.BUS_ERROR, result.message
        assert "bus-off" in result.message
    finally:
        group.close()
        bus.close()
        sim.stop()
        kernel.shutdown()
