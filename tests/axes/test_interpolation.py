"""The drive-side reconstructions against cases computed by hand from the seeds."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.interpolation import (
    Interpolation,
    PiecewiseCubic,
    cubic_p,
    cubic_pv,
    epos2_pvt,
    hermite_coefficients,
    linear,
)
from pvtflow.axes.drive.scaling import AxisScaling


def _segment(c: tuple[np.ndarray, ...], T: float) -> PiecewiseCubic:
    return PiecewiseCubic(np.array([0.0]), np.array([float(T)]), *(np.atleast_1d(x) for x in c))


def test_hermite_meets_both_end_points_with_both_velocities() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        p0, p1 = rng.integers(-(10**6), 10**6, 2)
        v0, v1 = rng.normal(0, 50, 2)
        T = float(rng.integers(1, 256))
        seg = _segment(hermite_coefficients(p0, v0, p1, v1, T), T)
        assert float(seg.position(0.0)) == pytest.approx(p0, abs=1e-6)
        assert float(seg.position(T)) == pytest.approx(p1, abs=1e-6)
        assert float(seg.velocity(0.0)) == pytest.approx(v0, abs=1e-9)
        assert float(seg.velocity(T)) == pytest.approx(v1, abs=1e-9)


def test_constant_velocity_is_a_straight_line() -> None:
    # P0 = 100 qc, V = 3 qc/ms over 20 ms: P1 = 160; the cubic must be 100 + 3 t (c2 = c3 = 0)
    c0, c1, c2, c3 = hermite_coefficients(100.0, 3.0, 160.0, 3.0, 20.0)
    assert (c0, c1) == (100.0, 3.0)
    assert c2 == pytest.approx(0.0) and c3 == pytest.approx(0.0)
    seg = _segment((c0, c1, c2, c3), 20.0)
    t = np.linspace(0, 20, 41)
    assert np.allclose(seg.position(t), 100.0 + 3.0 * t)
    assert np.allclose(seg.acceleration(t), 0.0)


def test_app_note_printed_coefficients_do_not_reproduce_the_start_point() -> None:
    """The seed's b, a (t0 = segment end, t - t0 <= 0) fail for a constant velocity: why pvtflow
    derives its own Hermite cubic (DESIGN.md section 4)."""
    P0, P1, V, T = 100.0, 160.0, 3.0, 20.0
    d, c = P1, V
    b = (3 * (P1 - P0) + T * (V + 2 * V)) / T**2
    a = (2 * (P1 - P0) + T * (V + V)) / T**3
    x = -T  # the segment start
    note_start = a * x**3 + b * x**2 + c * x + d
    assert abs(note_start - P0) > 1.0  # the printed formula misses P0
    seg = _segment(hermite_coefficients(P0, V, P1, V, T), T)
    assert float(seg.position(0.0)) == pytest.approx(P0)


def test_rest_to_rest_segment_by_hand() -> None:
    # 0 -> 100 qc in 10 ms from rest to rest: c2 = 3 * 100 / 10^2 = 3, c3 = -2 * 100 / 10^3 = -0.2
    c = hermite_coefficients(0.0, 0.0, 100.0, 0.0, 10.0)
    assert c[2] == pytest.approx(3.0) and c[3] == pytest.approx(-0.2)
    seg = _segment(c, 10.0)
    assert float(seg.position(5.0)) == pytest.approx(50.0)
    # acceleration 2 c2 = 6 at the start, 2 c2 + 6 c3 T = -6 at the end: extremal at the ends
    assert seg.max_abs_acceleration()[0] == pytest.approx(6.0)
    # velocity peaks at the vertex tau = -c2 / (3 c3) = 5: 2*3*5 + 3*(-0.2)*25 = 15 qc/ms
    assert seg.max_abs_velocity()[0] == pytest.approx(15.0)
    lo, hi = seg.position_range()
    assert (lo[0], hi[0]) == (pytest.approx(0.0), pytest.approx(100.0))


def test_exact_extrema_bound_dense_sampling() -> None:
    rng = np.random.default_rng(11)
    n = 500
    T = rng.uniform(1, 255, n)
    p0, v0, p1, v1 = rng.normal(0, 1e3, n), rng.normal(0, 20, n), rng.normal(0, 1e3, n), rng.normal(0, 20, n)
    c = hermite_coefficients(p0, v0, p1, v1, T)
    pc = PiecewiseCubic(np.zeros(n), T, *c)
    tau = np.linspace(0.0, 1.0, 4001)[:, None] * T[None, :]
    p = c[0] + tau * (c[1] + tau * (c[2] + tau * c[3]))
    v = c[1] + tau * (2 * c[2] + 3 * c[3] * tau)
    a = 2 * c[2] + 6 * c[3] * tau
    vmax, amax = pc.max_abs_velocity(), pc.max_abs_acceleration()
    lo, hi = pc.position_range()
    assert np.all(np.abs(v).max(axis=0) <= vmax + 1e-9)
    assert np.allclose(np.abs(v).max(axis=0), vmax, rtol=1e-4, atol=1e-6)
    assert np.allclose(np.abs(a).max(axis=0), amax)
    assert np.all(p.max(axis=0) <= hi + 1e-6) and np.all(p.min(axis=0) >= lo - 1e-6)
    assert np.allclose(p.max(axis=0), hi, atol=1e-3) and np.allclose(p.min(axis=0), lo, atol=1e-3)


def test_position_range_of_a_parabola_with_float_noise_in_c3() -> None:
    """A constant-acceleration segment turning around inside: c3 is 0 up to float noise. The
    cancellation-prone root formula lost the extremum (a bug fixed here)."""
    seg = PiecewiseCubic(
        np.array([0.0]), np.array([10.0]), np.array([0.0]), np.array([5.0]), np.array([-0.5]), np.array([1e-18])
    )
    _, hi = seg.position_range()
    assert hi[0] == pytest.approx(12.5)


def test_epos2_records_to_segments() -> None:
    # 2000 qc/rev, 1 rpm units: 1 unit = 2000 / 60000 qc/ms
    f = AxisScaling(2000, 10.0).qc_per_ms_per_velocity_unit
    assert f == pytest.approx(1.0 / 30.0)
    records = [[1000, 0, 5], [1300, 600, 20], [1500, 0, 20], [1500, 0, 0], [9999, 99, 7]]
    pc = epos2_pvt(records, f)
    # dwell of 5 ms, then two segments; the time-0 record ends it (what follows is never run)
    assert list(pc.start) == [0.0, 5.0, 25.0]
    assert list(pc.duration) == [5.0, 20.0, 20.0]
    assert pc.end_time == 45.0
    assert pc.position(0.0) == pytest.approx(1000.0) and pc.position(5.0) == pytest.approx(1000.0)
    assert pc.position(25.0) == pytest.approx(1300.0)
    assert pc.velocity(25.0) == pytest.approx(600 * f)  # 20 qc/ms
    assert pc.position(45.0) == pytest.approx(1500.0) and pc.position(100.0) == pytest.approx(1500.0)
    assert pc.velocity(100.0) == 0.0


def test_linear_reaches_record_k_after_k_plus_one_periods() -> None:
    pc = linear([[0, 0, 2], [10, 0, 2], [30, 0, 2], [30, 0, 2]], 2.0)
    assert pc.interpolation is Interpolation.LINEAR
    assert pc.position(2.0) == pytest.approx(0.0)
    assert pc.position(4.0) == pytest.approx(10.0)
    assert pc.position(5.0) == pytest.approx(20.0)
    assert pc.position(6.0) == pytest.approx(30.0)
    # velocity steps 0 -> 5 -> 10 -> 0 qc/ms, each spread over its 2 ms period,
    # less the rounding of whole counts (2 qc per period): (5 - 1) / 2, (5 - 1) / 2, (10 - 1) / 2
    assert list(pc.max_abs_acceleration()) == pytest.approx([0.0, 2.0, 2.0, 4.5])


def test_cubic_pv_uses_the_record_velocities() -> None:
    f = 0.5
    pc = cubic_pv([[0, 0, 4], [40, 20, 4], [80, 0, 4]], 4.0, f)  # 20 units = 10 qc/ms
    assert pc.position(8.0) == pytest.approx(40.0)
    assert pc.velocity(8.0) == pytest.approx(10.0)
    assert pc.position(12.0) == pytest.approx(80.0)


def test_cubic_p_central_difference_and_extra_cycle() -> None:
    pc = cubic_p([[0, 0, 1], [10, 0, 1], [30, 0, 1], [30, 0, 1]], 1.0)
    assert pc.start[0] == 1.0  # one cycle later than the other submodes
    # velocity at record 1 (reached at 3 ms): (30 - 0) / 2 = 15 qc/ms; at the end at rest
    assert pc.velocity(3.0) == pytest.approx(15.0)
    assert pc.position(3.0) == pytest.approx(10.0)
    assert pc.velocity(pc.end_time) == pytest.approx(0.0)
