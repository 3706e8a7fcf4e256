"""Cell configuration: the shipped cells load, and every kind of mistake is named precisely."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config

ARM = CONFIG_DIR / "cells" / "arm6.yaml"
GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"


def arm_data() -> dict[str, Any]:
    data = yaml.safe_load(ARM.read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "arm6.urdf")
    return data


def write(tmp_path: Path, data: Any) -> Path:
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def expect_error(tmp_path: Path, data: Any, where: str, fragment: str) -> ConfigError:
    path = write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        load_cell_config(path)
    err = info.value
    assert err.file == str(path)
    assert err.where == where
    assert fragment in err.problem, err.problem
    assert str(err).startswith(f"{path}: ")
    return err


def test_shipped_cells_load() -> None:
    arm = load_cell_config(ARM)
    assert arm.name == "arm6"
    assert arm.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert [a.node_id for a in arm.ordered_axes()] == [1, 2, 3, 4, 5, 6]
    assert all(a.profile == "epos2_pvt" for a in arm.axes)
    assert arm.simulated and arm.bus.interface == "simwire"
    gantry = load_cell_config(GANTRY)
    assert gantry.joint_names == ("x", "y", "z")
    assert all(j.kind == "prismatic" for j in gantry.model.joints)


def test_default_config_is_the_arm() -> None:
    assert load_cell_config(None).source == ARM


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_cell_config(tmp_path / "nope.yaml")


def test_not_yaml(tmp_path: Path) -> None:
    expect_error(tmp_path, "axes: [unclosed", "", "not valid YAML")


def test_top_level_not_a_mapping(tmp_path: Path) -> None:
    expect_error(tmp_path, "- 1\n- 2\n", "(top level)", "must be a mapping")


def test_missing_urdf(tmp_path: Path) -> None:
    data = arm_data()
    data["robot"]["urdf"] = "no/such/robot.urdf"
    expect_error(tmp_path, data, "robot.urdf", "URDF file not found")


def test_broken_urdf(tmp_path: Path) -> None:
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'/><joint name='j' type='revolute'><parent link='a'/></joint></robot>")
    data = arm_data()
    data["robot"]["urdf"] = str(bad)
    expect_error(tmp_path, data, "robot.urdf", "not a readable URDF")


def test_unknown_tcp_frame(tmp_path: Path) -> None:
    data = arm_data()
    data["robot"]["tcp_frame"] = "flange"
    expect_error(tmp_path, data, "robot.tcp_frame", "no frame 'flange'")


def test_unknown_joint(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][2]["joint"] = "joint_7"
    expect_error(tmp_path, data, "axes[2].joint", "unknown joint 'joint_7'")


def test_joint_without_axis(tmp_path: Path) -> None:
    data = arm_data()
    del data["axes"][5]
    expect_error(tmp_path, data, "axes", "joint 'joint_6' of the URDF has no axis")


def test_joint_with_two_axes(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][5]["joint"] = "joint_1"
    expect_error(tmp_path, data, "axes[5].joint", "already has an axis (axes[0])")


def test_duplicate_node_id(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][3]["node_id"] = 2
    expect_error(tmp_path, data, "axes[3].node_id", "duplicate node id 2 (also axes[1])")


@pytest.mark.parametrize("node_id", [0, 128, "3", True])
def test_node_id_out_of_range_or_wrong_type(tmp_path: Path, node_id: Any) -> None:
    data = arm_data()
    data["axes"][0]["node_id"] = node_id
    expect_error(tmp_path, data, "axes[0].node_id", "")


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        ("max_profile_velocity_rpm", 0, "must be positive"),
        ("max_profile_velocity_rpm", -100, "must be positive"),
        ("max_acceleration_rpm_s", 0, "must be positive"),
        ("max_acceleration_rpm_s", "fast", "must be a finite number"),
        ("max_acceleration_rpm_s", math.inf, "must be a finite number"),
        ("profile_velocity_rpm", -1, "must be positive"),
        ("min_position_qc", 1.5, "must be an integer"),
        ("max_position_qc", 2**31, "outside"),
    ],
)
def test_bad_drive_limit(tmp_path: Path, field: str, value: Any, fragment: str) -> None:
    data = arm_data()
    data["axes"][1]["limits"][field] = value
    expect_error(tmp_path, data, f"axes[1].limits.{field}", fragment)


def test_position_limits_reversed(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["limits"]["min_position_qc"] = 5000
    data["axes"][0]["limits"]["max_position_qc"] = 5000
    expect_error(tmp_path, data, "axes[0].limits.max_position_qc", "must be above min_position_qc")


def test_position_limits_disjoint_from_urdf(tmp_path: Path) -> None:
    data = arm_data()
    # 1e6 qc is far past joint_1's URDF range of +-2.97 rad (50930 qc/rad)
    data["axes"][0]["limits"]["min_position_qc"] = 1_000_000
    data["axes"][0]["limits"]["max_position_qc"] = 2_000_000
    expect_error(tmp_path, data, "axes[0].limits", "does not overlap the URDF range")


def test_missing_limit(tmp_path: Path) -> None:
    data = arm_data()
    del data["axes"][4]["limits"]["max_acceleration_rpm_s"]
    expect_error(tmp_path, data, "axes[4].limits.max_acceleration_rpm_s", "missing")


def test_unknown_field_is_a_typo(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["limits"]["max_profile_velocity"] = 3000
    expect_error(tmp_path, data, "axes[0].limits.max_profile_velocity", "unknown field")


def test_unknown_profile(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["profile"] = "epos4"
    expect_error(tmp_path, data, "axes[0].profile", "unknown drive profile 'epos4'")


def test_zero_gear_ratio(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["scaling"]["gear_ratio"] = 0
    expect_error(tmp_path, data, "axes[0].scaling.gear_ratio", "must not be zero")


def test_lead_on_a_revolute_joint(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["scaling"]["lead_m"] = 0.01
    expect_error(tmp_path, data, "axes[0].scaling.lead_m", "revolute")


def test_prismatic_joint_needs_a_lead(tmp_path: Path) -> None:
    data = yaml.safe_load(GANTRY.read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "gantry3.urdf")
    del data["axes"][0]["scaling"]["lead_m"]
    expect_error(tmp_path, data, "axes[0].scaling.lead_m", "missing")


def test_unknown_can_interface(tmp_path: Path) -> None:
    data = arm_data()
    data["bus"]["interface"] = "vcan0"
    expect_error(tmp_path, data, "bus.interface", "unknown python-can interface")


def test_sync_period_out_of_range(tmp_path: Path) -> None:
    data = arm_data()
    data["bus"]["sync_period_ms"] = 0
    expect_error(tmp_path, data, "bus.sync_period_ms", "must be positive")


def test_bufferless_drive_period_must_be_the_sync_period(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["profile"] = "sync_setpoint"
    data["axes"][0]["period_ms"] = 4
    expect_error(tmp_path, data, "axes[0].period_ms", "must equal bus.sync_period_ms")


def test_period_on_a_buffered_drive(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["period_ms"] = 10
    expect_error(tmp_path, data, "axes[0].period_ms", "only fixed-period profiles")


def test_buffer_levels_checked(tmp_path: Path) -> None:
    data = arm_data()
    data["axes"][0]["buffer"] = {"underflow_warning": 40, "overflow_warning": 41}
    expect_error(tmp_path, data, "axes[0].buffer.overflow_warning", "at least 2 above")


def test_tcp_speed_needs_a_frame(tmp_path: Path) -> None:
    data = arm_data()
    del data["robot"]["tcp_frame"]
    expect_error(tmp_path, data, "planning.max_tcp_speed", "needs robot.tcp_frame")


def test_the_speed_band_is_a_planning_option(tmp_path: Path) -> None:
    from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND
    from pvtflow.service.cell_planner import planner_for_cell

    assert load_cell_config(ARM).planning.speed_band == DEFAULT_SPEED_BAND == 0.0  # time-optimal unless asked
    data = arm_data()
    data.setdefault("planning", {})["speed_band"] = 0.05
    cell = load_cell_config(write(tmp_path, data))
    assert cell.planning.speed_band == 0.05 and planner_for_cell(cell).speed_band == 0.05


@pytest.mark.parametrize("value", [-0.01, 0.6, "5 %", True, math.nan])
def test_a_bad_speed_band_is_named(tmp_path: Path, value: Any) -> None:
    data = arm_data()
    data.setdefault("planning", {})["speed_band"] = value
    err = expect_error(tmp_path, data, "planning.speed_band", "must be")
    assert "\n" not in str(err)


def test_mixed_profiles_cell(tmp_path: Path) -> None:
    data = arm_data()
    data["bus"]["sync_period_ms"] = 4
    data["axes"][1]["profile"] = "cia402_ip_linear"
    data["axes"][1]["period_ms"] = 4
    data["axes"][2]["profile"] = "sync_setpoint"
    data["axes"][3]["profile"] = "parker_slvdn"
    data["axes"][3]["interpolation_submode"] = -2
    cell = load_cell_config(write(tmp_path, data))
    assert [a.period_ms for a in cell.axes[:4]] == [None, 4, 4, 4]
    assert cell.axes[3].interpolation_submode == -2


def test_a_fixed_period_axis_gets_one_setpoint_per_sync(tmp_path: Path) -> None:
    data = arm_data()
    data["bus"]["sync_period_ms"] = 4
    data["axes"][1]["profile"] = "cia402_ip_linear"
    data["axes"][1]["period_ms"] = 8
    expect_error(tmp_path, data, "axes[1].period_ms", "must equal bus.sync_period_ms (4), got 8")


@pytest.mark.parametrize("profile", ["cia402_ip_linear", "sync_setpoint", "parker_slvdn"])
def test_a_sync_period_the_service_cannot_hold_is_refused(tmp_path: Path, profile: str) -> None:
    """Below 1 ms a fixed-period drive's setpoints cannot be held on the wall clock: the cell file
    is refused, naming the profile and the shortest period (the EPOS2, buffered, is not concerned)."""
    data = arm_data()
    data["bus"]["sync_period_ms"] = 0.5
    # every axis an EPOS2: not refused for the period, but for its bus (axes.master.budget)
    expect_error(tmp_path, data, "bus", "no room for one record per EPOS2 axis per SYNC period")
    data["axes"][2]["profile"] = profile
    expect_error(tmp_path, data, "axes[2].profile", f"{profile} takes one setpoint per SYNC")
    expect_error(tmp_path, data, "axes[2].profile", "the shortest SYNC period pvtflow holds for it is 1 ms")


def test_config_is_not_modified_by_loading(tmp_path: Path) -> None:
    data = arm_data()
    before = copy.deepcopy(data)
    load_cell_config(write(tmp_path, data))
    assert data == before


def test_the_master_heartbeat_settings(tmp_path: Path) -> None:
    arm = load_cell_config(ARM)
    assert arm.bus.master_node_id == 127 and arm.bus.master_heartbeat_ms == 100
    assert arm.bus.master_consumer_time_ms == 300  # 100 ms x the cell's heartbeat_timeout_factor 3
    data = arm_data()
    data["bus"].update(master_node_id=100, master_heartbeat_ms=20, heartbeat_timeout_factor=2.5)
    bus = load_cell_config(write(tmp_path, data)).bus
    assert (bus.master_node_id, bus.master_heartbeat_ms, bus.master_consumer_time_ms) == (100, 20, 50)


@pytest.mark.parametrize(
    ("changes", "where", "fragment"),
    [
        ({"master_node_id": 3}, "bus.master_node_id", "is the node id of axes[2] (joint_3)"),
        ({"master_node_id": 0}, "bus.master_node_id", "[1, 127]"),
        ({"master_node_id": 128}, "bus.master_node_id", "[1, 127]"),
        ({"master_node_id": "x"}, "bus.master_node_id", "integer"),
        ({"master_heartbeat_ms": 0}, "bus.master_heartbeat_ms", "[1, 65535]"),
        ({"master_heartbeat_ms": float("nan")}, "bus.master_heartbeat_ms", "integer"),
        ({"master_heartbeat_ms": 30000}, "bus.master_heartbeat_ms", "0x1016 holds at most 65535 ms"),
        ({"heartbeat_timeout_factor": 1}, "bus.heartbeat_timeout_factor", "must be above 1"),
    ],
)
def test_bad_master_heartbeat_settings(tmp_path: Path, changes: dict[str, Any], where: str, fragment: str) -> None:
    data = arm_data()
    data["bus"].update(changes)
    expect_error(tmp_path, data, where, fragment)


# --- homing -----------------------------------------------------------------------------------------------
def gantry_data() -> dict[str, Any]:
    data = yaml.safe_load(GANTRY.read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "gantry3.urdf")
    return data


def test_the_gantry_homes_and_the_arm_does_not() -> None:
    gantry = load_cell_config(GANTRY)
    assert gantry.requires_homing and gantry.homing_order == (("z",), ("x", "y"))
    x = gantry.axis_for_joint("x")
    assert x.homing is not None and x.homing.method == 1 and x.homing.offset_qc == 1500
    assert x.simulation is not None and x.simulation.index_spacing_qc == 4096
    arm = load_cell_config(ARM)
    assert not arm.requires_homing and all(a.homing is None and a.simulation is None for a in arm.axes)


def test_a_homing_method_by_name_and_no_order(tmp_path: Path) -> None:
    data = gantry_data()
    data["axes"][0]["homing"]["method"] = "negative_limit_switch"
    del data["homing_order"]
    cell = load_cell_config(write(tmp_path, data))
    assert cell.axis_for_joint("x").homing.method == 17  # type: ignore[union-attr]
    assert cell.homing_stages() == [["x"], ["y"], ["z"]]  # no order: one axis at a time


@pytest.mark.parametrize(
    ("change", "where", "fragment"),
    [
        (lambda d: d["axes"][0]["homing"].update(method=7), "axes[0].homing.method", "7 is not a homing method"),
        (lambda d: d["axes"][0]["homing"].update(method="spin"), "axes[0].homing.method", "'spin' is not a homing"),
        (lambda d: d["axes"][0]["homing"].update(speed=3), "axes[0].homing.speed", "unknown field"),
        (
            lambda d: d["axes"][0]["homing"].update(switch_speed_rpm=5000),
            "axes[0].homing.switch_speed_rpm",
            "above the drive's max profile velocity",
        ),
        (
            lambda d: d["axes"][0]["homing"].update(current_threshold_ma=800),
            "axes[0].homing.current_threshold_ma",
            "only the hard-stop methods",
        ),
        (
            lambda d: d["axes"][0].update(profile="parker_slvdn", period_ms=int(d["bus"]["sync_period_ms"])),
            "axes[0].homing",
            "the parker_slvdn profile has no homing mode",
        ),
        (lambda d: d.update(homing_order=[["x", "w"]]), "homing_order[0]", "unknown joint 'w'"),
        (lambda d: d.update(homing_order=[["x"], ["y"]]), "homing_order", "leaves out z"),
        (lambda d: d.update(homing_order=[["x", "y"], "x", "z"]), "homing_order[1]", "in the order twice"),
        (
            lambda d: d["axes"][0]["simulation"].update(positive_limit_switch_qc=-5000),
            "axes[0].simulation.positive_limit_switch_qc",
            "must be above negative_limit_switch_qc",
        ),
        (
            lambda d: d["axes"][0]["simulation"].update(index_spacing_qc=0),
            "axes[0].simulation.index_spacing_qc",
            "0 is outside",
        ),
    ],
)
def test_homing_mistakes_are_named(tmp_path: Path, change: Any, where: str, fragment: str) -> None:
    data = gantry_data()
    change(data)
    expect_error(tmp_path, data, where, fragment)


def test_requires_homing_without_anything_to_home(tmp_path: Path) -> None:
    data = arm_data()
    data["requires_homing"] = True
    expect_error(tmp_path, data, "requires_homing", "no axis has a homing section")


def gantry_ip_linear_data(tmp_path: Path) -> dict[str, Any]:
    data = yaml.safe_load((CONFIG_DIR / "cells" / "gantry3-mixed.yaml").read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "gantry3.urdf")
    return data


def test_fixed_period_axes_are_planned_below_their_limits_by_the_headroom(tmp_path: Path) -> None:
    """bus.fixed_period_headroom scales a fixed-period axis's velocity and acceleration in the plan's
    joint limits; a buffered (EPOS2) axis keeps its full 0x607F / 0x60C5."""
    data = gantry_ip_linear_data(tmp_path)
    data["bus"]["fixed_period_headroom"] = 0.0
    full = load_cell_config(write(tmp_path, data))
    data["bus"]["fixed_period_headroom"] = 0.02
    cell = load_cell_config(write(tmp_path, data))
    assert cell.bus.fixed_period_headroom == 0.02
    assert load_cell_config(CONFIG_DIR / "cells" / "gantry3-mixed.yaml").bus.fixed_period_headroom == 0.002
    a, b = full.joint_limits(), cell.joint_limits()
    fixed = [ax.profile.fixed_period for ax in cell.ordered_axes()]
    assert any(fixed) and not all(fixed)  # the mixed cell has both kinds
    for k, is_fixed in enumerate(fixed):
        share = 0.98 if is_fixed else 1.0
        assert b.velocity[k] == pytest.approx(share * a.velocity[k], rel=1e-12)
        assert b.acceleration[k] == pytest.approx(share * a.acceleration[k], rel=1e-12)
        assert (b.lower[k], b.upper[k]) == (a.lower[k], a.upper[k])
    assert [ax.limits for ax in cell.axes] == [ax.limits for ax in full.axes]  # the drives get their full limits


@pytest.mark.parametrize("value", [-0.01, 0.51, "2 %", math.nan])
def test_a_bad_fixed_period_headroom_is_named(tmp_path: Path, value: Any) -> None:
    data = gantry_ip_linear_data(tmp_path)
    data["bus"]["fixed_period_headroom"] = value
    path = write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        load_cell_config(path)
    assert info.value.where == "bus.fixed_period_headroom"


@pytest.mark.wall  # names the wall clock; no time passes
def test_the_cyclic_process_is_auto_unless_the_cell_says(tmp_path: Path) -> None:
    """``bus.cyclic_process`` / ``interface_sync``: true, false or auto (the default). Auto runs the cyclic path
    in a process of its own on the wall clock wherever another process can open the interface (socketcan, a
    served simwire channel), never in lockstep or on a bus only this process reaches; the interface times SYNC
    where a kernel timer or the served medium does (socketcan, simwire)."""
    import dataclasses

    from pvtflow.axes.canbus.clock import Clock
    from pvtflow.axes.drive.config import interface_times_sync, runs_cyclic

    bus = load_cell_config(ARM).bus
    assert bus.cyclic_process is None and bus.interface_sync is None
    served = dataclasses.replace(bus, channel="pvtflow-arm6@127.0.0.1:40000")
    assert runs_cyclic(served, Clock.WALL) and not runs_cyclic(served, Clock.LOCKSTEP)
    assert not runs_cyclic(bus, Clock.WALL)  # an in-process simwire channel: only this process reaches it
    assert runs_cyclic(dataclasses.replace(bus, interface="socketcan", channel="can0"), Clock.WALL)
    assert not runs_cyclic(dataclasses.replace(bus, interface="virtual"), Clock.WALL)
    assert not runs_cyclic(dataclasses.replace(served, cyclic_process=False), Clock.WALL)
    assert interface_times_sync(served) and not interface_times_sync(dataclasses.replace(bus, interface="virtual"))
    assert not interface_times_sync(dataclasses.replace(served, interface_sync=False))
    for said, means in ((True, True), (False, False), ("auto", None)):
        data = arm_data()
        data["bus"]["cyclic_process"] = data["bus"]["interface_sync"] = said
        cell = load_cell_config(write(tmp_path, data))
        assert (cell.bus.cyclic_process, cell.bus.interface_sync) == (means, means)
    data = arm_data()
    data["bus"]["cyclic_process"] = "yes"
    expect_error(tmp_path, data, "bus.cyclic_process", "must be true, false or auto, got 'yes'")
