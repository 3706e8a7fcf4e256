"""Knot placement of all EPOS2 axes at once: the shortcuts it takes change no answer.

The axes are placed as one flat problem (their samples end to end) and the work that repeats is
reused (deviations of unchanged segments, right-hand sides of unchanged least-squares segments,
answers of repairs already solved). Each shortcut must give what the full computation gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner import knot_kernels
from planner.build import build_program
from planner.interpolation import PiecewiseCubic, epos2_pvt, hermite_coefficients
from planner.knots import (
    DriveAxis,
    KnotOptions,
    _check_knots,
    _Flat,
    _lsq_fit,
    _place_epos2,
    _round_knots,
    _sample,
    _switch_knots,
)
from planner.plan import plan
from service.config import load_cell_config
from service.plan_cmd import plan_input_for_cell


@pytest.fixture(scope="module")
def arm6_plan():
    cell = load_cell_config()
    axes = [DriveAxis.from_config(a) for a in cell.ordered_axes()]
    lim = cell.joint_limits()
    rng = np.random.default_rng(11)
    wp = lim.lower + (lim.upper - lim.lower) * (0.15 + 0.7 * rng.random((4, lim.dof)))
    out = plan(plan_input_for_cell(cell, wp))
    assert out.ok, out.message
    smp = _sample(out.trajectory, axes, 1.0)
    return cell, axes, out.trajectory, smp


def test_axes_placed_together_as_each_alone(arm6_plan) -> None:
    """The flat problem is block-independent: an axis gets the same records with the others as alone."""
    _, axes, _, smp = arm6_plan
    cols = list(range(len(axes)))
    together = _place_epos2(_Flat.of(axes, cols, smp), smp, cols, KnotOptions(), "lsq")
    for i in (0, 2, 5):
        alone = _place_epos2(_Flat.of([axes[i]], [i], smp), smp, [i], KnotOptions(), "lsq")[0]
        np.testing.assert_array_equal(alone[0].records, together[i][0].records)
        assert alone[0].deviation_qc == pytest.approx(together[i][0].deviation_qc, abs=1e-12)


def test_flat_check_is_the_drive_reconstruction(arm6_plan) -> None:
    """Per axis, the flat check's deviation and limit ratios are those of ``epos2_pvt`` of the records."""
    _, axes, _, smp = arm6_plan
    cols = list(range(len(axes)))
    placed = _place_epos2(_Flat.of(axes, cols, smp), smp, cols, KnotOptions(), "lsq")
    t = np.arange(smp.n_ms + 1.0)
    for i, (ax, (res, _)) in enumerate(zip(axes, placed, strict=True)):
        recon = epos2_pvt(res.records, ax.scaling.qc_per_ms_per_velocity_unit)
        dev = np.abs(recon.position(t + res.records[0, 2]) - smp.position[i]).max()
        assert res.deviation_qc == pytest.approx(dev, abs=1e-9)
        ra = ax.scaling.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration()).max() / ax.limits.max_acceleration_rpm_s
        rv = ax.scaling.qc_per_ms_to_rpm(recon.max_abs_velocity()).max() / ax.limits.max_profile_velocity_rpm
        assert res.acceleration_ratio == pytest.approx(ra, rel=1e-12)
        assert res.velocity_ratio == pytest.approx(rv, rel=1e-12)


def test_incremental_check_equals_the_full_one(arm6_plan) -> None:
    _, axes, _, smp = arm6_plan
    fl = _Flat.of(axes, list(range(len(axes))), smp)
    rng = np.random.default_rng(3)
    knots = fl.flat_knots([np.arange(0, smp.n_ms, 40) for _ in axes])
    fit = _lsq_fit(fl, knots)
    P, V = _round_knots(fl, knots, fit.P, fit.V)
    prev = _check_knots(fl, knots, P, V)
    # nudge a few knots, split a few segments: only those segments are evaluated again
    inner = np.flatnonzero(~fl.is_end(knots))
    moved = rng.choice(inner, 12, replace=False)
    P2, V2 = P.copy(), V.copy()
    P2[moved] += 1
    V2[moved[:6]] -= 2
    knots2 = np.union1d(knots, knots[inner[:5]] + 7)
    fit2 = _lsq_fit(fl, knots2)
    P3, V3 = _round_knots(fl, knots2, fit2.P, fit2.V)
    for k, p, v in ((knots, P2, V2), (knots2, P3, V3)):
        fast = _check_knots(fl, k, p, v, prev).chk
        full = _check_knots(fl, k, p, v).chk
        np.testing.assert_array_equal(fast.seg_deviation, full.seg_deviation)
        np.testing.assert_array_equal(fast.acceleration_ratio, full.acceleration_ratio)
        np.testing.assert_array_equal(fast.position_out, full.position_out)


def test_incremental_fit_gives_the_same_verdicts(arm6_plan) -> None:
    """Reused right-hand sides give the same solution; skipped segments keep their verdict."""
    _, axes, _, smp = arm6_plan
    fl = _Flat.of(axes, list(range(len(axes))), smp)
    target = 0.6
    knots = fl.flat_knots([np.arange(0, smp.n_ms, 60) for _ in axes])
    prev = _lsq_fit(fl, knots, None, target)
    bad = np.flatnonzero(prev.worst > target)
    knots2 = np.union1d(knots, (knots[bad] + knots[bad + 1]) // 2)
    fast = _lsq_fit(fl, knots2, prev, target)
    full = _lsq_fit(fl, knots2, None, target)
    np.testing.assert_allclose(fast.P, full.P, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.V, full.V, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.worst > target, full.worst > target)


def _repair_setup(arm6_plan, spacing: int):
    _, axes, _, smp = arm6_plan
    fl = _Flat.of(axes, list(range(len(axes))), smp)
    knots = fl.flat_knots([np.arange(0, smp.n_ms, spacing) for _ in axes])
    fit = _lsq_fit(fl, knots)
    P, V = _round_knots(fl, knots, fit.P, fit.V)
    real = np.flatnonzero(fl.axis_of(knots[:-1]) == fl.axis_of(knots[1:]))
    return fl, knots, P, V, real


def _repair_at_once(fl, knots, P, V, segs) -> bool:
    """Every segment of ``segs`` repaired from the same records, the changes applied together."""
    base_P, base_V = P.copy(), V.copy()
    moved = False
    for s in segs:
        a = fl.axis_of(knots[s])
        p, v = base_P.copy(), base_V.copy()
        moved |= knot_kernels._repair_segment(knots, p, v, s, fl.stride, fl.f[a], fl.rv_per[a], fl.ra_per[a], fl.p, 1.0)
        P[s : s + 2], V[s : s + 2] = p[s : s + 2], v[s : s + 2]
    return moved


def test_repair_in_fewest_waves_as_in_four(arm6_plan) -> None:
    """Repairs batched by neighbourhood give what the four waves by segment index mod 4 give, each
    wave's segments repaired at once."""
    fl, knots, P, V, real = _repair_setup(arm6_plan, 30)
    rng = np.random.default_rng(5)
    for _ in range(3):  # runs of neighbours, lone segments, every axis
        segs = np.unique(np.concatenate((rng.choice(real, 25, replace=False), real[10:16], real[-4:])))
        fast_P, fast_V = P.copy(), V.copy()
        fast_moved = knot_kernels.repair_segments(
            knots, fast_P, fast_V, segs, fl.stride, fl.f, fl.rv_per, fl.ra_per, fl.p, 1.0
        )
        ref_P, ref_V = P.copy(), V.copy()
        local = segs - np.searchsorted(knots, fl.axis_of(knots[segs]) * fl.stride)
        ref_moved = False
        for w in range(4):
            ref_moved |= _repair_at_once(fl, knots, ref_P, ref_V, segs[local % 4 == w])
        np.testing.assert_array_equal(fast_P, ref_P)
        np.testing.assert_array_equal(fast_V, ref_V)
        assert fast_moved == ref_moved


def _best_nudge(fl, knots, P, V, s, tol):
    """The repair rule, restated with the array forms of the reconstruction: every nudge of the two
    end records, judged on the three segments they touch."""
    a = fl.axis_of(knots[s])
    f = fl.f[a]
    same = [0 <= k < len(knots) and fl.axis_of(knots[k]) == a for k in (s - 1, s, s + 1, s + 2)]
    free = [not fl.is_end(knots[k : k + 1])[0] for k in (s, s + 1)]
    best, best_score = None, np.inf
    for dp0 in (-1, 0, 1):
        for dv0 in (-2, -1, 0, 1, 2):
            for dp1 in (-1, 0, 1):
                for dv1 in (-2, -1, 0, 1, 2):
                    if (not free[0] and (dp0 or dv0)) or (not free[1] and (dp1 or dv1)):
                        continue
                    p, v = P.astype(float), V.astype(float)
                    p[s] += dp0
                    v[s] += dv0
                    p[s + 1] += dp1
                    v[s + 1] += dv1
                    dev = max(
                        abs(p[k] - fl.p[knots[k]]) for k, ok in zip((s - 1, s, s + 1, s + 2), same, strict=True) if ok
                    )
                    ratio = 0.0
                    for k in (s - 1, s, s + 1):
                        if not (same[k - s + 1] and same[k - s + 2]):
                            continue
                        T = float(knots[k + 1] - knots[k])
                        c = hermite_coefficients(p[k], v[k] * f, p[k + 1], v[k + 1] * f, T)
                        tau = np.floor(np.array([0.25, 0.5, 0.75]) * T)
                        h = c[0] + tau * (c[1] + tau * (c[2] + tau * c[3]))
                        dev = max(dev, float(np.abs(h - fl.p[knots[k] + tau.astype(int)]).max()))
                        cub = PiecewiseCubic(np.zeros(1), np.array([T]), *(np.atleast_1d(x) for x in c))
                        ratio = max(
                            ratio,
                            float(cub.max_abs_velocity()[0]) * fl.rv_per[a],
                            float(cub.max_abs_acceleration()[0]) * fl.ra_per[a],
                        )
                    score = ratio + 1e-6 * dev
                    if dev <= tol and score < best_score:
                        best, best_score = (dp0, dv0, dp1, dv1), score
    return best


def test_repair_picks_the_best_nudge(arm6_plan) -> None:
    """The compiled repair chooses what the rule says, by the array forms of the reconstruction."""
    fl, knots, P, V, real = _repair_setup(arm6_plan, 25)
    rng = np.random.default_rng(8)
    checked = 0
    for s in rng.choice(real, 40, replace=False):
        a = fl.axis_of(knots[s])
        want = _best_nudge(fl, knots, P, V, s, 1.0)
        p, v = P.copy(), V.copy()
        moved = knot_kernels._repair_segment(knots, p, v, s, fl.stride, fl.f[a], fl.rv_per[a], fl.ra_per[a], fl.p, 1.0)
        got = (p[s] - P[s], v[s] - V[s], p[s + 1] - P[s + 1], v[s + 1] - V[s + 1])
        if want is None or want == (0, 0, 0, 0):
            assert not moved and got == (0, 0, 0, 0)
        else:
            assert moved and got == want
            checked += 1
    assert checked > 5  # the case moves records (the test would be empty otherwise)


def test_switch_knots_largest_first_apart_and_inside() -> None:
    switch_ms = np.array([3.0, 20.0, 24.0, 40.0, 47.0, 95.0, 98.0])
    jump = np.array([9.0, 1.0, 5.0, 2.0, 3.0, 4.0, 8.0])
    # 3 and 98 are too close to the ends; 24 beats 20, 47 beats 40 (within 8 ms of each other)
    np.testing.assert_array_equal(_switch_knots(switch_ms, jump, 0.5, 100, 8), [24, 47])
    np.testing.assert_array_equal(_switch_knots(switch_ms, jump, 4.5, 100, 8), [24])
    assert len(_switch_knots(switch_ms, jump, 10.0, 100, 8)) == 0


def test_build_reports_its_timing(arm6_plan) -> None:
    cell, axes, traj, _ = arm6_plan
    built = build_program(traj, axes, cell.name)
    assert set(built.timing) == {"knots", "validation"}
    assert all(t >= 0.0 for t in built.timing.values())


def test_banded_cholesky_solves_as_lapack() -> None:
    """The least-squares solve (LAPACK's unblocked banded Cholesky, compiled) against scipy's."""
    from scipy.linalg import solveh_banded

    rng = np.random.default_rng(4)
    n, kd = 60, 3
    ab = np.zeros((kd + 1, n))
    ab[:kd] = rng.normal(size=(kd, n))
    ab[kd] = 4.0 * kd + rng.random(n)  # diagonally dominant: positive definite
    for d in range(1, kd + 1):
        ab[kd - d, :d] = 0.0  # the band's unused corner
    rhs = rng.normal(size=n)
    want = solveh_banded(ab, rhs)
    got_ab, got = ab.copy(), rhs.copy()
    assert knot_kernels._cholesky_solve_banded(got_ab, got)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    ab[kd, 5] = -1.0  # not positive definite: refused, not a wrong answer
    assert not knot_kernels._cholesky_solve_banded(ab, rhs.copy())
