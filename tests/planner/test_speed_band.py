"""TOPP-RA's profile flattened within a speed band (planner.speed_band): inside the band and the
limits, fewer acceleration switches, TOPP-RA's own profile for jerk-limited plans."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND, flattened
from pvtflow.planner.timing import (
    DEFAULT_GRIDPOINTS,
    RneaJointTorqueConstraint,
    _solve,
    make_gridpoints,
    parameterize,
    timing_constraints,
)
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
GANTRY = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")


def waypoints(cell, n: int = 8, seed: int = 3) -> np.ndarray:
    lim = cell.joint_limits()
    rng = np.random.default_rng(seed)
    return lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((n, lim.dof)))


def switches(traj, limits: JointLimits, fraction: float = 0.01) -> int:
    """Acceleration jumps above ``fraction`` of a joint's limit, over all joints."""
    _, jump = traj.acceleration_jumps()
    return int((jump > fraction * np.asarray(limits.acceleration)).sum())


@pytest.mark.parametrize("cell", [ARM, GANTRY], ids=["arm6", "gantry3"])
def test_flattened_profile_stays_in_the_band_and_the_limits(cell) -> None:
    limits = cell.joint_limits()
    path = JointPath(waypoints(cell), limits)
    cons = timing_constraints(limits)
    topp = parameterize(path, limits, cons)
    band = 0.05
    flat = flattened(topp, limits, band)
    np.testing.assert_array_equal(flat.gridpoints, topp.gridpoints)
    # never faster than TOPP-RA at a gridpoint (s'^2 is linear between them in both: nowhere), at most
    # the band slower
    assert np.all(flat.sd <= topp.sd * (1.0 + 1e-12) + 1e-12)
    assert np.all(flat.sd >= (1.0 - band) * topp.sd * (1.0 - 1e-12))
    assert topp.duration < flat.duration <= topp.duration / (1.0 - band)
    rv, ra = flat.limit_ratios(limits)
    rv0, ra0 = topp.limit_ratios(limits)
    assert rv <= max(1.0, rv0) + 1e-9 and ra <= max(1.0, ra0) + 1e-9
    # the point of it: far fewer acceleration switches for the knots to sit on
    assert switches(flat, limits) < 0.6 * switches(topp, limits)


def test_band_zero_is_toppras_profile() -> None:
    limits = GANTRY.joint_limits()
    path = JointPath(waypoints(GANTRY), limits)
    cons = timing_constraints(limits)
    topp = parameterize(path, limits, cons)
    assert flattened(topp, limits, 0.0) is topp
    np.testing.assert_array_equal(parameterize(path, limits, cons, speed_band=0.0).sd, topp.sd)


def test_flattened_profile_is_kept_only_where_it_holds_the_torque_limits() -> None:
    """Where the cell has torque limits, the flattened profile is kept where it holds them as
    TOPP-RA does (at the gridpoints); where it does not, TOPP-RA's own profile is the plan."""
    base = ARM.joint_limits()
    path = JointPath(waypoints(ARM, 4, seed=5), base)
    cons = timing_constraints(base, ARM.model, torque_limits=True)
    torque = next(c for c in cons if isinstance(c, RneaJointTorqueConstraint))
    own = parameterize(path, base, cons, speed_band=0.0)
    flat = parameterize(path, base, cons, speed_band=0.05)
    assert torque.holds_on(flat) and flat.duration > own.duration
    # at 30 % of the effort limits the flattened profile breaks them at a gridpoint: TOPP-RA's own stays
    weak = JointLimits(base.names, base.lower, base.upper, base.velocity, base.acceleration, base.effort * 0.3)
    weak_cons = timing_constraints(weak, ARM.model, torque_limits=True)
    weak_torque = next(c for c in weak_cons if isinstance(c, RneaJointTorqueConstraint))
    raw = _solve(path, make_gridpoints(path, DEFAULT_GRIDPOINTS), weak, weak_cons)  # before the dense torque check
    assert not weak_torque.holds_on(flattened(raw, weak, 0.05))
    own = parameterize(path, weak, weak_cons, speed_band=0.0)
    np.testing.assert_array_equal(parameterize(path, weak, weak_cons, speed_band=0.05).sd, own.sd)
    # between the gridpoints the torque is held by a slow-down of TOPP-RA's own profile
    assert own.duration > raw.duration and np.allclose(own.sd * own.duration, raw.sd * raw.duration)


def test_planner_flattens_only_plans_without_a_jerk_limit() -> None:
    """A jerk-limited timing starts from TOPP-RA's own profile, whose duration is its lower bound."""
    limits = ARM.joint_limits()
    w = waypoints(ARM, 3, seed=7)
    flat = Planner(limits).plan(PlanInput(w))
    plain = Planner(limits, speed_band=0.0).plan(PlanInput(w))
    assert flat.ok and plain.ok
    assert Planner(limits).speed_band == DEFAULT_SPEED_BAND
    assert plain.trajectory.duration < flat.trajectory.duration <= plain.trajectory.duration / (1 - DEFAULT_SPEED_BAND)
    jerky = Planner(limits).plan(PlanInput(w, max_jerk=10.0 * np.asarray(limits.acceleration)))
    assert jerky.ok
    assert jerky.details["lower_bound_s"] == pytest.approx(plain.trajectory.duration, rel=1e-12)


@pytest.mark.parametrize("band", [-0.1, 1.0, 1.5])
def test_planner_refuses_a_band_outside_0_1(band: float) -> None:
    with pytest.raises(ValueError, match="speed_band must be in"):
        Planner(ARM.joint_limits(), speed_band=band)


def test_a_straight_move_keeps_its_cruise_speed() -> None:
    """Accelerate, cruise, brake along one axis: three spans of constant s'' already, so the band
    gains nothing and costs (almost) nothing; a greedy split cruised at the band's lower edge."""
    limits = GANTRY.joint_limits()
    start = limits.lower + 0.2 * (limits.upper - limits.lower)
    goal = start.copy()
    goal[0] = limits.lower[0] + 0.8 * (limits.upper[0] - limits.lower[0])
    plain = Planner(limits, speed_band=0.0).plan(PlanInput([start, goal])).trajectory
    flat = Planner(limits).plan(PlanInput([start, goal])).trajectory
    assert flat.duration <= plain.duration * 1.005


def test_fewer_spans_than_toppra_with_no_more_time_than_the_band() -> None:
    """The split's own count: the flattened profile switches s'' at a fraction of the gridpoints."""
    limits = GANTRY.joint_limits()
    path = JointPath(waypoints(GANTRY), limits)
    topp = parameterize(path, limits, timing_constraints(limits))
    flat = flattened(topp, limits, DEFAULT_SPEED_BAND)
    changes = np.count_nonzero(np.abs(np.diff(flat.sdd)) > 1e-9 * np.abs(flat.sdd).max())
    assert changes < 0.25 * len(flat.sdd)
    assert flat.duration <= topp.duration / (1.0 - DEFAULT_SPEED_BAND)
