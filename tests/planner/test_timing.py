"""TOPP-RA pieces: the cell's torque constraint, the lean algorithm, trajectory sampling."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import toppra
import toppra.algorithm as algo
import toppra.constraint as constraint

from pvtflow.planner.constraints import TORQUE_MIDDLE_MARGIN
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.timing import (
    DEFAULT_GRIDPOINTS,
    LeanTOPPRA,
    RneaJointTorqueConstraint,
    _solve,
    make_gridpoints,
    parameterize,
    timing_constraints,
)
from pvtflow.planner.trajectory import Trajectory
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
WAYPOINTS = np.array(
    [
        [0.0, -1.0, 1.2, 0.3, -0.2, 0.0],
        [1.1, 0.2, -0.4, -0.6, 0.5, 1.0],
        [-0.5, 0.6, 0.3, 0.8, -0.7, -1.2],
        [0.4, -0.3, -0.9, 0.1, 0.3, 0.4],
    ]
)


def test_torque_constraint_equals_toppras() -> None:
    """Same a, b, c as toppra's JointTorqueConstraint on Pinocchio's RNEA (three calls per gridpoint)."""
    path = JointPath(WAYPOINTS, LIMITS)
    grid = make_gridpoints(path, 60)
    ours = RneaJointTorqueConstraint(ARM.model, LIMITS.effort).compute_constraint_params(path, grid)
    stock = constraint.JointTorqueConstraint(
        ARM.model.inverse_dynamics,
        np.column_stack((-LIMITS.effort, LIMITS.effort)),
        np.zeros(6),
        discretization_scheme=constraint.DiscretizationType.Collocation,
    ).compute_constraint_params(path, grid)
    for mine, theirs in zip(ours[:3], stock[:3], strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-9)
    # same rows: F tau <= g  <=>  -effort <= tau <= effort
    np.testing.assert_array_equal(ours[3], stock[3])
    np.testing.assert_array_equal(ours[4], stock[4])


def test_lean_toppra_equals_toppra_on_the_cell_constraints() -> None:
    """The skipped lower-bound LPs and the batched constraints change nothing: toppra's own TOPPRA
    (seidel) gives the same controllable sets and path velocities."""
    path = JointPath(WAYPOINTS, LIMITS)
    grid = make_gridpoints(path, 80)
    cons = timing_constraints(LIMITS, ARM.model, torque_limits=True, tcp_frame="tool0", max_tcp_speed=2.0)
    lean = LeanTOPPRA(cons, path, grid)
    stock = algo.TOPPRA(cons, path, gridpoints=grid, solver_wrapper="seidel")
    # the stock lower bounds are 0 up to the LP's round-off (1e-16)
    K_lean, K_stock = lean.compute_controllable_sets(0.0, 0.0), stock.compute_controllable_sets(0.0, 0.0)
    np.testing.assert_allclose(K_lean, K_stock, rtol=1e-12, atol=1e-12)
    sd_lean = lean.compute_parameterization(0.0, 0.0)[1]
    sd_stock = stock.compute_parameterization(0.0, 0.0)[1]
    np.testing.assert_allclose(sd_lean, sd_stock, rtol=1e-9, atol=1e-9)


def _sets_by_toppras_wrapper(lean: LeanTOPPRA) -> np.ndarray:
    """The controllable sets with every LP the compiled pass solves put to toppra's own seidel solver
    wrapper (Cython), call by call in the same order, the same closed-form skips."""
    n, rows, wrapper = lean._N, lean._rows, lean.solver_wrapper
    K = np.full((n + 1, 2), np.nan)
    K[n] = (0.0, 0.0)
    g_max = np.zeros(wrapper.get_no_vars())
    g_max[0], g_max[1] = 1e-9, -1.0
    two_delta = 2.0 * wrapper.get_deltas()
    (u_lo, u_hi), lo, hi = lean._u_top, 0.0, 0.0
    for i in range(n - 1, -1, -1):
        x = lean._x_top[i]
        first = max(u_lo[i], (lo - x) / two_delta[i])
        if first + 1e-9 * (1.0 + abs(first)) <= min(u_hi[i], (hi - x) / two_delta[i]):
            x_hi = x
        else:
            x_hi = wrapper.solve_stagewise_optim(i, None, g_max, np.nan, np.nan, lo, hi)[1]
            if x_hi != x_hi:
                x_hi = rows.x_extreme(i, two_delta[i], lo, hi, highest=True)
        x_lo = (
            0.0
            if lo == 0.0 and lean._rest[i]
            else wrapper.solve_stagewise_optim(i, None, -g_max, np.nan, np.nan, lo, hi)[1]
        )
        if x_lo != x_lo and x_hi == x_hi:
            x_lo = rows.x_extreme(i, two_delta[i], lo, hi, highest=False)
        lo, hi = max(x_lo, 0.0), x_hi
        if lo != lo or hi != hi:
            break
        K[i] = lo, hi
    return K


def test_compiled_backward_pass_is_toppras_seidel_solver_bit_for_bit() -> None:
    """The backward pass's 2-D LPs, solved in the compiled loop, give what toppra's seidel solver
    wrapper gives, bit for bit (its warm starts included), on random paths of both cells, with and
    without binding torque limits, on coarse and fine grids."""
    rng = np.random.default_rng(11)
    gantry = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
    weak = JointLimits(
        LIMITS.names, LIMITS.lower, LIMITS.upper, LIMITS.velocity, LIMITS.acceleration, LIMITS.effort * 0.3
    )
    cases = [
        (LIMITS, timing_constraints(LIMITS, ARM.model, True, "tool0", 2.0)),
        (LIMITS, timing_constraints(weak, ARM.model, True, "tool0", 2.0)),
        (gantry.joint_limits(), timing_constraints(gantry.joint_limits(), gantry.model, False, "tool0", 1.0)),
    ]
    lps = 0
    for limits, cons in cases:
        for _ in range(6):
            w = limits.lower + (limits.upper - limits.lower) * (
                0.05 + 0.9 * rng.random((int(rng.integers(2, 9)), limits.dof))
            )
            path = JointPath(w, limits)
            lean = LeanTOPPRA(cons, path, make_gridpoints(path, int(rng.choice([20, 60, 140]))))
            K = lean.compute_controllable_sets(0.0, 0.0)
            np.testing.assert_array_equal(K, _sets_by_toppras_wrapper(lean))
            lps += int(np.sum(K[:-1, 1] != lean._x_top[:-1]))
    assert lps > 100  # stages whose upper end the LP gave


def test_lower_bound_lp_still_solved_where_rest_is_not_allowed() -> None:
    """Where gravity alone exceeds an effort limit, standing still is infeasible: the LP decides."""
    weak = JointLimits(LIMITS.names, LIMITS.lower, LIMITS.upper, LIMITS.velocity, LIMITS.acceleration, np.ones(6))
    path = JointPath(WAYPOINTS[:2], LIMITS)
    cons = timing_constraints(weak, ARM.model, torque_limits=True)
    K = LeanTOPPRA(cons, path, make_gridpoints(path, 20)).compute_controllable_sets(0.0, 0.0)
    assert np.isnan(K).any()


def test_states_equal_position_and_velocity() -> None:
    """The one-pass sampling (rows per joint) is the path's own spline at s(t), times s'(t)."""
    tr = Planner(LIMITS, ARM.model, "tool0", 2.0, torque_limits=True).plan(PlanInput(WAYPOINTS)).trajectory
    assert tr is not None
    t = np.concatenate((np.linspace(-0.1, tr.duration + 0.1, 1001), tr.breakpoints))
    q, qd = tr.states(t)
    assert q.shape == qd.shape == (6, len(t))
    scale = np.abs(tr.path.points).max()
    np.testing.assert_allclose(q.T, tr.position(t), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(qd.T, tr.velocity(t), rtol=0, atol=1e-12 * np.abs(qd).max())
    q1, qd1 = tr.states(0.5 * tr.duration)
    np.testing.assert_allclose(qd1[:, 0], tr.velocity(0.5 * tr.duration), rtol=0, atol=1e-12 * np.abs(qd).max())
    np.testing.assert_allclose(q1[:, 0], tr.position(0.5 * tr.duration), rtol=0, atol=1e-12 * scale)
    assert tr.states(np.array([]))[0].shape == (6, 0)
    # the pass walks on from one sample's interval to the next: times in any order give the same
    order = np.random.default_rng(3).permutation(len(t))
    q2, qd2 = tr.states(t[order])
    np.testing.assert_array_equal(q2, q[:, order])
    np.testing.assert_array_equal(qd2, qd[:, order])


def test_acceleration_jumps_are_the_switches_of_the_profile() -> None:
    tr = Planner(LIMITS, ARM.model, "tool0", 2.0).plan(PlanInput(WAYPOINTS)).trajectory
    assert tr is not None
    times, jumps = tr.acceleration_jumps()
    np.testing.assert_array_equal(times, tr.breakpoints[1:-1])
    eps = 1e-9 * tr.duration
    seen = np.abs(tr.acceleration(times + eps) - tr.acceleration(times - eps))
    np.testing.assert_allclose(jumps, seen, rtol=1e-5, atol=1e-6 * np.abs(seen).max())
    assert jumps.max() > 0.1 * np.abs(tr.acceleration(times)).max()  # a time-optimal profile does switch


def test_acceleration_jumps_are_the_numpy_statements_bit_for_bit() -> None:
    """The compiled pass gives what q_s diff(s'') + (q_ss+ - q_ss-) s'^2 in numpy gives, on paths
    with clamped waypoints (the second derivative jumps there) too."""
    rng = np.random.default_rng(7)
    planner = Planner(LIMITS)
    kinked = 0
    for _ in range(30):
        w = LIMITS.lower + (LIMITS.upper - LIMITS.lower) * (0.02 + 0.96 * rng.random((6, LIMITS.dof)))
        tr = planner.plan(PlanInput(w)).trajectory
        assert tr is not None
        kinked += len(tr.path.kinks) > 0
        grid = tr.gridpoints
        curvature = tr.path(grid[1:-1], 2) - tr.path.on_piece_of(grid[:-2], grid[1:-1], 2)
        numpy = np.abs(tr.path(grid[1:-1], 1) * np.diff(tr.sdd)[:, None] + curvature * (tr.sd[1:-1] ** 2)[:, None])
        np.testing.assert_array_equal(tr.acceleration_jumps()[1], numpy)
    assert kinked > 0


def test_stage_rows_are_the_matrix_products() -> None:
    """``StageRows.stack`` (one compiled loop per constraint, F's nonzeros only) gives the stacked
    F a, F b, F c - h of every constraint of the cell, torque included, as numpy's products do."""
    from pvtflow.planner.topp.rows import StageRows, times

    planner = Planner(LIMITS, ARM.model, "tool0", 2.0, torque_limits=True)
    path = JointPath(WAYPOINTS, LIMITS)
    grid = make_gridpoints(path, 60)
    params = [c.compute_constraint_params(path, grid) for c in planner.constraints]
    rows = StageRows.stack(params, len(grid))
    live = [p for p in params if p[0] is not None]
    np.testing.assert_array_equal(rows.A, np.hstack([times(p[3], p[0]) for p in live]))
    np.testing.assert_array_equal(rows.B, np.hstack([times(p[3], p[1]) for p in live]))
    np.testing.assert_array_equal(rows.C, np.hstack([times(p[3], p[2]) - p[4] for p in live]))


@pytest.mark.parametrize("max_speed", [0.5, 2.0])
def test_cell_plan_holds_torque_at_the_gridpoints_and_tcp_speed(max_speed: float) -> None:
    tr = Planner(LIMITS, ARM.model, "tool0", max_speed, torque_limits=True).plan(PlanInput(WAYPOINTS)).trajectory
    assert tr is not None
    t = tr.breakpoints
    tau = ARM.model.inverse_dynamics_rows(tr.position(t), tr.velocity(t), tr.acceleration(t))
    assert np.all(np.abs(tau) <= LIMITS.effort * (1 + 1e-6))
    mid = 0.5 * (t[1:] + t[:-1])
    speed = ARM.model.frame_speeds(tr.position(mid), tr.velocity(mid), "tool0")
    assert speed.max() <= max_speed * 1.005


def test_deferred_torque_limits_give_the_same_plan_as_solving_with_them() -> None:
    """parameterize solves without the torque rows first and checks the result against them: where
    they hold, that is the plan with them; where they do not, it solves again with them."""
    path = JointPath(WAYPOINTS, LIMITS)
    cons = timing_constraints(LIMITS, ARM.model, torque_limits=True, tcp_frame="tool0", max_tcp_speed=2.0)
    torque = next(c for c in cons if isinstance(c, RneaJointTorqueConstraint))
    fast = parameterize(path, LIMITS, cons)
    assert torque.holds_on(fast)
    full, _ = _solve(path, make_gridpoints(path, DEFAULT_GRIDPOINTS), LIMITS, cons)
    np.testing.assert_allclose(fast.sd, full.sd, rtol=1e-9, atol=1e-9)
    assert fast.duration == pytest.approx(full.duration, rel=1e-12)

    weak = JointLimits(
        LIMITS.names, LIMITS.lower, LIMITS.upper, LIMITS.velocity, LIMITS.acceleration, LIMITS.effort * 0.3
    )
    weak_cons = timing_constraints(weak, ARM.model, torque_limits=True)
    weak_torque = next(c for c in weak_cons if isinstance(c, RneaJointTorqueConstraint))
    free = parameterize(path, weak, [c for c in weak_cons if c is not weak_torque])
    assert not weak_torque.holds_on(free)  # the unconstrained plan needs more torque than there is
    held = parameterize(path, weak, weak_cons)
    assert weak_torque.holds_on(held)
    assert held.duration > free.duration


def _end_torques(tr: Trajectory) -> np.ndarray:
    """Pinocchio's RNEA, call by call, at the exact states of both ends of every interval: the
    starts with their own s'', then the ends on the interval's own piece with the interval's s''
    (not the next one's)."""
    path, grid, sd, sdd = tr.path, tr.gridpoints, tr.sd, tr.sdd
    start = grid[:-1]
    q_s, q_ss = path.on_piece_of(start, start, 1), path.on_piece_of(start, start, 2)
    e_s, e_ss = path.on_piece_of(start, grid[1:], 1), path.on_piece_of(start, grid[1:], 2)
    states = [
        (path.on_piece_of(start, start, 0), q_s * sd[:-1, None], q_ss * (sd[:-1] ** 2)[:, None] + q_s * sdd[:, None]),
        (path.on_piece_of(start, grid[1:], 0), e_s * sd[1:, None], e_ss * (sd[1:] ** 2)[:, None] + e_s * sdd[:, None]),
    ]
    return np.vstack([[ARM.model.inverse_dynamics(*row) for row in zip(*s, strict=True)] for s in states])


@pytest.mark.parametrize("scale", [1.0, 0.3])
def test_torque_check_is_pinocchios_rnea_or_a_bound_at_both_ends_of_every_interval(scale: float) -> None:
    """The torque check takes Pinocchio's RNEA at the exact states of every gridpoint and of the
    interval ends it cannot bound clear of the middle margin; where it bounds one, the end's own
    torque is within that bound, and the decisions are those of every end's torque (a plan far from
    the limits and one over them)."""
    effort = LIMITS.effort * scale
    lim = JointLimits(LIMITS.names, LIMITS.lower, LIMITS.upper, LIMITS.velocity, LIMITS.acceleration, effort)
    torque = RneaJointTorqueConstraint(ARM.model, effort)
    tr = parameterize(JointPath(WAYPOINTS, LIMITS), lim, timing_constraints(lim), speed_band=0.05)
    check, expected, m = torque.check(tr), _end_torques(tr), len(tr.sdd)
    computed = ~check.bounded
    np.testing.assert_allclose(check.tau[computed], expected[computed], rtol=1e-12, atol=1e-9)
    ratio = np.abs(expected) / effort
    assert np.all(ratio[check.bounded] <= 1.0 - TORQUE_MIDDLE_MARGIN)
    assert check.holds == bool(np.all(ratio[:m] <= 1.0) and np.all(ratio[-1] <= 1.0)) == torque.holds_on(tr)
    worst = ratio.max(axis=1)
    np.testing.assert_array_equal(
        check._near, np.flatnonzero(np.maximum(worst[:m], worst[m:]) > 1.0 - TORQUE_MIDDLE_MARGIN)
    )
    if scale == 1.0:  # far from the limits: most ends bounded, no slow-down
        assert check.bounded.sum() > m / 2 and check.holds and check.slowdown() == 1.0
    else:  # over a limit: the slow-down from every end and middle, as the constraint's own check
        assert not check.holds and check.slowdown() > 1.0
    assert check.slowdown() == pytest.approx(torque.slowdown(tr), rel=1e-6)
    mid = 0.5 * (tr.breakpoints[:-1] + tr.breakpoints[1:])
    q, qd, qdd, tau = check._middles(np.arange(m))
    np.testing.assert_allclose(q, tr.position(mid), atol=1e-12)
    np.testing.assert_allclose(qd, tr.velocity(mid), atol=1e-12)
    np.testing.assert_allclose(qdd, tr.acceleration(mid), atol=1e-9)
    np.testing.assert_allclose(tau, ARM.model.inverse_dynamics_rows(tr.position(mid), qd, qdd), atol=1e-9)


def test_mass_matrix_bound_holds_over_the_joint_ranges() -> None:
    """|M(q) v| <= mass_matrix_bound |v| at every configuration (Pinocchio's CRBA at random q in
    the limits), and it is not so loose that it bounds nothing (within 20 x)."""
    bound = ARM.model.mass_matrix_bound()
    rng = np.random.default_rng(3)
    worst = 0.0
    for q in rng.uniform(LIMITS.lower, LIMITS.upper, (300, LIMITS.dof)):
        M = pin.crba(ARM.model.model, ARM.model.data, q)
        worst = max(worst, float(np.linalg.eigvalsh(np.triu(M) + np.triu(M, 1).T).max()))
    assert worst <= bound <= 20.0 * worst


@pytest.mark.parametrize("scale", [1.0, 0.5, 0.3])
def test_an_intervals_inside_adds_far_less_torque_than_the_middle_margin(scale: float) -> None:
    """The torque check takes an interval's middle only where one of its ends is within
    TORQUE_MIDDLE_MARGIN of a limit: on the cell's paths, binding or not, the inside of every
    interval (19 samples) exceeds the larger of its ends by less than a third of that margin."""
    effort = LIMITS.effort * scale
    lim = JointLimits(LIMITS.names, LIMITS.lower, LIMITS.upper, LIMITS.velocity, LIMITS.acceleration, effort)
    planner = Planner(lim, ARM.model, "tool0", max_tcp_speed=2.0, torque_limits=True)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(12):
        w = LIMITS.lower + (LIMITS.upper - LIMITS.lower) * (0.1 + 0.8 * rng.random((8, LIMITS.dof)))
        out = planner.plan(PlanInput(w))
        assert out.ok, out.message
        tr = out.trajectory
        t = tr.check_times(19)
        tau = ARM.model.inverse_dynamics_rows(tr.position(t), tr.velocity(t), tr.acceleration(t))
        r = (np.abs(tau) / effort).reshape(len(tr.sdd), 21, -1)
        assert r.max() <= 1.0 + 1e-3  # and the plan holds the limits
        worst = max(worst, float((r[:, 1:-1].max(axis=1) - np.maximum(r[:, 0], r[:, -1])).max()))
    assert worst < TORQUE_MIDDLE_MARGIN / 3


def test_limit_ratios_are_the_paths_own_derivatives() -> None:
    """The compiled post-check gives what the path's own derivatives say: |qd| and |qdd| at every
    check time and at their peaks inside every grid interval (at least the check times' worst, at
    most a dense sampling's, within the sampling's error)."""
    tr = Planner(LIMITS, ARM.model, "tool0", 2.0).plan(PlanInput(WAYPOINTS)).trajectory
    assert tr is not None

    def ratios(t: np.ndarray) -> tuple[float, float]:
        s, sd, sdd, start, _ = tr._state(t)
        qs = tr.path.on_piece_of(start, s, 1)
        qdd = tr.path.on_piece_of(start, s, 2) * (sd * sd)[:, None] + qs * sdd[:, None]
        return float(np.max(np.abs(qs * sd[:, None]) / LIMITS.velocity)), float(
            np.max(np.abs(qdd) / LIMITS.acceleration)
        )

    rv, ra = tr.limit_ratios(LIMITS)
    rv_check, ra_check = ratios(tr.check_times())
    b = tr.breakpoints
    dense = (b[:-1, None] + np.diff(b)[:, None] * np.linspace(0.0, 1.0, 257)[None, 1:-1]).ravel()
    rv_dense, ra_dense = ratios(np.concatenate((tr.check_times(), dense)))
    assert rv_check * (1 - 1e-12) <= rv <= rv_dense * (1 + 1e-6)
    assert ra_check * (1 - 1e-12) <= ra <= ra_dense * (1 + 1e-6)
    assert 0.5 < max(rv, ra) <= 1.0 + 1e-9  # a time-optimal plan reaches a limit, and keeps it


def test_path_evaluation_is_toppras_spline() -> None:
    """JointPath evaluates its spline in one compiled pass; the numbers are toppra's (scipy's
    CubicSpline and its derivatives), scalars and arrays alike, past the ends too."""
    path = JointPath(WAYPOINTS, LIMITS)
    ref = toppra.SplineInterpolator(path.waypoint_s, path.points, bc_type="not-a-knot")
    s = np.concatenate((np.linspace(-0.1, path.length + 0.1, 997), path.waypoint_s))
    for order in (0, 1, 2):
        want = ref(s, order)
        np.testing.assert_allclose(path(s, order), want, rtol=0, atol=1e-12 * np.abs(want).max())
        np.testing.assert_allclose(path(s[5], order), ref(s[5], order), rtol=0, atol=1e-12 * np.abs(want).max())
        assert path(s[:1000].reshape(-1, 2)[:, :1], order).shape == (500, 1, LIMITS.dof)
    with pytest.raises(ValueError, match="order"):
        path(s, 3)


def test_compiled_forward_pass_equals_toppras_on_random_paths() -> None:
    """The forward pass's one-variable LPs, solved in the compiled loop, give toppra's own path
    velocities (stock TOPPRA, seidel) on random paths of the cell's constraints."""
    rng = np.random.default_rng(21)
    cons = timing_constraints(LIMITS, ARM.model, tcp_frame="tool0", max_tcp_speed=2.0)
    compared = 0
    while compared < 15:
        wp = LIMITS.lower + (LIMITS.upper - LIMITS.lower) * (0.25 + 0.5 * rng.random((5, LIMITS.dof)))
        try:
            path = JointPath(wp, LIMITS)
        except PlanError:
            continue  # the spline leaves the limits between waypoints: not a path
        grid = make_gridpoints(path, 100)
        sd_lean = LeanTOPPRA(cons, path, grid).compute_parameterization(0.0, 0.0)[1]
        stock = algo.TOPPRA(cons, path, gridpoints=grid, solver_wrapper="seidel")
        sd_stock = stock.compute_parameterization(0.0, 0.0)[1]
        np.testing.assert_allclose(sd_lean, sd_stock, rtol=1e-9, atol=1e-9)
        compared += 1
