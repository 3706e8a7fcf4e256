"""Time-optimal planning: limits respected, waypoints passed, near-optimal, clear errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import PlanResult
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
GANTRY = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
ARM_LIMITS = ARM.joint_limits()


def random_paths(limits: JointLimits, count: int, seed: int, n_waypoints: int = 8) -> list[np.ndarray]:
    """Seeded random in-limit waypoint sets (every one is a path: tests/planner/test_path_limits.py)."""
    rng = np.random.default_rng(seed)
    return [rng.uniform(0.7 * limits.lower, 0.7 * limits.upper, (n_waypoints, limits.dof)) for _ in range(count)]


def dense_times(duration: float, n: int = 4001) -> np.ndarray:
    return np.linspace(0.0, duration, n)


@pytest.mark.parametrize("waypoints", random_paths(ARM_LIMITS, 4, seed=7))
def test_trajectory_respects_limits_and_passes_waypoints(waypoints: np.ndarray) -> None:
    out = Planner(ARM_LIMITS).plan(PlanInput(waypoints))
    assert out.ok, out.message
    tr = out.trajectory
    assert tr is not None
    t = np.concatenate((dense_times(tr.duration), tr.check_times()))
    v, a, q = tr.velocity(t), tr.acceleration(t), tr.position(t)
    # checked at 8 samples per grid interval by the planner: between them the excess is < 1e-5
    assert np.all(np.abs(v) <= ARM_LIMITS.velocity * (1 + 1e-5))
    assert np.all(np.abs(a) <= ARM_LIMITS.acceleration * (1 + 1e-5))
    assert np.all(q >= ARM_LIMITS.lower - 1e-9) and np.all(q <= ARM_LIMITS.upper + 1e-9)
    # every waypoint is passed, at increasing times, starting and ending at rest
    times = tr.waypoint_times
    assert times[0] == 0.0 and times[-1] == pytest.approx(tr.duration)
    assert np.all(np.diff(times) > 0)
    np.testing.assert_allclose(tr.position(times), waypoints, atol=1e-9)
    np.testing.assert_allclose(tr.velocity(np.array([0.0, tr.duration])), 0.0, atol=1e-9)
    # some joint runs at a limit somewhere: time-optimal, not merely feasible
    assert max(np.max(np.abs(v) / ARM_LIMITS.velocity), np.max(np.abs(a) / ARM_LIMITS.acceleration)) > 0.999


def test_duration_within_one_percent_of_the_fine_reference() -> None:
    """The optimality ratio on a fixed seeded set (the benchmark runs 200 of these): TOPP-RA's own
    profile (speed band 0; the default flattens it, at most the band slower: test_speed_band.py)."""
    fast = Planner(ARM_LIMITS, speed_band=0.0)
    reference = Planner(ARM_LIMITS, gridpoints=3000, speed_band=0.0)
    ratios = []
    for w in random_paths(ARM_LIMITS, 6, seed=2026):
        ratios.append(fast.plan(PlanInput(w)).trajectory.duration / reference.plan(PlanInput(w)).trajectory.duration)
    assert max(ratios) <= 1.01, ratios
    assert min(ratios) >= 0.995, ratios  # not faster than the converged optimum: no limit cheating


def test_single_axis_move_matches_the_closed_form() -> None:
    """A straight gantry move along X is a trapezoid: T = d / v + v / a (TOPP-RA's own profile; the
    default, flattened within the speed band, at most 1 / (1 - band) times that)."""
    lim = GANTRY.joint_limits()
    start, goal = np.array([0.1, 0.4, -0.1]), np.array([1.1, 0.4, -0.1])
    tr = Planner(lim, speed_band=0.0).plan(PlanInput([start, goal])).trajectory
    v, a = lim.velocity[0], lim.acceleration[0]
    expected = 1.0 / v + v / a
    assert tr.duration == pytest.approx(expected, rel=0.01)
    assert tr.duration >= expected * (1 - 1e-6)
    flat = Planner(lim).plan(PlanInput([start, goal])).trajectory
    assert tr.duration <= flat.duration <= tr.duration / (1.0 - DEFAULT_SPEED_BAND)


def test_torque_limits_bind_through_rnea() -> None:
    weak = JointLimits(
        ARM_LIMITS.names,
        ARM_LIMITS.lower,
        ARM_LIMITS.upper,
        ARM_LIMITS.velocity,
        ARM_LIMITS.acceleration,
        ARM_LIMITS.effort * np.array([0.25, 0.34, 0.25, 1, 1, 1]),
    )
    w = np.array([[0.0, -1.0, 1.2, 0, 0, 0], [1.5, 0.8, -0.6, 0, 0, 0]])
    free = Planner(weak, ARM.model).plan(PlanInput(w)).trajectory
    out = Planner(weak, ARM.model, torque_limits=True).plan(PlanInput(w))
    assert out.ok, out.message
    tr = out.trajectory
    assert tr.duration > 1.02 * free.duration  # the torque limit changed the plan
    # torques within the effort limits at the gridpoints (where TOPP-RA holds them) and between them
    # (20 times per interval, one-sided at both ends: the planner checks 3 and slows down)
    t = tr.check_times(19)
    tau = np.array(
        [
            ARM.model.inverse_dynamics(q, v, a)
            for q, v, a in zip(tr.position(t), tr.velocity(t), tr.acceleration(t), strict=True)
        ]
    )
    assert np.all(np.abs(tau) <= weak.effort * 1.001)
    assert np.max(np.abs(tau) / weak.effort) > 0.99


def test_tcp_speed_limit() -> None:
    w = np.array([[-1.2, -0.3, 0.5, 0.2, -0.4, 0.0], [1.2, 0.4, -0.6, -0.2, 0.4, 1.0]])
    out = Planner(ARM_LIMITS, ARM.model, "tool0", max_tcp_speed=0.5).plan(PlanInput(w))
    assert out.ok, out.message
    tr = out.trajectory
    t = dense_times(tr.duration, 801)
    speed = [
        np.linalg.norm(ARM.model.frame_jacobian(q, "tool0")[:3] @ v)
        for q, v in zip(tr.position(t), tr.velocity(t), strict=True)
    ]
    # held exactly at the interval samples; between them the excess is second order
    assert max(speed) <= 0.5 * 1.005
    assert max(speed) >= 0.5 * 0.98


@pytest.mark.parametrize(
    ("waypoints", "result", "fragment"),
    [
        ([[0.0] * 6], PlanResult.INVALID_INPUT, "at least 2 waypoints"),
        ([[0.0] * 5, [0.1] * 5], PlanResult.INVALID_INPUT, "needs 6 joint values"),
        ([[0.0] * 6, [0.1, 0.1, math.nan, 0.1, 0.1, 0.1]], PlanResult.INVALID_INPUT, "not a finite number"),
        ([[0.0] * 6, [0.1, 0.1, 0.1, math.inf, 0.1, 0.1]], PlanResult.INVALID_INPUT, "not a finite number"),
        ([[0.0] * 6, "abc"], PlanResult.INVALID_INPUT, "list of lists of numbers"),
        ([0.0, 0.1], PlanResult.INVALID_INPUT, "2-D array"),
        ([[0.0] * 6, [0.1] * 6, [0.1] * 6], PlanResult.REPEATED_WAYPOINT, "waypoints 1 and 2 are the same point"),
        (
            [[0.0] * 6, [3.5, 0, 0, 0, 0, 0]],
            PlanResult.WAYPOINT_OUT_OF_LIMITS,
            "waypoint 1, joint joint_1: 3.5 is outside",
        ),
    ],
)
def test_bad_input_gives_a_clear_result(waypoints: object, result: PlanResult, fragment: str) -> None:
    out = Planner(ARM_LIMITS).plan(PlanInput(waypoints))
    assert out.result is result
    assert fragment in out.message, out.message
    assert out.trajectory is None


def test_infeasible_when_gravity_exceeds_the_effort_limit() -> None:
    tiny = JointLimits(
        ARM_LIMITS.names,
        ARM_LIMITS.lower,
        ARM_LIMITS.upper,
        ARM_LIMITS.velocity,
        ARM_LIMITS.acceleration,
        np.full(6, 1.0),
    )
    out = Planner(tiny, ARM.model, torque_limits=True).plan(PlanInput([[0.0, 0.5, 0, 0, 0, 0], [0.5, 0.5, 0, 0, 0, 0]]))
    assert out.result is PlanResult.INFEASIBLE
    assert "satisfies the limits" in out.message


def test_bad_planner_settings() -> None:
    with pytest.raises(ValueError, match="gridpoints"):
        Planner(ARM_LIMITS, gridpoints=1)
    with pytest.raises(ValueError, match="max_tcp_speed"):
        Planner(ARM_LIMITS, ARM.model, "tool0", max_tcp_speed=-1.0)
