"""The compiled steps of a plan give what their numpy statements give, bit for bit.

``fit_knots`` (``refine_kernels.fit_rounds``), ``quantize_checked`` (``round_kernels.round_check_repair``)
and ``split_verdict`` each do in one call what ``lsq_fit`` / ``split_segments``, ``round_knots`` /
``check_knots`` / ``repair_rounds`` and a few numpy operations do step by step; the TOPP-RA backward
pass skips its LPs in a compiled loop (``topp.passes.known_stages``) where the stage's set is known;
the interval speed constraints build their rows in one (``constraints._interval_rows``), and the
stages' ranges of u at x in another (``topp.rows.u_range``). The path's not-a-knot spline is
scipy's ``CubicSpline`` without its wrapper (``path.not_a_knot``), the grid one ``np.unique`` of the
candidates the unions gave.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.constraints import _IntervalSpeedConstraint
from pvtflow.planner.knots import KnotError, KnotOptions, epos2
from pvtflow.planner.knots.check import axes_records, axis_records, check_knots, knot_records, over_limit
from pvtflow.planner.knots.flat import Flat
from pvtflow.planner.knots.quantize import quantize_checked, repair_rounds, round_knots
from pvtflow.planner.knots.refine import fit_knots, lsq_fit, split_segments
from pvtflow.planner.knots.round_kernels import split_verdict
from pvtflow.planner.knots.samples import sample_trajectory
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.timing import make_gridpoints
from pvtflow.planner.topp.lean import LeanTOPPRA
from pvtflow.service.cell_planner import planner_for_cell
from pvtflow.service.config import load_cell_config


@pytest.fixture(scope="module")
def arm6_flat():
    cell = load_cell_config()
    axes = list(cell.ordered_axes())
    lim = cell.joint_limits()
    rng = np.random.default_rng(5)
    wp = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((6, lim.dof)))
    planner = planner_for_cell(cell)
    out = planner.plan(PlanInput(wp))
    assert out.ok, out.message
    smp = sample_trajectory(out.trajectory, axes, 1.0)
    return planner, out.trajectory, Flat.of(axes, list(range(len(axes))), smp)


def _fit_step_by_step(fl: Flat, knots: np.ndarray, target: float, max_rounds: int):
    fitted = None
    for _ in range(max_rounds):
        fitted = lsq_fit(fl, knots, fitted, target)
        T = np.diff(knots)
        bad = np.flatnonzero(((fitted.worst > target) & (T >= 2)) | (T > TIME_MAX_MS))
        if not len(bad):
            break
        knots = split_segments(knots, bad)
    return knots, fitted


@pytest.mark.parametrize(("spacing", "target", "rounds"), [(120, 0.8, 40), (300, 0.3, 40), (200, 0.5, 2)])
def test_fit_rounds_are_the_steps(arm6_flat, spacing: int, target: float, rounds: int) -> None:
    _, _, fl = arm6_flat
    start = fl.flat_knots([np.arange(0, fl.stride - 1, spacing) for _ in fl.axes])
    knots, fitted = fit_knots(fl, start, target, rounds)
    ref_knots, ref = _fit_step_by_step(fl, start, target, rounds)
    np.testing.assert_array_equal(knots, ref_knots)
    for got, want in ((fitted.knots, ref.knots), (fitted.rhs, ref.rhs), (fitted.P, ref.P), (fitted.V, ref.V)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(fitted.worst, ref.worst)
    if rounds == 2:  # ran out of rounds: the knots were split after the last fit
        assert len(knots) > len(fitted.knots)


@pytest.mark.parametrize("spacing", [15, 40, 90])
def test_quantize_checked_is_round_check_repair(arm6_flat, spacing: int) -> None:
    _, _, fl = arm6_flat
    knots = fl.flat_knots([np.arange(0, fl.stride - 1, spacing) for _ in fl.axes])
    fit = lsq_fit(fl, knots)
    prev = None
    for p, v in ((fit.P, fit.V), (fit.P + 0.3, fit.V * 1.01)):  # the second reuses the first's check
        P, V, checked = quantize_checked(fl, knots, p, v, prev, 1.0)
        P0, V0 = round_knots(fl, knots, p, v)
        _, P1, V1, ref = repair_rounds(fl, knots, P0, V0, check_knots(fl, knots, P0, V0, prev), 1.0)
        np.testing.assert_array_equal(P, P1)
        np.testing.assert_array_equal(V, V1)
        np.testing.assert_array_equal(checked.P, ref.P)
        np.testing.assert_array_equal(checked.V, ref.V)
        for field in ("seg_deviation", "velocity_ratio", "acceleration_ratio", "position_out"):
            np.testing.assert_array_equal(getattr(checked.chk, field), getattr(ref.chk, field))
        prev = checked


def test_repairs_remembered_from_the_last_round_are_the_search(arm6_flat, monkeypatch) -> None:
    """A chain whose records a previous round's repair already searched gets that repair's records
    (``repair_chains_memo``): each round of a placement gives the records the search gives
    (``repair_rounds``, no memo)."""
    _, _, fl = arm6_flat
    calls = []

    def recorded(fl, knots, p, v, prev, tol):
        out = quantize_checked(fl, knots, p, v, prev, tol)
        calls.append((fl, knots, p, v, tol, out))
        return out

    monkeypatch.setattr(epos2, "quantize_checked", recorded)
    # 0x60C5 a hair lower than the cell's: rounding crosses it on many segments, round after round
    tight = dataclasses.replace(fl, ra_per=fl.ra_per * 1.003)
    epos2.place_epos2(tight, sample_trajectory(arm6_flat[1], tight.axes, 1.0), list(range(len(fl.axes))),
                      KnotOptions(), epos2.Start.LEAST_SQUARES)  # fmt: skip
    remembered = 0
    for i, (f, knots, p, v, tol, (P, V, checked)) in enumerate(calls):
        P0, V0 = round_knots(f, knots, p, v)
        _, P1, V1, ref = repair_rounds(f, knots, P0, V0, check_knots(f, knots, P0, V0), tol)
        np.testing.assert_array_equal(P, P1)
        np.testing.assert_array_equal(V, V1)
        np.testing.assert_array_equal(checked.P, ref.P)
        for field in ("seg_deviation", "velocity_ratio", "acceleration_ratio", "position_out"):
            np.testing.assert_array_equal(getattr(checked.chk, field), getattr(ref.chk, field))
        if i:  # rows of a chain this round searched or took from the last round's memo
            last = {tuple(r) for r in calls[i - 1][5][2].memo[1].tolist()}
            remembered += sum(tuple(r) in last for r in checked.memo[1].tolist())
    assert len(calls) >= 2 and remembered > 0


def test_quantize_checked_refuses_what_no_record_holds(arm6_flat) -> None:
    _, _, fl = arm6_flat
    knots = fl.flat_knots([np.arange(0, fl.stride - 1, 50) for _ in fl.axes])
    fit = lsq_fit(fl, knots)
    for p, v, what in ((fit.P + 1e12, fit.V, "int32 position"), (fit.P, fit.V * 1e12, None)):
        if what is None:  # velocities are clipped to 0x607F first: only a unit finer than int24 fails
            P, V, _ = quantize_checked(fl, knots, p, v, None, 1.0)
            np.testing.assert_array_equal((P, V), round_knots(fl, knots, p, v))
            continue
        with pytest.raises(KnotError, match=what):
            quantize_checked(fl, knots, p, v, None, 1.0)
        with pytest.raises(KnotError, match=what):
            round_knots(fl, knots, p, v)


def test_split_verdict_is_the_numpy_rule(arm6_flat) -> None:
    _, _, fl = arm6_flat
    rng = np.random.default_rng(2)
    knots = fl.flat_knots([np.arange(0, fl.stride - 1, 25) for _ in fl.axes])
    fit = lsq_fit(fl, knots)
    chk = quantize_checked(fl, knots, fit.P, fit.V, None, 1.0)[2].chk
    n = len(fl.axes)
    for tol, jerk, last in (
        (1.0, np.zeros(0, dtype=np.int64), np.full(n, np.iinfo(np.int64).max)),
        (0.05, rng.choice(len(knots) - 1, 9, replace=False), rng.integers(0, 4, n)),
        (0.5, np.sort(rng.choice(len(knots) - 1, 30, replace=False)), np.zeros(n, dtype=np.int64)),
    ):
        bad, n_stuck, strays = split_verdict(
            knots, fl.stride, chk.seg_deviation, chk.position_out, chk.velocity_ratio, chk.acceleration_ratio,
            tol, jerk, last, 24,
        )  # fmt: skip
        T = np.diff(knots)
        ref_bad = np.flatnonzero((chk.seg_deviation > tol) | chk.position_out)
        ref_bad = ref_bad[T[ref_bad] >= 2]
        stuck = np.union1d(np.flatnonzero(over_limit(chk)), jerk)
        ax_stuck = fl.axis_of(knots[stuck])
        ref_n = np.bincount(ax_stuck, minlength=n)
        ref_strays = np.zeros(n, dtype=bool)
        ref_strays[fl.axis_of(knots[ref_bad])] = True
        give_up = (ref_n > 0) & ~ref_strays & (ref_n >= last)
        stuck = stuck[~give_up[ax_stuck]]
        np.testing.assert_array_equal(bad, np.union1d(ref_bad, stuck[T[stuck] >= 24]))
        np.testing.assert_array_equal(n_stuck, ref_n)
        np.testing.assert_array_equal(strays, ref_strays)


def test_axis_records_read_back(arm6_flat) -> None:
    _, _, fl = arm6_flat
    knots = fl.flat_knots([np.arange(0, fl.stride - 1, 30) for _ in fl.axes])
    fit = lsq_fit(fl, knots)
    P, V, checked = quantize_checked(fl, knots, fit.P, fit.V, None, 1.0)
    chk = checked.chk
    for a in range(len(fl.axes)):
        k0, k1 = np.searchsorted(knots, [a * fl.stride, (a + 1) * fl.stride])
        records = knot_records(fl, a, knots, P, V, 3)
        np.testing.assert_array_equal(records[:-1, :2], np.column_stack((P[k0:k1], V[k0:k1])))
        np.testing.assert_array_equal(records[-1], [P[k1 - 1], 0, 0])
        np.testing.assert_array_equal(records[:-1, 2], np.concatenate(([3], np.diff(knots[k0:k1]))))
        placed, _ = axis_records(fl, a, knots, P, V, chk, 3)
        assert placed.deviation_qc == chk.seg_deviation[k0 : k1 - 1].max()
        assert placed.velocity_ratio == chk.velocity_ratio[k0 : k1 - 1].max()
        assert placed.acceleration_ratio == chk.acceleration_ratio[k0 : k1 - 1].max()
    # several axes in one call: each as alone
    some = [0, 2, 3, len(fl.axes) - 1]
    together = axes_records(fl, some, knots, P, V, chk, 3)
    assert list(together) == some
    for a in some:
        alone, scale = axis_records(fl, a, knots, P, V, chk, 3)
        np.testing.assert_array_equal(together[a][0].records, alone.records)
        assert together[a][0] == dataclasses.replace(alone, records=together[a][0].records)
        assert together[a][1] == scale


def test_backward_pass_shortcuts_match_the_lps(arm6_flat) -> None:
    """Where ``_known_stages`` takes a stage without its LP, the seidel LPs give the same set."""
    planner, traj, _ = arm6_flat
    path = traj.path
    grid = make_gridpoints(path, 140)
    algo = LeanTOPPRA(planner.constraints, path, grid)
    K = algo.compute_controllable_sets(0.0, 0.0)
    assert np.isfinite(K).all()
    sw = algo.solver_wrapper
    sw.setup_solver()
    g_max = np.array([1e-9, -1.0])  # the highest x (toppra's objective for the controllable set's top)
    for i in range(len(grid) - 1):
        lo, hi = K[i + 1]
        x_hi = sw.solve_stagewise_optim(i, None, g_max, np.nan, np.nan, lo, hi)[1]
        assert x_hi == pytest.approx(K[i, 1], rel=1e-6, abs=1e-9)
        x_lo = sw.solve_stagewise_optim(i, None, -g_max, np.nan, np.nan, lo, hi)[1]
        assert max(x_lo, 0.0) == pytest.approx(K[i, 0], abs=1e-6 * (1.0 + K[i, 1]))
    sw.close_solver()


def _speed_rows_numpy(c: _IntervalSpeedConstraint, path, gridpoints: np.ndarray):
    n, f = len(gridpoints), len(c.FRACTIONS)
    sigma = np.append(np.diff(gridpoints), 0.0)[:, None] * c.FRACTIONS[None, :]
    inner = c.FRACTIONS < 1.0
    s_inner = (gridpoints[:-1, None] + sigma[:-1, inner]).ravel()
    factors2 = c.speed_factors(path, np.concatenate((gridpoints, s_inner))) ** 2
    with np.errstate(divide="ignore"):
        x_max = np.minimum(np.min(c.limit**2 / factors2, axis=1), 1e8)
    bound = np.empty((n, f))
    bound[:-1, inner] = x_max[n:].reshape(n - 1, int(inner.sum()))
    bound[:-1, ~inner] = x_max[1:n, None]
    bound[-1] = x_max[n - 1]
    return 2.0 * sigma, -bound, np.column_stack((np.zeros(n), x_max[:n]))


@pytest.mark.parametrize("intervals", [3, 60, 140])
def test_interval_speed_rows_are_the_numpy_rule(arm6_flat, intervals: int) -> None:
    planner, traj, _ = arm6_flat
    grid = make_gridpoints(traj.path, intervals)
    speed = [c for c in planner.constraints if isinstance(c, _IntervalSpeedConstraint)]
    assert len(speed) == 2  # arm6: the joint velocities and the TCP speed
    for c in speed:
        a, b, C, _, _, ubound, xbound = c.compute_constraint_params(traj.path, grid)
        for got, want in zip((a, C, xbound), _speed_rows_numpy(c, traj.path, grid), strict=True):
            np.testing.assert_array_equal(got, want)
        assert b.shape == a.shape and ubound is None


def test_interval_speed_rows_where_nothing_moves() -> None:
    """A sample where the bounded quantity does not move (factor 0) allows any speed: the cap."""
    cell = load_cell_config()
    lim = cell.joint_limits()
    a, b = lim.lower + 0.4 * (lim.upper - lim.lower), lim.lower + 0.6 * (lim.upper - lim.lower)
    b[1:] = a[1:]  # joint 0 alone moves: the other joints' velocity factors are 0 everywhere
    out = planner_for_cell(cell).plan(PlanInput(np.array([a, b])))
    assert out.ok, out.message
    grid = make_gridpoints(out.trajectory.path, 20)
    c = next(c for c in planner_for_cell(cell).constraints if isinstance(c, _IntervalSpeedConstraint))
    rows = c.compute_constraint_params(out.trajectory.path, grid)
    want = _speed_rows_numpy(c, out.trajectory.path, grid)
    for got, ref in zip((rows[0], rows[2], rows[6]), want, strict=True):
        np.testing.assert_array_equal(got, ref)


def _bits(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float).view(np.int64)


@pytest.mark.parametrize("n", [2, 3, 4, 5, 8, 12])
def test_not_a_knot_is_scipys_spline_bit_for_bit(n: int) -> None:
    from scipy.interpolate import CubicSpline

    from pvtflow.planner.path import not_a_knot

    rng = np.random.default_rng(n)
    for _ in range(200):
        w = rng.uniform(-3.0, 3.0, (n, 6))
        s = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))))
        spline = CubicSpline(s, w, bc_type="not-a-knot")
        c, end = not_a_knot(s, w)
        assert np.array_equal(_bits(c), _bits(spline.c))
        assert np.array_equal(_bits(end), _bits(spline(s[-1], 1)))


def test_u_range_is_the_numpy_statements_bit_for_bit() -> None:
    from pvtflow.planner.topp.rows import StageRows

    cell = load_cell_config()
    planner = planner_for_cell(cell)
    rng = np.random.default_rng(11)
    lim = cell.joint_limits()
    wp = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))
    path = planner.plan(PlanInput(wp)).trajectory.path
    grid = make_gridpoints(path, 140)
    rows = StageRows.stack([c.compute_constraint_params(path, grid) for c in planner.constraints], len(grid))
    xs = [rows.x_hi, np.zeros(len(grid)), rng.uniform(-1.0, 50.0, len(grid))]
    nan_x = rng.uniform(0.0, 5.0, len(grid))
    nan_x[::7] = np.nan
    xs.append(nan_x)
    for x in xs:
        A = rows.A
        r = rows.B * x[:, None] + rows.C
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            bound = -r / A
        hi = np.minimum(rows.u_hi, np.min(np.where(A > 0.0, bound, np.inf), axis=1, initial=np.inf))
        lo = np.maximum(rows.u_lo, np.max(np.where(A < 0.0, bound, -np.inf), axis=1, initial=-np.inf))
        lo[np.any((A == 0.0) & (r > 0.0), axis=1) | (x < rows.x_lo) | (x > rows.x_hi)] = np.inf
        for got, want in zip(rows.u_range_at(x), (lo, hi), strict=True):
            # the same numbers, NaN where numpy's are (a NaN's sign bit is not a number)
            num = ~np.isnan(want)
            assert np.array_equal(np.isnan(got), ~num)
            assert np.array_equal(_bits(got[num]), _bits(want[num]))
    assert np.isfinite(rows.u_range_at(rows.x_hi)[1]).all()


def test_gridpoints_are_the_unions_of_their_candidates() -> None:
    from pvtflow.planner.path import JointPath
    from pvtflow.planner.timing import END_REFINEMENT

    lim = load_cell_config().joint_limits()
    rng = np.random.default_rng(2)
    for k in range(100):
        # 90 % of the range: some paths are clamped and have kinks
        wp = lim.lower + (lim.upper - lim.lower) * (0.05 + 0.9 * rng.random((8, lim.dof)))
        path = JointPath(wp, lim)
        n = 140
        length = path.length
        steps = length / n * END_REFINEMENT
        ends = np.concatenate((steps, length - steps))
        kinks = (path.kinks[:, None] + np.concatenate((steps, -steps))[None, :]).ravel()
        kinks = kinks[(kinks > 0.0) & (kinks < length)]
        grid = np.union1d(np.union1d(np.linspace(0.0, length, n + 1), path.waypoint_s), np.union1d(ends, kinks))
        sliver = np.diff(grid) <= 1e-3 * (length / n) * END_REFINEMENT[-1]
        waypoint = np.isin(grid, path.waypoint_s)
        drop = np.zeros(len(grid), dtype=bool)
        drop[1:] = sliver & ~waypoint[1:]
        drop[:-1] |= sliver & waypoint[1:] & ~waypoint[:-1]
        grid = grid[~drop]
        grid[-1] = length
        assert np.array_equal(_bits(make_gridpoints(path, n)), _bits(grid)), k
