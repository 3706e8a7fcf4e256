"""Homing (CiA 402 mode 6) on simulated drives: every simulated method ends homed at its home position
(position error 0 counts: the position reads the home offset where the machine has the home), a homing
error and a timeout halt the cell, a fault during homing halts every axis, a reboot undoes homing."""

from __future__ import annotations

import dataclasses
import threading
import uuid
from collections.abc import Callable
from typing import Any

import pytest

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import AxisSimulation, HomingConfig
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import GroupError, Result
from pvtflow.axes.master.homing import CellHoming, HomingRequestError, HomingResult, homing_stages
from pvtflow.axes.sim.cell import SimulatedCell
from pvtflow.axes.sim.cia402.homing_mode import HomingState
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

M = od.HomingMethod
INDEX = 4096
SWITCHES = AxisSimulation(
    power_up_qc=5000,
    negative_limit_switch_qc=-2000,
    positive_limit_switch_qc=30000,
    home_switch_qc=10000,
    index_spacing_qc=INDEX,
    index_offset_qc=123,
)
NEGATIVE_HOME_SWITCH = dataclasses.replace(SWITCHES, home_switch_active_above=False)
HARD_STOPS = AxisSimulation(
    power_up_qc=5000,
    index_spacing_qc=INDEX,
    index_offset_qc=123,
    negative_hard_stop_qc=-3000,
    positive_hard_stop_qc=33000,
)
# method -> (machine, where its home position is on that machine)
CASES: dict[int, tuple[AxisSimulation, int]] = {
    M.NEGATIVE_LIMIT_SWITCH_INDEX: (SWITCHES, 123),  # the first index pulse above the switch's edge
    M.POSITIVE_LIMIT_SWITCH_INDEX: (SWITCHES, 123 + 7 * INDEX),
    M.NEGATIVE_LIMIT_SWITCH: (SWITCHES, -2000),
    M.POSITIVE_LIMIT_SWITCH: (SWITCHES, 30000),
    M.POSITIVE_HOME_SWITCH_FROM_ABOVE: (SWITCHES, 10000),
    M.POSITIVE_HOME_SWITCH_FROM_BELOW: (SWITCHES, 10000),
    M.NEGATIVE_HOME_SWITCH_FROM_BELOW: (NEGATIVE_HOME_SWITCH, 10000),
    M.NEGATIVE_HOME_SWITCH_FROM_ABOVE: (NEGATIVE_HOME_SWITCH, 10000),
    M.INDEX_NEGATIVE: (SWITCHES, 123 + INDEX),
    M.INDEX_POSITIVE: (SWITCHES, 123 + 2 * INDEX),
    M.CURRENT_POSITION: (SWITCHES, 5000),
    M.CURRENT_POSITION_37: (SWITCHES, 5000),
    M.HARD_STOP_POSITIVE_INDEX: (HARD_STOPS, 123 + 8 * INDEX),
    M.HARD_STOP_NEGATIVE_INDEX: (HARD_STOPS, 123),
    M.HARD_STOP_POSITIVE: (HARD_STOPS, 33000),
    M.HARD_STOP_NEGATIVE: (HARD_STOPS, -3000),
}
FAST = dict(switch_speed_rpm=600.0, zero_speed_rpm=200.0, acceleration_rpm_s=20000.0, current_threshold_ma=1000)


@pytest.fixture(scope="module")
def gantry3() -> CellConfig:
    return load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")


def with_homing(cell: CellConfig, settings: dict[str, tuple[HomingConfig, AxisSimulation]]) -> CellConfig:
    axes = tuple(
        dataclasses.replace(a, homing=settings[a.joint][0], simulation=settings[a.joint][1])
        if a.joint in settings
        else dataclasses.replace(a, homing=None, simulation=None)
        for a in cell.axes
    )
    return dataclasses.replace(cell, axes=axes)


def test_the_cell_order_gives_the_stages(gantry3: CellConfig) -> None:
    cell = with_homing(gantry3, {j: (HomingConfig(35), SWITCHES) for j in ("x", "y", "z")})
    assert homing_stages(cell.axes, [["z"], ["x", "y"]]) == [["z"], ["x", "y"]]
    assert homing_stages(cell.axes, [["z"], ["x", "y"]], ["y", "z"]) == [["z"], ["y"]]
    assert homing_stages(cell.axes, None) == [["x"], ["y"], ["z"]]  # no order: one at a time
    with pytest.raises(HomingRequestError, match="unknown axis 'w'"):
        homing_stages(cell.axes, None, ["w"])
    absolute = with_homing(gantry3, {"x": (HomingConfig(35), SWITCHES)})
    with pytest.raises(HomingRequestError, match="'y' has no homing"):
        homing_stages(absolute.axes, None, ["y"])


@pytest.mark.parametrize("method", sorted(CASES), ids=lambda m: f"{int(m)}-{M(m).name.lower()}")
def test_every_method_homes_on_its_home_position(
    gantry3: CellConfig, make_rig: Callable[..., Any], method: int
) -> None:
    machine, home = CASES[method]
    homing = HomingConfig(method, offset_qc=home, timeout_s=10.0, **FAST)  # type: ignore[arg-type]
    rig = make_rig(with_homing(gantry3, {"x": (homing, machine)}))
    drive = rig.sim.drive("x")
    assert rig.group.state.homed == (False, True, True)  # y and z have nothing to home
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.HOMED, outcome.message
    assert drive.homing.runs[-1].state is HomingState.ATTAINED
    assert drive.actual == home  # the position reads the home offset...
    assert drive.machine_position == home  # ...exactly where the machine has its home: error 0 counts
    report = outcome.axes[0]
    assert report.homed and report.position_qc == home and report.time_s is not None
    assert rig.group.state.homed == (True, True, True)
    assert drive.read(od.MODES_OF_OPERATION_DISPLAY) == od.INTERPOLATED_POSITION_MODE  # ready for programs
    assert rig.sim.internal_errors == []


def test_a_homing_error_halts_the_cell(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    """A hard stop before the limit switch the method looks for: the drive's following error."""
    blocked = dataclasses.replace(SWITCHES, negative_hard_stop_qc=1000)
    homing = HomingConfig(M.NEGATIVE_LIMIT_SWITCH, timeout_s=10.0, **FAST)  # type: ignore[arg-type]
    rig = make_rig(with_homing(gantry3, {"x": (homing, blocked)}))
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.HOMING_ERROR and outcome.joint == "x"
    assert "homing error" in outcome.message
    assert rig.group.state.homed[0] is False
    assert "hard stop" in rig.sim.drive("x").homing.runs[-1].reason


def test_a_search_that_finds_nothing_times_out(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    nothing = AxisSimulation(power_up_qc=0)  # no switch anywhere: the search goes on
    homing = HomingConfig(M.NEGATIVE_LIMIT_SWITCH, timeout_s=0.3, **FAST)  # type: ignore[arg-type]
    rig = make_rig(with_homing(gantry3, {"x": (homing, nothing)}))
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.TIMEOUT, outcome.message
    assert "not homed within 0.3 s" in outcome.message
    drive = rig.sim.drive("x")
    assert drive.velocity == 0.0 and drive.homing.runs[-1].state is HomingState.INTERRUPTED
    assert rig.group.state.homed[0] is False


def test_a_fault_during_homing_halts_every_axis(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    """x and y home together; y faults while both search: x halts on the next SYNC, z never starts."""
    slow = HomingConfig(M.NEGATIVE_LIMIT_SWITCH, timeout_s=30.0, switch_speed_rpm=100.0, acceleration_rpm_s=20000.0)
    far = dataclasses.replace(SWITCHES, power_up_qc=20000)
    rig = make_rig(with_homing(gantry3, {j: (slow, far) for j in ("x", "y", "z")}))
    x, y, z = (rig.sim.drive(j) for j in ("x", "y", "z"))
    homing = CellHoming(rig.group)
    result: list[object] = []
    thread = threading.Thread(target=lambda: result.append(homing.run([["x", "y"], ["z"]])))
    thread.start()
    assert x.wait_until(lambda: x.machine_position < 19000, 30.0)
    y.inject_emcy(0x5530)
    thread.join(30.0)
    outcome = result[0]
    assert outcome.result in (HomingResult.EMCY, HomingResult.DRIVE_FAULT) and outcome.joint == "y"  # type: ignore[attr-defined]
    assert x.homing.runs[-1].state is HomingState.INTERRUPTED and x.velocity == 0.0
    assert z.homing.runs == []  # the later stage never started
    assert rig.group.state.homed == (False, False, False)


def test_a_stop_during_homing_halts_it(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    slow = HomingConfig(M.NEGATIVE_LIMIT_SWITCH, timeout_s=30.0, switch_speed_rpm=100.0, acceleration_rpm_s=20000.0)
    far = dataclasses.replace(SWITCHES, power_up_qc=20000)
    rig = make_rig(with_homing(gantry3, {"x": (slow, far)}))
    x = rig.sim.drive("x")
    result: list[object] = []
    thread = threading.Thread(target=lambda: result.append(CellHoming(rig.group).run([["x"]])))
    thread.start()
    assert x.wait_until(lambda: x.machine_position < 19000, 30.0)
    rig.group.stop("operator")
    thread.join(30.0)
    assert result[0].result is HomingResult.STOPPED  # type: ignore[attr-defined]
    assert x.velocity == 0.0 and rig.group.state.homed[0] is False


def test_a_homing_holds_the_cell_until_it_ends(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    """One activity at a time (``CellRunState``): while a homing holds the cell no program starts and
    no second homing begins, nothing of either sent; once it has ended the cell is free again."""
    from axes_programs import axis_program

    slow = HomingConfig(M.NEGATIVE_LIMIT_SWITCH, timeout_s=30.0, switch_speed_rpm=100.0, acceleration_rpm_s=20000.0)
    far = dataclasses.replace(SWITCHES, power_up_qc=20000)
    rig = make_rig(with_homing(gantry3, {"x": (slow, far)}))
    x = rig.sim.drive("x")
    homing = CellHoming(rig.group)
    result: list[object] = []
    thread = threading.Thread(target=lambda: result.append(homing.run([["x"]])))
    thread.start()
    assert x.wait_until(lambda: x.machine_position < 19000, 30.0)
    assert rig.group.state.holder is homing
    axes = gantry3.ordered_axes()
    still = PvtProgram("gantry3", tuple(axis_program(a, 0, 0, 100, 10) for a in axes))
    with pytest.raises(GroupError, match="the cell is homing"):
        rig.group.start(still)
    with pytest.raises(GroupError, match="already running"):
        CellHoming(rig.group).run([["x"]])
    assert len(x.homing.runs) == 1
    rig.group.stop("operator")
    thread.join(30.0)
    assert result[0].result is HomingResult.STOPPED  # type: ignore[attr-defined]
    assert rig.group.state.holder is None


def test_a_reboot_undoes_homing(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    homing = HomingConfig(M.CURRENT_POSITION, offset_qc=5000)
    rig = make_rig(with_homing(gantry3, {"x": (homing, SWITCHES), "y": (homing, SWITCHES)}))
    assert CellHoming(rig.group).run([["x", "y"]]).ok
    assert rig.group.state.homed == (True, True, True)
    boots = rig.bus.watch.boot_count(11)
    rig.bus.nmt(11, 0x81)  # NMT reset node: the drive boots again, its encoder counts from 0
    assert rig.sim.drive("x").wait_until(lambda: rig.bus.watch.boot_count(11) > boots, 5.0)
    assert rig.group.state.homed == (False, True, True)
    rig.sim.drive("y").power_cycle()  # a power loss: boot-up message
    assert rig.sim.drive("y").wait_until(lambda: rig.bus.watch.boot_count(12) > boots, 5.0)
    assert rig.group.state.homed == (False, False, True)
    assert CellHoming(rig.group).run([["x", "y"]]).ok  # configured again (it rebooted), homed again
    assert rig.group.state.homed == (True, True, True)


@pytest.mark.wall
def test_homing_with_sync_on_the_wall_clock(gantry3: CellConfig) -> None:
    """The same homing with SYNC every 1 ms of wall-clock time, as on a real cell."""
    homing = HomingConfig(M.INDEX_POSITIVE, offset_qc=123 + 2 * INDEX, timeout_s=10.0, **FAST)  # type: ignore[arg-type]
    cell = with_homing(gantry3, {"x": (homing, SWITCHES)})
    bus_config = dataclasses.replace(cell.bus, channel=f"home-rt-{uuid.uuid4().hex[:8]}")
    cell = dataclasses.replace(cell, bus=bus_config)
    with SimulatedCell(cell, clock="wall") as sim:
        bus = CellBus(bus_config, clock=Clock.WALL).open()
        group = AxisGroup(bus, cell.ordered_axes())
        try:
            outcome = CellHoming(group).run([["x"]])
        finally:
            group.close()
            bus.close()
    assert outcome.ok, outcome.message
    assert sim.drive("x").actual == sim.drive("x").machine_position == 123 + 2 * INDEX


def test_a_faulted_drive_is_not_reset_behind_the_users_back(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    homing = HomingConfig(M.CURRENT_POSITION, offset_qc=5000)
    rig = make_rig(with_homing(gantry3, {"x": (homing, SWITCHES)}))
    rig.group.configure()
    rig.sim.drive("x").inject_emcy(0x5530)
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.DRIVE_FAULT and "recover first" in outcome.message
    assert rig.sim.drive("x").homing.runs == [] and rig.group.state.homed[0] is False
    assert rig.group.recover().ok
    assert CellHoming(rig.group).run([["x"]]).ok


def test_an_unhomed_program_is_really_wrong(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    """x powers up somewhere on its machine (seeded) with its encoder at 0: a program from 0 to 0.7 m,
    planned as if 0 were the machine's 0, runs into the positive limit switch (at 1.21 m)."""
    from axes_programs import axis_program

    rig = make_rig(gantry3)
    drive = rig.sim.drive("x")
    assert drive.actual == 0 and drive.machine_position > 100_000  # seed 0: half a metre from the machine's 0
    axes = gantry3.ordered_axes()
    far = int(axes[0].scaling.position_to_qc(0.7))
    moves = [axis_program(a, 0, far if a.joint == "x" else 0, 1500, 10) for a in axes]
    result = rig.group.run(PvtProgram("gantry3", tuple(moves)), timeout_s=30)
    assert result.result in (Result.DRIVE_FAULT, Result.EMCY) and result.joint == "x", result.message
    assert "positive limit switch" in drive.faults[-1].check
    assert drive.machine_position < gantry3.axis_for_joint("x").simulation.positive_limit_switch_qc  # type: ignore[union-attr]


def test_an_axis_that_does_not_read_its_offset_at_home_is_not_homed(
    gantry3: CellConfig, make_rig: Callable[..., Any]
) -> None:
    """After homing the master reads 0x6064: an EPOS2 that holds another home position 0x2081 than
    the cell's (here one a vendor tool stored after configuration) reads another position at its home."""
    homing = HomingConfig(M.NEGATIVE_LIMIT_SWITCH_INDEX, offset_qc=123, timeout_s=10.0, **FAST)  # type: ignore[arg-type]
    rig = make_rig(with_homing(gantry3, {"x": (homing, SWITCHES)}))
    rig.group.configure()
    rig.sim.drive("x").store(od.EPOS2_HOME_POSITION, 0, 0)
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.HOMING_ERROR and outcome.joint == "x"
    assert "x reads 0x6064 = 0 qc at its home, not its home position 0x2081 = 123 qc" in outcome.message
    assert rig.group.state.homed[0] is False


def test_the_epos2_homes_by_maxons_definitions(gantry3: CellConfig, make_rig: Callable[..., Any]) -> None:
    """maxon's EPOS2: 0x2081 is what the position reads at home and 0x607C a move from the reference to
    it. The master writes the cell's offset to 0x2081 and 0x607C = 0, and the axis reads it on the
    reference; a 0x607C left by a vendor tool moves the home past the reference, reading 0x2081 there."""
    homing = HomingConfig(M.NEGATIVE_LIMIT_SWITCH_INDEX, offset_qc=123, timeout_s=10.0, **FAST)  # type: ignore[arg-type]
    rig = make_rig(with_homing(gantry3, {"x": (homing, SWITCHES)}))
    drive = rig.sim.drive("x")
    assert CellHoming(rig.group).run([["x"]]).result is HomingResult.HOMED
    assert (drive.read(od.EPOS2_HOME_POSITION), drive.read(od.HOME_OFFSET)) == (123, 0)
    on_reference = drive.machine_position
    assert drive.actual == 123
    drive.store(od.HOME_OFFSET, 0, 500)  # the move past the reference, as maxon defines 0x607C
    outcome = CellHoming(rig.group).run([["x"]])
    assert outcome.result is HomingResult.HOMED, outcome.message
    assert drive.actual == 123 and drive.machine_position == on_reference + 500
