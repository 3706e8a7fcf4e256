"""The Pinocchio model: joint order, URDF limits, kinematics and dynamics of the shipped robots."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.planner.model import ModelError, RobotModel
from pvtflow.service.config import CONFIG_DIR

ARM = CONFIG_DIR / "robots" / "arm6.urdf"
GANTRY = CONFIG_DIR / "robots" / "gantry3.urdf"


def test_arm_joints_and_limits() -> None:
    m = RobotModel.from_urdf(ARM)
    assert m.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert m.index("joint_4") == 3
    assert m.joints[0].kind == "revolute"
    assert (m.joints[0].lower, m.joints[0].upper, m.joints[0].velocity, m.joints[0].effort) == (-2.97, 2.97, 2.8, 320)
    assert m.has_dynamics
    with pytest.raises(KeyError, match="unknown joint"):
        m.index("joint_9")


def test_gantry_is_prismatic_without_gravity_on_xy() -> None:
    m = RobotModel.from_urdf(GANTRY)
    assert [j.kind for j in m.joints] == ["prismatic"] * 3
    tau = m.inverse_dynamics(np.zeros(3), np.zeros(3), np.zeros(3))
    # only Z carries its weight: (3 kg) * 9.81
    np.testing.assert_allclose(tau, [0.0, 0.0, 3.0 * 9.81], atol=1e-9)


def test_forward_kinematics_and_jacobian() -> None:
    m = RobotModel.from_urdf(ARM)
    q = np.array([0.3, -0.4, 0.7, 0.2, -0.5, 0.1])
    T = m.frame_placement(q, "tool0")
    J = m.frame_jacobian(q, "tool0")
    assert T.shape == (4, 4) and J.shape == (6, 6)
    # the Jacobian's linear part is the derivative of the frame origin
    eps = 1e-6
    numeric = np.column_stack(
        [
            (m.frame_placement(q + eps * e, "tool0")[:3, 3] - m.frame_placement(q - eps * e, "tool0")[:3, 3])
            / (2 * eps)
            for e in np.eye(6)
        ]
    )
    np.testing.assert_allclose(J[:3], numeric, atol=1e-6)
    # home pose: arm stretched along x, 0.1 + 0.3 high
    np.testing.assert_allclose(m.frame_placement(np.zeros(6), "tool0")[:3, 3], [1.03, 0.0, 0.4], atol=1e-12)


def test_unknown_frame() -> None:
    with pytest.raises(KeyError, match="unknown frame"):
        RobotModel.from_urdf(ARM).frame_jacobian(np.zeros(6), "flange")


def test_continuous_joint_is_refused() -> None:
    urdf = """<robot name="c"><link name="a"/><link name="b"/>
      <joint name="spin" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>"""
    with pytest.raises(ModelError, match="revolute or prismatic"):
        RobotModel.from_urdf_string(urdf)


def test_missing_urdf(tmp_path) -> None:
    with pytest.raises(ModelError, match="not found"):
        RobotModel.from_urdf(tmp_path / "none.urdf")


def test_batched_inverse_dynamics_and_frame_speeds_match_one_by_one() -> None:
    """The batched forms the planner uses give the per-configuration RNEA and |J_lin qd|."""
    m = RobotModel.from_urdf(ARM)
    rng = np.random.default_rng(3)
    q, qd, qdd = (rng.uniform(-2.0, 2.0, (25, 6)) for _ in range(3))
    tau = m.inverse_dynamics_rows(q, qd, qdd)
    np.testing.assert_allclose(tau, [m.inverse_dynamics(*x) for x in zip(q, qd, qdd, strict=True)], atol=1e-12)
    speeds = m.frame_speeds(q, qd, "tool0")
    expected = [np.linalg.norm(m.frame_jacobian(a, "tool0")[:3] @ v) for a, v in zip(q, qd, strict=True)]
    np.testing.assert_allclose(speeds, expected, rtol=1e-12, atol=1e-12)
    assert m.inverse_dynamics_rows(q[:0], qd[:0], qdd[:0]).shape == (0, 6)
    with pytest.raises(ValueError, match="expected an"):
        m.inverse_dynamics_rows(q[:, :5], qd, qdd)
    with pytest.raises(ValueError, match="same shape"):
        m.inverse_dynamics_rows(q, qd[:3], qdd)
    with pytest.raises(KeyError, match="unknown frame"):
        m.frame_speeds(q, qd, "nowhere")
