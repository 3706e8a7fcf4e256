"""Joint torque in jerk-limited plans (planner/jerk, ``_torque_slowdown``): held everywhere in time,
not only at the solver's rows, by the solver's answer and by the anytime answers; a solver's optimum
slowed for it is said to be no optimum.

Checked with Pinocchio's RNEA at 20 samples per grid interval (one-sided at both ends, as
tests/planner/test_plan.py checks TOPP-RA's) and every 1 ms.
"""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.planner.jerk import JerkTrajectory
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
ARM_LIMITS = ARM.joint_limits()
BINDING = np.array([[0.0, -1.0, 1.2, 0, 0, 0], [1.5, 0.8, -0.6, 0, 0, 0]])  # tests/planner/test_plan.py's
# a path whose solver answer was 1 % over a limit between its rows, at 30 % of every effort
SIX = np.array(
    [
        [-1.46, -0.13, 0.64, 1.93, 1.16, 1.4],
        [-2.07, 1.44, 0.44, -1.98, -0.78, 0.58],
        [-0.53, -0.16, 1.16, 1.55, 0.15, 1.4],
        [-0.43, 1.43, 0.4, 2.23, -1.44, 1.83],
        [0.27, 0.64, -1.17, 0.23, -0.67, -1.88],
        [-2.29, 1.23, 0.65, -1.41, -0.77, -0.16],
    ]
)
EFFORT = {"test_plan": np.array([0.25, 0.34, 0.25, 1, 1, 1]), "30%": np.full(6, 0.3)}


def limits_with(effort: np.ndarray) -> JointLimits:
    lim = ARM_LIMITS
    return JointLimits(lim.names, lim.lower, lim.upper, lim.velocity, lim.acceleration, lim.effort * effort)


def torque_ratio(traj: JerkTrajectory, effort: np.ndarray) -> float:
    """Worst |tau| / effort at 20 samples per grid interval and every 1 ms."""
    t = np.concatenate((traj.check_times(19), np.linspace(0.0, traj.duration, int(traj.duration * 1000) + 1)))
    tau = ARM.model.inverse_dynamics_rows(traj.position(t), traj.velocity(t), traj.acceleration(t))
    return float(np.max(np.abs(tau) / effort))


def plan(limits: JointLimits, waypoints: np.ndarray, budget_ms: float | None = None):
    out = Planner(limits, ARM.model, torque_limits=True).plan(
        PlanInput(waypoints, max_jerk=10.0 * limits.acceleration, budget_ms=budget_ms)
    )
    assert out.ok, out.message
    assert isinstance(out.trajectory, JerkTrajectory)
    return out


@pytest.mark.parametrize("cut", list(EFFORT), ids=list(EFFORT))
def test_the_solvers_answer_on_a_binding_path_holds_torque_between_its_rows(cut: str) -> None:
    """Without the check: 1.4e-4 (test_plan's efforts) and 8.5e-5 (30 %) over, between the rows."""
    limits = limits_with(EFFORT[cut])
    out = plan(limits, BINDING)
    ratio = torque_ratio(out.trajectory, limits.effort)
    assert ratio <= 1.0 + 1e-5
    assert ratio > 0.99  # the limit binds: the check did not just slow everything down
    assert out.details["solver"] in ("fatrop", "ipopt") and out.details["solver_finished"] is True
    assert 1.0 < out.details["torque_scale"] < 1.01
    # a hair (up to 0.1 %: 6.7e-4 and 9.2e-4 here) leaves the solver's optimum optimal, more does not
    assert out.details["optimal"] is (out.details["torque_scale"] <= 1.001)
    np.testing.assert_allclose(out.trajectory.position(out.trajectory.waypoint_times), BINDING, atol=1e-9)


def test_a_solvers_answer_slowed_for_torque_is_not_called_optimal() -> None:
    """1 % over between the rows without the check: slowed by 3.9 %, so no longer the solver's optimum."""
    limits = limits_with(EFFORT["30%"])
    out = plan(limits, SIX)
    assert torque_ratio(out.trajectory, limits.effort) <= 1.0 + 1e-4
    assert out.details["solver_finished"] is True
    assert out.details["torque_scale"] > 1.001
    assert out.details["optimal"] is False
    lower = out.details["lower_bound_s"]
    assert lower <= out.trajectory.duration  # the gap stays a gap: the duration is the slowed motion's


def test_the_floor_at_a_small_budget_holds_torque() -> None:
    """The S-curve floor (no time for a solver) knows no torque: 10 % over without the check."""
    limits = limits_with(EFFORT["30%"])
    out = plan(limits, BINDING, budget_ms=0.0)
    assert out.details["solver"] == "scurve" and out.details["optimal"] is False
    ratio = torque_ratio(out.trajectory, limits.effort)
    assert 0.99 < ratio <= 1.0 + 1e-5
    assert out.details["torque_scale"] > 1.1
    np.testing.assert_allclose(out.trajectory.position(out.trajectory.waypoint_times), BINDING, atol=1e-9)


def test_whatever_answers_a_tight_budget_holds_torque() -> None:
    """45 ms: the floor, or ipopt's iterate where it had one by then; either is checked."""
    limits = limits_with(EFFORT["30%"])
    for waypoints in (BINDING, SIX):
        out = plan(limits, waypoints, budget_ms=45.0)
        assert torque_ratio(out.trajectory, limits.effort) <= 1.0 + 1e-4


def test_a_plan_well_inside_its_torque_limits_is_not_slowed_for_them() -> None:
    """The cell's own efforts on the same paths: the screen passes, nothing changes."""
    for waypoints in (BINDING, SIX):
        out = plan(ARM_LIMITS, waypoints)
        assert out.details["torque_scale"] == 1.0
        assert torque_ratio(out.trajectory, ARM_LIMITS.effort) < 0.98
