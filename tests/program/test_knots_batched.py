"""Knot placement of all EPOS2 axes at once: the shortcuts it takes change no answer.

The axes are placed as one flat problem (their samples end to end) and the work that repeats is
reused (deviations of unchanged segments, right-hand sides of unchanged least-squares segments,
answers of repairs already solved). Each shortcut must give what the full computation gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.build import build_program
from planner.interpolation import epos2_pvt
from planner.knots import (
    DriveAxis,
    KnotOptions,
    _check_knots,
    _Flat,
    _lsq_fit,
    _place_epos2,
    _repair,
    _repair_wave,
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
        dev = np.abs(recon.position(t + res.records[0, 2]) - smp.position[:, i]).max()
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


def test_repair_in_fewest_waves_as_in_four(arm6_plan) -> None:
    """Repairs batched by neighbourhood give what the four waves by segment index mod 4 give."""
    _, axes, _, smp = arm6_plan
    fl = _Flat.of(axes, list(range(len(axes))), smp)
    knots = fl.flat_knots([np.arange(0, smp.n_ms, 30) for _ in axes])
    fit = _lsq_fit(fl, knots)
    P, V = _round_knots(fl, knots, fit.P, fit.V)
    real = np.flatnonzero(fl.axis_of(knots[:-1]) == fl.axis_of(knots[1:]))
    rng = np.random.default_rng(5)
    for _ in range(3):  # runs of neighbours, lone segments, every axis
        segs = np.unique(np.concatenate((rng.choice(real, 25, replace=False), real[10:16], real[-4:])))
        fast_P, fast_V, fast_moved = _repair(fl, knots, P, V, segs, 1.0, {})
        ref_P, ref_V = P.copy(), V.copy()
        local = segs - np.searchsorted(knots, fl.axis_of(knots[segs]) * fl.stride)
        ref_moved = False
        for w in range(4):
            if (local % 4 == w).any():
                ref_moved |= _repair_wave(fl, knots, ref_P, ref_V, segs[local % 4 == w], 1.0, {})
        np.testing.assert_array_equal(fast_P, ref_P)
        np.testing.assert_array_equal(fast_V, ref_V)
        assert fast_moved == ref_moved


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
