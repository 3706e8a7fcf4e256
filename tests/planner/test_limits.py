"""Drive limits become joint limits through the axis scaling; the stricter of drive and URDF wins."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.planner.limits import JointLimits, joint_limits_from_drives
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def test_revolute_scaling_by_hand() -> None:
    # 500-line encoder (2000 qc/rev) behind a 100:1 gearbox
    s = AxisScaling.revolute(qc_per_motor_rev=2000, gear_ratio=100)
    assert s.qc_per_joint_unit == pytest.approx(2000 * 100 / (2 * math.pi))  # 31830.99 qc/rad
    assert s.position_to_qc(1.0) == pytest.approx(31830.988618)
    assert s.qc_to_position(31830.988618) == pytest.approx(1.0)
    # 3000 rpm at the motor = 30 rpm at the joint = pi rad/s
    assert s.rpm_to_velocity(3000) == pytest.approx(math.pi)
    assert s.velocity_to_rpm(math.pi) == pytest.approx(3000)
    # 60000 rpm/s at the motor = 600 rpm/s at the joint = 20 pi rad/s^2
    assert s.rpm_s_to_acceleration(60000) == pytest.approx(20 * math.pi)
    # the drive's own velocity factor: 1 rpm = 2000 qc / 60000 ms
    assert s.drive_velocity_to_qc_per_ms(1) == pytest.approx(2000 / 60000)


def test_prismatic_scaling_by_hand() -> None:
    # 4096 qc/rev, 10 mm lead screw behind a 2:1 belt: 200 motor rev per metre
    s = AxisScaling.prismatic(qc_per_motor_rev=4096, lead_m=0.010, gear_ratio=2)
    assert s.motor_rev_per_joint_unit == pytest.approx(200)
    assert s.position_to_qc(0.1) == pytest.approx(81920)
    assert s.rpm_to_velocity(1200) == pytest.approx(0.1)  # 1200 rpm = 20 rev/s = 0.1 m/s
    assert s.rpm_s_to_acceleration(12000) == pytest.approx(1.0)


def test_velocity_unit_and_offset() -> None:
    s = AxisScaling.revolute(2000, 100, velocity_unit_rpm=0.1, position_offset_qc=1000)
    assert s.position_to_qc(0.0) == 1000
    assert s.velocity_to_drive(math.pi) == pytest.approx(30000)  # 3000 rpm in 0.1 rpm units
    assert s.drive_to_velocity(30000) == pytest.approx(math.pi)
    assert s.drive_velocity_to_qc_per_ms(10) == pytest.approx(2000 / 60000)


def test_scaling_rejects_nonsense() -> None:
    with pytest.raises(ValueError):
        AxisScaling(0, 1)
    with pytest.raises(ValueError):
        AxisScaling(2000, 0)
    with pytest.raises(ValueError):
        AxisScaling.prismatic(2000, lead_m=-0.01)
    with pytest.raises(ValueError):
        DriveLimits(0, 1000, -1, 1)
    with pytest.raises(ValueError):
        DriveLimits(1000, 1000, 5, 5)


def test_joint_limits_from_drives_by_hand() -> None:
    scalings = [AxisScaling.revolute(2000, 100), AxisScaling.prismatic(4096, 0.02)]
    drives = [
        DriveLimits(3000, 60000, -31831, 63662),
        DriveLimits(1500, 30000, 0, 204800),
    ]
    lim = joint_limits_from_drives(("a", "b"), scalings, drives)
    np.testing.assert_allclose(lim.velocity, [math.pi, 1500 / 60 * 0.02])
    np.testing.assert_allclose(lim.acceleration, [20 * math.pi, 30000 / 60 * 0.02])
    np.testing.assert_allclose(lim.lower, [-31831 / 31830.988618, 0.0], rtol=1e-9)
    np.testing.assert_allclose(lim.upper, [63662 / 31830.988618, 1.0], rtol=1e-9)


def test_inverted_axis_swaps_position_limits() -> None:
    s = AxisScaling.revolute(2000, -100)
    lim = joint_limits_from_drives(("a",), [s], [DriveLimits(3000, 60000, -31831, 63662)])
    assert lim.lower[0] == pytest.approx(-2.0, abs=1e-4)
    assert lim.upper[0] == pytest.approx(1.0, abs=1e-4)
    assert lim.velocity[0] == pytest.approx(math.pi)


def test_stricter_limit_wins() -> None:
    a = JointLimits(("j",), np.array([-1.0]), np.array([2.0]), np.array([3.0]), np.array([np.inf]), np.array([np.inf]))
    b = JointLimits(("j",), np.array([-2.0]), np.array([1.0]), np.array([4.0]), np.array([5.0]), np.array([10.0]))
    m = a.merged_with(b)
    assert (m.lower[0], m.upper[0], m.velocity[0], m.acceleration[0], m.effort[0]) == (-1.0, 1.0, 3.0, 5.0, 10.0)


def test_arm_cell_limits_by_hand() -> None:
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    lim = cell.joint_limits()
    # joint_1: 4000 rpm through 160:1 = 25 rpm = 2.618 rad/s, below the URDF's 2.8: the drive wins
    assert lim.velocity[0] == pytest.approx(4000 / 160 / 60 * 2 * math.pi)
    # joint_2: 5000 rpm / 160 = 3.27 rad/s, above the URDF's 2.8: the URDF wins
    assert lim.velocity[1] == pytest.approx(2.8)
    # joint_1: 30000 rpm/s / 160 = 187.5 rpm/s = 19.63 rad/s^2 (the URDF has no acceleration limit)
    assert lim.acceleration[0] == pytest.approx(30000 / 160 / 60 * 2 * math.pi)
    # joint_1: 0x607D +-147000 qc / (2000 * 160 / 2 pi qc/rad) = +-2.886 rad, inside the URDF's +-2.97
    assert lim.upper[0] == pytest.approx(147000 / (2000 * 160 / (2 * math.pi)))
    assert lim.lower[0] == pytest.approx(-lim.upper[0])
    # effort comes from the URDF only
    assert lim.effort[0] == 320.0
