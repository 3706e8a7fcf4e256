"""Jerk-limited timing (planner/jerk): the TOPP-RA path timed again under |q'''| <= max_jerk.

Checked densely (64 samples per grid interval, more than the planner's own check) against every
limit, against TOPP-RA's duration, through the waypoints, and down to the drives' program.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import pvtflow.planner.jerk.solve as jerk_solve
from pvtflow.planner.jerk import JerkTrajectory
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
WAYPOINTS = np.array([[0.0] * 6, [0.6, -0.4, 0.5, 0.3, -0.3, 0.8], [-0.3, 0.2, -0.2, -0.4, 0.2, -0.5]])


@pytest.fixture(scope="module")
def cell_planner() -> CellPlanner:
    return CellPlanner(ARM)


def random_paths(count: int, waypoints: int, seed: int) -> list[np.ndarray]:
    """Random arm6 waypoints inside the middle 80 % of every joint's range (as bench/jerk.py draws them)."""
    rng = np.random.default_rng(seed)
    lo, hi = LIMITS.lower, LIMITS.upper
    return [lo + (hi - lo) * (0.1 + 0.8 * rng.random((waypoints, LIMITS.dof))) for _ in range(count)]


def dense_ratios(traj: JerkTrajectory, max_jerk: np.ndarray) -> tuple[float, float, float]:
    t = traj.check_times(64)
    return (
        float(np.max(np.abs(traj.velocity(t)) / LIMITS.velocity)),
        float(np.max(np.abs(traj.acceleration(t)) / LIMITS.acceleration)),
        float(np.max(np.abs(traj.jerk(t)) / max_jerk)),
    )


@pytest.mark.parametrize("factor", [10.0, 4.0])
def test_jerk_limited_plans_hold_every_limit_densely_and_validate(cell_planner: CellPlanner, factor: float) -> None:
    """Random 6-waypoint arm6 paths, max_jerk = factor x amax per second: |jerk| within 0.1 % of the
    limit, |v| and |a| within theirs, the TCP speed within the cell's, through every waypoint, at
    rest at both ends, no faster than TOPP-RA, and a program the validator accepts."""
    max_jerk = factor * LIMITS.acceleration
    assert cell_planner.planner is not None
    for wp in random_paths(3, 6, seed=int(factor)):
        topp = cell_planner.plan(PlanInput(wp))
        res = cell_planner.plan(PlanInput(wp, max_jerk=max_jerk))
        assert topp.ok and res.ok, res.message
        assert res.plan is not None and topp.plan is not None and res.program is not None
        traj = res.plan.trajectory
        assert isinstance(traj, JerkTrajectory)
        rv, ra, rj = dense_ratios(traj, max_jerk)
        assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9 and rj <= 1.001, (rv, ra, rj)
        assert rj > 0.9  # the jerk limit binds somewhere: it is what makes the motion longer
        assert traj.speed_ratio(cell_planner.planner.constraints) <= 1.0 + 1e-9
        assert traj.duration >= topp.plan.trajectory.duration
        assert np.allclose(traj.position(traj.waypoint_times), wp, atol=1e-9, rtol=0.0)
        assert np.allclose(traj.velocity(np.array([0.0, traj.duration])), 0.0, atol=1e-9)
        assert np.allclose(traj.acceleration(np.array([0.0, traj.duration])), 0.0, atol=1e-6)
        assert res.program.metadata["max_jerk"] == pytest.approx(list(max_jerk))
        assert not validate_program(res.program).errors
        assert res.plan.details["solver"] in ("fatrop", "ipopt")


def test_the_acceleration_is_continuous_where_topp_ra_switches() -> None:
    """TOPP-RA's acceleration jumps between its intervals; the jerk-limited one only by round-off."""
    planner = Planner(LIMITS)
    topp, jl = (
        planner.plan(PlanInput(WAYPOINTS)).trajectory,
        planner.plan(PlanInput(WAYPOINTS, max_jerk=10 * LIMITS.acceleration)).trajectory,
    )
    assert topp is not None and isinstance(jl, JerkTrajectory)
    assert np.max(topp.acceleration_jumps()[1] / LIMITS.acceleration) > 0.5
    assert np.max(jl.acceleration_jumps()[1] / LIMITS.acceleration) < 1e-6


def test_a_lower_jerk_limit_is_slower_and_one_joint_may_go_unlimited() -> None:
    planner = Planner(LIMITS)
    durations = []
    for factor in (20.0, 5.0, 2.0):
        out = planner.plan(PlanInput(WAYPOINTS, max_jerk=factor * LIMITS.acceleration))
        assert out.ok and out.trajectory is not None
        durations.append(out.trajectory.duration)
    assert durations[0] < durations[1] < durations[2]
    only_last = np.full(LIMITS.dof, math.inf)
    only_last[5] = 2.0 * LIMITS.acceleration[5]
    out = planner.plan(PlanInput(WAYPOINTS, max_jerk=only_last))
    assert out.ok and isinstance(out.trajectory, JerkTrajectory)
    t = out.trajectory.check_times(64)
    assert np.max(np.abs(out.trajectory.jerk(t)[:, 5])) <= only_last[5] * 1.001
    assert out.details["max_jerk"] == [*[None] * (LIMITS.dof - 1), only_last[5]]
    assert out.trajectory.duration < durations[2]  # the other joints are free


def test_the_cells_jerk_limit_applies_and_a_requests_replaces_it() -> None:
    cell_jerk = 3.0 * LIMITS.acceleration
    planner = Planner(LIMITS, max_jerk=cell_jerk)
    by_cell = planner.plan(PlanInput(WAYPOINTS))
    assert isinstance(by_cell.trajectory, JerkTrajectory)
    assert by_cell.details["max_jerk"] == pytest.approx(list(cell_jerk))
    by_request = planner.plan(PlanInput(WAYPOINTS, max_jerk=30.0 * LIMITS.acceleration))
    assert isinstance(by_request.trajectory, JerkTrajectory)
    assert by_request.trajectory.duration < by_cell.trajectory.duration
    unlimited = planner.plan(PlanInput(WAYPOINTS, max_jerk=[math.inf] * LIMITS.dof))  # no joint limited: TOPP-RA
    assert unlimited.ok and not isinstance(unlimited.trajectory, JerkTrajectory)
    assert Planner(LIMITS).plan(PlanInput(WAYPOINTS)).trajectory.duration == unlimited.trajectory.duration


def test_the_speed_override_scales_the_jerk_limit_by_the_product_of_its_factors() -> None:
    """velocity_scale k, acceleration_scale k^2 is the motion slowed down in time by k: jerk k^3,
    so the plan held is the unscaled one k times slower. Any other pair: the product, held densely."""
    max_jerk = 10.0 * LIMITS.acceleration
    planner = Planner(LIMITS)
    full = planner.plan(PlanInput(WAYPOINTS, max_jerk=max_jerk))
    half = planner.plan(PlanInput(WAYPOINTS, velocity_scale=0.5, acceleration_scale=0.25, max_jerk=max_jerk))
    assert half.details["max_jerk"] == pytest.approx(list(0.125 * max_jerk))
    assert half.trajectory.duration == pytest.approx(2.0 * full.trajectory.duration, rel=0.02)
    for vs, acc in ((0.5, 1.0), (1.0, 0.3), (0.8, 0.6)):
        out = planner.plan(PlanInput(WAYPOINTS, velocity_scale=vs, acceleration_scale=acc, max_jerk=max_jerk))
        assert out.details["max_jerk"] == pytest.approx(list(vs * acc * max_jerk))
        *_, rj = dense_ratios(out.trajectory, vs * acc * max_jerk)
        assert rj <= 1.001 and rj > 0.9  # held, and the scaled limit is what binds
        assert out.trajectory.duration > full.trajectory.duration


def test_the_program_records_the_scaled_jerk_limit(cell_planner: CellPlanner) -> None:
    max_jerk = 10.0 * LIMITS.acceleration
    res = cell_planner.plan(PlanInput(WAYPOINTS, velocity_scale=0.5, acceleration_scale=0.5, max_jerk=max_jerk))
    assert res.ok, res.message
    assert res.program.metadata["max_jerk"] == pytest.approx(list(0.25 * max_jerk))


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ([100.0] * 5, "max_jerk has 5 values, the cell has 6 joints"),
        ([100.0] * 7, "max_jerk has 7 values"),
        ([100.0, 0.0, 1, 1, 1, 1], "max_jerk[1] must be positive, got 0"),
        ([100.0, 1, -2.0, 1, 1, 1], "max_jerk[2] must be positive, got -2"),
        ([math.nan, 1, 1, 1, 1, 1], "max_jerk[0] must be positive, got nan"),
        ([1, 1, 1, 1, 1, "5"], "max_jerk[5] must be a positive number"),
        ([True, 1, 1, 1, 1, 1], "max_jerk[0] must be a positive number"),
        (100.0, "max_jerk must be a list of 6 positive numbers"),
        ("100,100", "max_jerk must be a list of 6 positive numbers"),
    ],
)
def test_a_bad_jerk_limit_is_refused_naming_the_field_and_nothing_is_planned(value: object, words: str) -> None:
    out = Planner(LIMITS).plan(PlanInput(WAYPOINTS, max_jerk=value))  # type: ignore[arg-type]
    assert not out.ok and out.trajectory is None
    assert out.result.value == "invalid_input"
    assert words in out.message
    assert out.details == {"field": "max_jerk"}
    with pytest.raises(ValueError, match="max_jerk"):
        Planner(LIMITS, max_jerk=value)  # type: ignore[arg-type]


@pytest.fixture
def two_iterations(monkeypatch: pytest.MonkeyPatch):
    """Solvers that give up after 2 iterations: a program they cannot solve in that."""
    jerk_solve.cached_program.cache_clear()
    monkeypatch.setattr(jerk_solve, "_MAX_ITER", 2)
    yield
    jerk_solve.cached_program.cache_clear()


def test_a_program_the_solvers_do_not_solve_is_infeasible_with_their_status(two_iterations: None) -> None:
    out = Planner(LIMITS).plan(PlanInput(WAYPOINTS, max_jerk=10.0 * LIMITS.acceleration))
    assert not out.ok and out.trajectory is None
    assert out.result.value == "infeasible"
    assert "fatrop:" in out.message and "ipopt: Maximum_Iterations_Exceeded" in out.message
    assert out.details["solver_status"] in out.message


def test_a_tiny_jerk_limit_is_met_slowly_not_broken() -> None:
    """A limit a million times below the acceleration limit per second: a long motion within it
    (the start is slowed down towards it, the solvers do not get lost in restoration)."""
    max_jerk = 1e-4 * LIMITS.acceleration
    out = Planner(LIMITS).plan(PlanInput(WAYPOINTS[:2], max_jerk=max_jerk))
    assert out.ok and isinstance(out.trajectory, JerkTrajectory), out.message
    rv, ra, rj = dense_ratios(out.trajectory, max_jerk)
    assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9 and rj <= 1.001


def test_a_path_topp_ra_cruises_on_is_timed_jerk_limited() -> None:
    """TOPP-RA at the velocity limit on most of its intervals (a 75th percentile of |s''| of 0):
    the warm profile still moves (it was braked to rest everywhere, and the grid's share of a zero
    duration never settled), and the plan holds every limit."""
    from pvtflow.planner.jerk.warm import WarmProfile
    from pvtflow.planner.timing import parameterize, timing_constraints

    wp = np.array([[1.47, -1.15, 1.78, 2.12, -0.81, 0.67], [-0.65, 0.6, -1.57, -0.14, 0.28, 0.6]])
    topp = Planner(LIMITS).plan(PlanInput(wp)).trajectory
    assert np.percentile(np.abs(topp.sdd), 75) == 0.0  # the case: a cruise on most intervals
    path = topp.path
    warm = parameterize(path, LIMITS, timing_constraints(LIMITS))
    profile = WarmProfile.of(warm, np.array([0.0, path.length]))
    assert profile.t[-1] > 0.0
    max_jerk = 10.0 * LIMITS.acceleration
    out = Planner(LIMITS).plan(PlanInput(wp, max_jerk=max_jerk))
    assert out.ok, out.message
    assert max(dense_ratios(out.trajectory, max_jerk)) <= 1.001
    assert out.trajectory.duration >= topp.duration
