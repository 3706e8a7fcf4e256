"""SimulatedCell: one simulated drive per configured axis, on the cell's own channel of its bus."""

from __future__ import annotations

import dataclasses
import uuid
from pathlib import Path

import canopen

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import wire_options
from pvtflow.axes.sim import Epos2Drive
from pvtflow.axes.sim.cell import (
    SHARED_INTERPRETER_HEARTBEAT_FACTOR,
    SHARED_INTERPRETER_QUICK_STOP_CONFIRM_MS,
    SimulatedCell,
    sharing_the_interpreter,
)
from pvtflow.axes.sim.process import LocalDrives
from pvtflow.service.config import load_cell_config

from .conftest import FrameLog

CELLS = Path(__file__).resolve().parents[3] / "configs" / "cells"


def test_arm6_cell_boots_six_epos2_with_the_configured_limits() -> None:
    cell = load_cell_config(CELLS / "arm6.yaml")
    channel = f"pvtflow-cell-{uuid.uuid4().hex[:10]}"
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.02
    log = FrameLog()
    master.listeners.append(log)
    master.connect(interface=cell.bus.interface, channel=channel, **wire_options(cell.bus, clock=Clock.LOCKSTEP))
    try:
        with SimulatedCell(cell, channel=channel) as sim:
            for axis in cell.axes:
                assert log.wait_for(0x700 + axis.node_id), f"no boot-up from node {axis.node_id}"
            assert all(isinstance(d, Epos2Drive) for d in sim)
            assert sim.drive("joint_3") is sim.drive(3)
            axis = cell.axis_for_joint("joint_2")
            node = master.add_node(axis.node_id, str(sim.drive(axis.node_id).eds_path))
            assert node.sdo[od.MAX_PROFILE_VELOCITY].raw == axis.limits.max_profile_velocity_rpm
            assert node.sdo[od.MAX_ACCELERATION].raw == axis.limits.max_acceleration_rpm_s
            assert node.sdo[od.SOFTWARE_POSITION_LIMIT][2].raw == axis.limits.max_position_qc
            master.send_message(0x80, b"")
            assert sim.wait_sync(1)
            assert sim.internal_errors == []
        assert not sim.running
    finally:
        master.disconnect()


def test_drives_that_share_the_masters_interpreter_get_the_wide_heartbeat_window() -> None:
    """In the master's interpreter the drives share its pauses: 10 periods there, the cell's 3 elsewhere."""
    cell = load_cell_config(CELLS / "arm6.yaml")
    assert cell.bus.heartbeat_timeout_factor < SHARED_INTERPRETER_HEARTBEAT_FACTOR
    shared = sharing_the_interpreter(cell)
    assert shared.bus.heartbeat_timeout_factor == SHARED_INTERPRETER_HEARTBEAT_FACTOR
    assert shared.bus.master_consumer_time_ms > cell.bus.master_consumer_time_ms
    assert shared.bus.quick_stop_confirm_ms == SHARED_INTERPRETER_QUICK_STOP_CONFIRM_MS
    assert cell.bus.lift_bus_threads and not shared.bus.lift_bus_threads  # they would take the drives' GIL
    bus = dataclasses.replace(cell.bus, interface="virtual", channel=uuid.uuid4().hex)
    virtual = dataclasses.replace(cell, bus=bus)
    assert LocalDrives(virtual, "lockstep").bus.heartbeat_timeout_factor == SHARED_INTERPRETER_HEARTBEAT_FACTOR
