"""Knot placement of all EPOS2 axes at once: the shortcuts it takes change no answer.

The axes are placed as one flat problem (their samples end to end) and the work that repeats is
reused (deviations of unchanged segments, right-hand sides of unchanged least-squares segments);
the integer repair searches combinations by a shortest path. Each shortcut must give what the full
computation gives.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pvtflow.axes.drive.interpolation import PiecewiseCubic, epos2_pvt, hermite_coefficients
from pvtflow.planner.build import build_program
from pvtflow.planner.knots import KnotOptions, quantize_kernels, refine_kernels
from pvtflow.planner.knots.check import check_knots
from pvtflow.planner.knots.epos2 import Start, place_epos2
from pvtflow.planner.knots.flat import Flat, within_record_time
from pvtflow.planner.knots.quantize import round_knots
from pvtflow.planner.knots.refine import lsq_fit, switch_knots
from pvtflow.planner.knots.samples import sample_trajectory
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import planner_for_cell
from pvtflow.service.config import load_cell_config


@pytest.fixture(scope="module")
def arm6_plan():
    cell = load_cell_config()
    axes = list(cell.ordered_axes())
    lim = cell.joint_limits()
    rng = np.random.default_rng(11)
    wp = lim.lower + (lim.upper - lim.lower) * (0.15 + 0.7 * rng.random((4, lim.dof)))
    out = planner_for_cell(cell).plan(PlanInput(wp))
    assert out.ok, out.message
    smp = sample_trajectory(out.trajectory, axes, 1.0)
    return cell, axes, out.trajectory, smp


def test_axes_placed_together_as_each_alone(arm6_plan) -> None:
    """The flat problem is block-independent: an axis gets the same records with the others as alone."""
    _, axes, _, smp = arm6_plan
    cols = list(range(len(axes)))
    together = place_epos2(Flat.of(axes, cols, smp), smp, cols, KnotOptions(), Start.LEAST_SQUARES)
    for i in (0, 2, 5):
        alone = place_epos2(Flat.of([axes[i]], [i], smp), smp, [i], KnotOptions(), Start.LEAST_SQUARES)[0]
        np.testing.assert_array_equal(alone[0].records, together[i][0].records)
        assert alone[0].deviation_qc == pytest.approx(together[i][0].deviation_qc, abs=1e-12)


def test_flat_check_is_the_drive_reconstruction(arm6_plan) -> None:
    """Per axis, the flat check's deviation and limit ratios are those of ``epos2_pvt`` of the records."""
    _, axes, _, smp = arm6_plan
    cols = list(range(len(axes)))
    placed = place_epos2(Flat.of(axes, cols, smp), smp, cols, KnotOptions(), Start.LEAST_SQUARES)
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
    fl = Flat.of(axes, list(range(len(axes))), smp)
    rng = np.random.default_rng(3)
    knots = fl.flat_knots([np.arange(0, smp.n_ms, 40) for _ in axes])
    fit = lsq_fit(fl, knots)
    P, V = round_knots(fl, knots, fit.P, fit.V)
    prev = check_knots(fl, knots, P, V)
    # nudge a few knots, split a few segments: only those segments are evaluated again
    inner = np.flatnonzero(~fl.is_end(knots))
    moved = rng.choice(inner, 12, replace=False)
    P2, V2 = P.copy(), V.copy()
    P2[moved] += 1
    V2[moved[:6]] -= 2
    knots2 = np.union1d(knots, knots[inner[:5]] + 7)
    fit2 = lsq_fit(fl, knots2)
    P3, V3 = round_knots(fl, knots2, fit2.P, fit2.V)
    for k, p, v in ((knots, P2, V2), (knots2, P3, V3)):
        fast = check_knots(fl, k, p, v, prev).chk
        full = check_knots(fl, k, p, v).chk
        np.testing.assert_array_equal(fast.seg_deviation, full.seg_deviation)
        np.testing.assert_array_equal(fast.acceleration_ratio, full.acceleration_ratio)
        np.testing.assert_array_equal(fast.position_out, full.position_out)


def test_incremental_fit_gives_the_same_verdicts(arm6_plan) -> None:
    """Reused right-hand sides give the same solution; skipped segments keep their verdict."""
    _, axes, _, smp = arm6_plan
    fl = Flat.of(axes, list(range(len(axes))), smp)
    target = 0.6
    knots = fl.flat_knots([np.arange(0, smp.n_ms, 60) for _ in axes])
    prev = lsq_fit(fl, knots, None, target)
    bad = np.flatnonzero(prev.worst > target)
    knots2 = np.union1d(knots, (knots[bad] + knots[bad + 1]) // 2)
    fast = lsq_fit(fl, knots2, prev, target)
    full = lsq_fit(fl, knots2, None, target)
    np.testing.assert_allclose(fast.P, full.P, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.V, full.V, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fast.worst > target, full.worst > target)


def _repair_setup(arm6_plan, spacing: int):
    _, axes, _, smp = arm6_plan
    fl = Flat.of(axes, list(range(len(axes))), smp)
    knots = fl.flat_knots([np.arange(0, smp.n_ms, spacing) for _ in axes])
    fit = lsq_fit(fl, knots)
    P, V = round_knots(fl, knots, fit.P, fit.V)
    real = np.flatnonzero(fl.axis_of(knots[:-1]) == fl.axis_of(knots[1:]))
    return fl, knots, P, V, real


def _candidates(fl, knots, P, V, k, shift):
    """Knot k's candidate records (time, count, velocity units): its own nudged, and with ``shift``
    the plan's rounded sample a ms earlier or later, nudged."""
    a = fl.axis_of(knots[k])
    out = []
    for ds in range(-shift, shift + 1):
        t = int(knots[k]) + ds
        if ds == 0:
            p0, v0 = int(P[k]), int(V[k])
        else:
            p0 = int(np.rint(fl.p[t]))
            v0 = int(np.clip(np.rint(fl.v[t] / fl.f[a]), -fl.v_units[a], fl.v_units[a]))
        out += [(t, p0 + dp, v0 + dv) for dp in (-1, 0, 1) for dv in (-2, -1, 0, 1, 2)]
    return out


def _combination_scores(fl, knots, P, V, i0, i1, tol, shift):
    """Every combination of the candidate records of knots i0 .. i1, judged with the array forms of
    the reconstruction: (records, worst limit ratio over the segments i0 - 1 .. i1, their summed
    excess over 1, their summed deviation at the ends and probes); the ratio is inf where a
    segment strays more than tol."""
    a = fl.axis_of(knots[i0])
    f = fl.f[a]
    left, right = (
        (int(knots[i0 - 1]), int(P[i0 - 1]), int(V[i0 - 1])),
        (int(knots[i1 + 1]), int(P[i1 + 1]), int(V[i1 + 1])),
    )
    out = []
    for combo in itertools.product(*(_candidates(fl, knots, P, V, k, shift) for k in range(i0, i1 + 1))):
        ratio, excess, total = 0.0, 0.0, 0.0
        chain = (left, *combo, right)
        for (t0, p0, v0), (t1, p1, v1) in itertools.pairwise(chain):
            T = float(t1 - t0)
            if not 1 <= T <= 255:
                ratio = np.inf
                continue
            c = hermite_coefficients(p0, v0 * f, p1, v1 * f, T)
            tau = np.floor(np.array([0.25, 0.5, 0.75]) * T)
            h = c[0] + tau * (c[1] + tau * (c[2] + tau * c[3]))
            dev = max(abs(p0 - fl.p[t0]), abs(p1 - fl.p[t1]), float(np.abs(h - fl.p[t0 + tau.astype(int)]).max()))
            cub = PiecewiseCubic(np.zeros(1), np.array([T]), *(np.atleast_1d(x) for x in c))
            lo, hi = cub.position_range()
            seg = max(
                float(cub.max_abs_velocity()[0]) * fl.rv_per[a], float(cub.max_abs_acceleration()[0]) * fl.ra_per[a]
            )
            if dev > tol or lo[0] < fl.pos_lo[a] or hi[0] > fl.pos_hi[a]:
                seg = np.inf
            ratio = max(ratio, seg)
            excess += max(seg - 1.0, 0.0)
            total += dev
        out.append((combo, ratio, excess, total))
    return out


@pytest.mark.parametrize(("free", "shift"), [(1, 0), (2, 0), (1, 1), (2, 1)])
def test_chain_repair_finds_the_best_combination(arm6_plan, free: int, shift: int) -> None:
    """The compiled chain repair finds, over every combination of its records' candidates (nudged,
    and with ``shift`` also moved a ms), the least worst limit ratio, and among the combinations
    under max(that, 1) the least summed excess, then the closest to the plan (brute force with the
    array forms of the reconstruction); it moves nothing when no combination beats the rounding."""
    fl, knots, P, V, real = _repair_setup(arm6_plan, 25)
    chk = check_knots(fl, knots, P, V).chk
    rng = np.random.default_rng(8 + free)
    # chains around the segments the rounding left over a limit, and some at random
    over = np.flatnonzero((chk.acceleration_ratio > 1.0) | (chk.velocity_ratio > 1.0))
    starts = np.concatenate((over, rng.choice(real, 20, replace=False)))
    improved, judged = 0, 0
    for i0 in starts:
        i1 = i0 + free - 1
        if fl.is_end(knots[i0 - 2 : i1 + 3]).any() or len(np.unique(fl.axis_of(knots[i0 - 2 : i1 + 3]))) != 1:
            continue  # a chain has a fixed knot on each side on its own axis and moves no axis end
        if judged == (4 if free + shift == 3 else 40):
            break  # 2025 combinations each: a few chains say it
        judged += 1
        scores = _combination_scores(fl, knots, P, V, i0, i1, 1.0, shift)
        now = tuple((int(knots[k]), int(P[k]), int(V[k])) for k in range(i0, i1 + 1))
        still = next(r for combo, r, _, _ in scores if combo == now)
        best = min(r for _, r, _, _ in scores)
        a = fl.axis_of(knots[i0])
        t, p, v = knots.copy(), P.copy(), V.copy()
        moved = quantize_kernels._repair_chain(
            t,
            p,
            v,
            i0,
            i1,
            shift,
            fl.stride,
            fl.f[a],
            fl.rv_per[a],
            fl.ra_per[a],
            fl.pos_lo[a],
            fl.pos_hi[a],
            fl.v_units[a],
            fl.p,
            fl.v,
            1.0,
        )
        if not best < still:
            assert not moved
            np.testing.assert_array_equal(p, P)
            np.testing.assert_array_equal(t, knots)
            continue
        cap = max(best, 1.0)
        least = min(quantize_kernels.EXCESS_WEIGHT * e + d for _, r, e, d in scores if r <= cap)
        got = tuple((int(t[k]), int(p[k]), int(v[k])) for k in range(i0, i1 + 1))
        _, got_ratio, got_excess, got_dev = next(s for s in scores if s[0] == got)
        assert got_ratio <= cap * (1 + 1e-12)
        assert quantize_kernels.EXCESS_WEIGHT * got_excess + got_dev == pytest.approx(least, rel=1e-9, abs=1e-9)
        improved += 1
    assert improved >= (2 if free + shift == 3 else 4)  # the case moves records (the test would be empty otherwise)


def test_repair_chains_moves_only_the_neighbourhood(arm6_plan) -> None:
    """Only records within reach of a segment over a limit move, never an axis's end, the worst
    limit ratio does not grow and fewer segments are over a limit."""
    fl, knots, P, V, _ = _repair_setup(arm6_plan, 10)  # a fit within the tolerance, as placed
    chk = check_knots(fl, knots, P, V).chk
    assert chk.seg_deviation.max() <= 1.0
    over = np.flatnonzero((chk.acceleration_ratio > 1.0) | (chk.velocity_ratio > 1.0))
    assert len(over) > 3
    reach = 2
    p, v = P.copy(), V.copy()
    assert quantize_kernels.repair_chains(
        knots,
        p,
        v,
        over,
        reach,
        0,
        fl.stride,
        fl.f,
        fl.rv_per,
        fl.ra_per,
        fl.pos_lo,
        fl.pos_hi,
        fl.v_units,
        fl.p,
        fl.v,
        1.0,
    )
    near = np.zeros(len(knots), dtype=bool)
    for s in over:
        for k in range(s - reach + 1, s + reach + 1):
            near[k] |= fl.axis_of(knots[k]) == fl.axis_of(knots[s])
    near &= ~fl.is_end(knots)
    moved = (p != P) | (v != V)
    assert moved.any() and not (moved & ~near).any()
    after = check_knots(fl, knots, p, v).chk
    worst_before = np.maximum(chk.acceleration_ratio, chk.velocity_ratio)
    worst_after = np.maximum(after.acceleration_ratio, after.velocity_ratio)
    assert worst_after.max() <= worst_before.max()
    assert (worst_after > 1.0).sum() < (worst_before > 1.0).sum()


def test_switch_knots_largest_first_apart_and_inside() -> None:
    switch_ms = np.array([3.0, 20.0, 24.0, 40.0, 47.0, 95.0, 98.0])
    jump = np.array([9.0, 1.0, 5.0, 2.0, 3.0, 4.0, 8.0])
    # 3 and 98 are too close to the ends; 24 beats 20, 47 beats 40 (within 8 ms of each other)
    np.testing.assert_array_equal(switch_knots(switch_ms, jump, 0.5, 100, 8), [24, 47])
    np.testing.assert_array_equal(switch_knots(switch_ms, jump, 4.5, 100, 8), [24])
    assert len(switch_knots(switch_ms, jump, 10.0, 100, 8)) == 0


def test_switch_knots_of_all_axes_laid_out_in_one_call(arm6_plan) -> None:
    """``switch_flat_knots`` gives what each axis's ``switch_knots`` laid out by ``Flat.flat_knots``
    gives (ends, long gaps split), on a plan's switches and on gaps longer than a record."""
    _, axes, _, smp = arm6_plan
    fl = Flat.of(axes, list(range(len(axes))), smp)
    for n_ms, fraction, t_max in ((smp.n_ms, 0.01, 255), (smp.n_ms, 0.2, 40), (smp.n_ms, 1e9, 255)):
        thresholds = np.abs(fl.amax) * fraction
        cols = np.arange(len(axes))
        got = refine_kernels.switch_flat_knots(smp.switch_ms, np.ascontiguousarray(smp.jump), cols, thresholds,
                                               n_ms, 8, t_max)  # fmt: skip
        per_axis = [switch_knots(smp.switch_ms, smp.jump[:, c], thresholds[c], n_ms, 8) for c in cols]
        if t_max == 255:
            np.testing.assert_array_equal(got, fl.flat_knots(per_axis))
        # every axis from its start to its goal, no gap over t_max, the switch knots among them
        stride = n_ms + 1
        for a in cols:
            mine = got[(got >= a * stride) & (got < (a + 1) * stride)] - a * stride
            assert mine[0] == 0 and mine[-1] == n_ms and np.diff(mine).max() <= t_max
            assert set(per_axis[a].tolist()) <= set(mine.tolist())


def test_build_reports_its_timing(arm6_plan) -> None:
    cell, axes, traj, _ = arm6_plan
    built = build_program(traj, axes, cell.name)
    assert set(built.timing) == {"knots", "validation"}
    assert all(t >= 0.0 for t in built.timing.values())


def test_block_tridiagonal_solve_equals_a_dense_solve() -> None:
    """The least-squares solve (2x2 block elimination, compiled) against numpy's dense solve of
    the same symmetric block tridiagonal matrix."""
    rng = np.random.default_rng(4)
    n = 40
    D = np.column_stack((8.0 + rng.random(n), rng.normal(size=n), 8.0 + rng.random(n)))
    E = rng.normal(size=(n, 4))
    E[-1] = 0.0  # the last knot couples to nothing
    E[17] = 0.0  # the step between two axes couples nothing
    A = np.zeros((2 * n, 2 * n))
    for k in range(n):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[D[k, 0], D[k, 1]], [D[k, 1], D[k, 2]]]
        if k < n - 1:
            A[2 * k : 2 * k + 2, 2 * k + 2 : 2 * k + 4] = E[k].reshape(2, 2)
            A[2 * k + 2 : 2 * k + 4, 2 * k : 2 * k + 2] = E[k].reshape(2, 2).T
    assert np.all(np.linalg.eigvalsh(A) > 0.0)  # diagonally dominant: positive definite
    b = rng.normal(size=(n, 2))
    want = np.linalg.solve(A, b.ravel()).reshape(n, 2)
    got = b.copy()
    assert refine_kernels._solve_block_tridiagonal(D, E, got)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    D[5, 0] = -1.0  # not positive definite: refused, not a wrong answer
    assert not refine_kernels._solve_block_tridiagonal(D, E, b.copy())


def test_long_gaps_are_split_evenly_within_a_record_time() -> None:
    """Every gap longer than 255 ms is cut into the fewest pieces of at most 255 ms, as even as whole
    ms make them; the knots there were are kept."""
    rng = np.random.default_rng(12)
    for _ in range(300):
        knots = np.unique(np.concatenate(([0], rng.integers(0, 20000, rng.integers(1, 40)), [20003])))
        out = within_record_time(knots)
        assert set(knots) <= set(out) and np.all(np.diff(out) <= 255) and np.all(np.diff(out) >= 1)
        for k0, k1 in itertools.pairwise(knots):
            inside = np.diff(out[(out >= k0) & (out <= k1)])
            assert len(inside) == -(-(k1 - k0) // 255)  # the fewest pieces
            assert inside.max() - inside.min() <= 1  # even, to the ms
