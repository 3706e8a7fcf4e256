"""Any waypoints inside the position limits are planned, through every waypoint, inside the limits.

The path is the not-a-knot spline where it stays inside the limits and is clamped (C1) where it
would swing out: random waypoint sets on the shipped cells, drawn by hypothesis (which also tries
the limits themselves, corners of the joint box and joints that do not move), must always plan.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import MIN_WAYPOINT_DISTANCE, JointPath, PlanResult
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

CELLS = {name: load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml").joint_limits() for name in ("arm6", "gantry3")}
PLANNERS = {name: Planner(limits) for name, limits in CELLS.items()}
# a fraction of each joint range: anywhere, or exactly at a limit or in the middle
FRACTION = st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1.0, 0.5]))


def waypoints_in(limits: JointLimits) -> st.SearchStrategy[np.ndarray]:
    """(N, dof) waypoints inside ``limits``, 2 to 8 of them, the limits themselves included."""
    row = st.lists(FRACTION, min_size=limits.dof, max_size=limits.dof)
    return st.lists(row, min_size=2, max_size=8).map(
        lambda f: np.where(np.array(f) >= 1.0, limits.upper, limits.lower + np.array(f) * (limits.upper - limits.lower))
    )


def assert_through_and_inside(path: JointPath, waypoints: np.ndarray, limits: JointLimits) -> None:
    """Every waypoint exactly, the limits everywhere between them (dense samples, both sides of
    every waypoint)."""
    np.testing.assert_allclose(path(path.waypoint_s), waypoints, rtol=0, atol=1e-12)
    s = np.concatenate((np.linspace(0.0, path.length, 20001), path.waypoint_s))
    for q in (path(s), path.on_piece_of(np.maximum(s - 1e-9, 0.0), s, 0)):
        assert np.all(q >= limits.lower - 1e-9) and np.all(q <= limits.upper + 1e-9)


@pytest.mark.parametrize("cell", sorted(CELLS))
def test_any_waypoints_inside_the_limits_are_planned_inside_them(cell: str) -> None:
    limits = CELLS[cell]

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(waypoints=waypoints_in(limits), scale=st.sampled_from([1.0, 1.0, 0.5, 0.3]))
    def check(waypoints: np.ndarray, scale: float) -> None:
        assume(np.all(np.linalg.norm(np.diff(waypoints, axis=0), axis=1) >= MIN_WAYPOINT_DISTANCE))
        out = PLANNERS[cell].plan(PlanInput(waypoints, velocity_scale=scale, acceleration_scale=scale))
        assert out.ok, f"{out.result.value}: {out.message}"
        tr = out.trajectory
        assert tr is not None
        assert_through_and_inside(tr.path, waypoints, limits)
        np.testing.assert_allclose(tr.position(tr.waypoint_times), waypoints, rtol=0, atol=1e-9)
        t = np.concatenate((np.linspace(0.0, tr.duration, 4001), tr.check_times()))
        q = tr.position(t)
        assert np.all(q >= limits.lower - 1e-9) and np.all(q <= limits.upper + 1e-9)
        # the post-check holds both limits at their exact peaks between its samples too; the trajectory
        # read back at a time (s from t, then the spline) and the peaks' closed form in s round
        # differently, seen up to 2e-8 of a limit (the drive-side check of the records is exact)
        assert np.all(np.abs(tr.velocity(t)) <= scale * limits.velocity * (1 + 1e-7))
        assert np.all(np.abs(tr.acceleration(t)) <= scale * limits.acceleration * (1 + 1e-7))

    check()


@pytest.mark.parametrize("cell", sorted(CELLS))
def test_bench_draws_are_all_planned(cell: str) -> None:
    """The benches' draws (8 waypoints in 80 % of every range): about half of them once left the
    limits on the spline; every one is a path now, and those that stayed inside are the spline."""
    limits = CELLS[cell]
    rng = np.random.default_rng(1)
    clamped = 0
    for _ in range(30):
        w = limits.lower + (limits.upper - limits.lower) * (0.1 + 0.8 * rng.random((8, limits.dof)))
        path = JointPath(w, limits)
        assert_through_and_inside(path, w, limits)
        clamped += bool(path.clamped.any())
    assert 5 <= clamped <= 25  # both kinds were drawn


def test_the_spline_stays_where_it_is_inside() -> None:
    """Waypoints whose spline stays inside get the spline itself: C2, no kink, scipy's numbers."""
    from scipy.interpolate import CubicSpline

    limits = CELLS["arm6"]
    w = np.array(
        [[0.0, -1.0, 1.2, 0.3, -0.2, 0.0], [1.1, 0.2, -0.4, -0.6, 0.5, 1.0], [-0.5, 0.6, 0.3, 0.8, -0.7, -1.2]]
    )
    path = JointPath(w, limits)
    assert not path.clamped.any() and len(path.kinks) == 0
    np.testing.assert_array_equal(path.pieces[1], CubicSpline(path.waypoint_s, w, bc_type="not-a-knot").c)


def test_a_swing_past_the_limit_is_clamped_c1_at_the_waypoints() -> None:
    """joint_1 through 2.5, 2.85 (the limit is 2.886) and back to -2: the spline peaks past the limit
    between the last two; the clamped path does not, keeps q and q' continuous, and its second
    derivative jumps only at the kinks it reports."""
    limits = CELLS["arm6"]
    w = np.array([[2.5, 0, 0, 0, 0, 0], [2.85, 0.2, 0, 0, 0, 0], [-2.0, 0.4, 0, 0, 0, 0]])
    out = PLANNERS["arm6"].plan(PlanInput(w))
    assert out.ok, out.message
    path = out.trajectory.path
    assert path.clamped[:, 0].any() and not path.clamped[:, 2:].any()
    assert_through_and_inside(path, w, limits)
    inner = path.waypoint_s[1:-1]
    left = path.waypoint_s[:-2]
    for order in (0, 1):
        np.testing.assert_allclose(path(inner, order), path.on_piece_of(left, inner, order), rtol=0, atol=1e-12)
    jump = np.abs(path(inner, 2) - path.on_piece_of(left, inner, 2)).max(axis=1)
    assert np.all(np.isin(inner[jump > 1e-9], path.kinks))
    # every waypoint and every kink side is a gridpoint: TOPP-RA holds both curvatures there
    assert set(path.waypoint_s) <= set(out.trajectory.gridpoints)


def test_the_safety_net_still_names_the_segment() -> None:
    """The exact check stays: pieces forced out of the limits (not something a waypoint list can
    make) are refused with the segment, joint and value."""
    limits = CELLS["arm6"]
    path = JointPath([[0.0] * 6, [0.5] * 6], limits)
    narrow = JointLimits(
        limits.names, limits.lower, np.full(6, 0.5), limits.velocity, limits.acceleration, limits.effort
    )
    c = path.pieces[1].copy()
    c[1, 0, 0] = 100.0  # a bulge on joint_1
    path._pieces = (path.pieces[0], c)
    with pytest.raises(Exception, match="between waypoints 0 and 1 takes joint joint_1") as exc:
        path.check_within(narrow)
    assert exc.value.result is PlanResult.PATH_OUT_OF_LIMITS
