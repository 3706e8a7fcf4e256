"""Test programs: smooth rest-to-rest motions sampled at fixed spacing, in drive units.

Until the planner's knot placement is used here, the tests build programs from an analytic
quintic (s = 10 u^3 - 15 u^4 + 6 u^5), rounded to drive units through AxisScaling, and check
with ``AxisProgram.reconstruction()`` that the drive's own interpolation stays in the limits.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.program import AxisProgram, PvtProgram

PEAK_VELOCITY = 1.875  # max of s'(u)
PEAK_ACCELERATION = 5.7735  # max of |s''(u)|


def quintic(p0: float, p1: float, duration_ms: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (qc) and velocity (qc/ms) of the rest-to-rest quintic at times t (ms)."""
    u = np.clip(t / duration_ms, 0.0, 1.0)
    s = u**3 * (10 - 15 * u + 6 * u**2)
    ds = 30 * u**2 * (1 - u) ** 2 / duration_ms
    return p0 + (p1 - p0) * s, (p1 - p0) * ds


def safe_distance(axis: AxisConfig, duration_ms: float, fraction: float = 0.5) -> float:
    """The largest move (qc) whose quintic stays at ``fraction`` of the drive's velocity/acceleration limits."""
    sc, lim = axis.scaling, axis.limits
    vmax = float(sc.rpm_to_qc_per_ms(lim.max_profile_velocity_rpm))
    amax = float(sc.rpm_s_to_qc_per_ms2(lim.max_acceleration_rpm_s))
    half_range = (lim.max_position_qc - lim.min_position_qc) / 2
    return min(
        fraction * min(vmax * duration_ms / PEAK_VELOCITY, amax * duration_ms**2 / PEAK_ACCELERATION), 0.4 * half_range
    )


def axis_program(
    axis: AxisConfig,
    start_qc: int,
    distance_qc: float,
    duration_ms: int,
    spacing_ms: int | None = None,
    *,
    end_record: bool = True,
) -> AxisProgram:
    sc = axis.scaling
    if axis.profile == "epos2_pvt":
        spacing = spacing_ms or 10
        n = int(np.ceil(duration_ms / spacing))
        t = np.arange(n + 1) * spacing
        p, v = quintic(start_qc, start_qc + distance_qc, n * spacing, t)
        records = np.zeros((n + 1, 3), dtype=np.int64)
        records[:, 0] = np.round(p)
        records[:, 1] = np.round(v / sc.qc_per_ms_per_velocity_unit)
        records[:, 2] = spacing
        records[0] = [start_qc, 0, spacing]
        records[-1, 1] = 0
        if end_record:
            records = np.vstack([records, [[records[-1, 0], 0, 0]]])
    else:
        period = axis.period_ms or 1
        n = int(np.ceil(duration_ms / period))
        t = np.arange(n + 1) * period
        p, v = quintic(start_qc, start_qc + distance_qc, n * period, t)
        records = np.zeros((n + 1, 3), dtype=np.int64)
        records[:, 0] = np.round(p)
        records[:, 1] = np.round(v / sc.qc_per_ms_per_velocity_unit)
        records[:, 2] = period
    return AxisProgram.of(axis, records)


def program(
    axes: Sequence[AxisConfig],
    duration_ms: int = 300,
    *,
    starts: Sequence[int] | None = None,
    fraction: float = 0.5,
    spacing_ms: int | None = None,
    cell: str = "test",
    sign: int = 1,
) -> PvtProgram:
    out = []
    for i, a in enumerate(axes):
        start = 0 if starts is None else int(starts[i])
        distance = sign * (1 if i % 2 == 0 else -1) * safe_distance(a, duration_ms, fraction)
        out.append(axis_program(a, start, distance, duration_ms, spacing_ms))
    return PvtProgram(cell, tuple(out))


def check_limits(prog: PvtProgram) -> None:
    """The drive's reconstruction of every axis stays inside 0x607F / 0x60C5 / 0x607D.

    A linear interpolator's "acceleration" is a velocity step per period; at 1 ms the rounding of
    positions to whole qc alone makes steps of 1 qc/ms, so 0x60C5 is checked on cubic drives only
    (the fixed-period drives fault on 0x607F and 0x607D, not on acceleration).
    """
    for a in prog.axes:
        rec = a.reconstruction()
        vmax = float(a.scaling.rpm_to_qc_per_ms(a.limits.max_profile_velocity_rpm))
        amax = float(a.scaling.rpm_s_to_qc_per_ms2(a.limits.max_acceleration_rpm_s))
        assert rec.max_abs_velocity().max() <= vmax, a.joint
        if rec.interpolation.cubic:
            assert rec.max_abs_acceleration().max() <= amax, a.joint
        lo, hi = rec.position_range()
        assert lo.min() >= a.limits.min_position_qc and hi.max() <= a.limits.max_position_qc, a.joint


def standstill_syncs(demands: np.ndarray) -> int:
    """SYNC periods inside the motion (after its first move, before its last) in which no axis moved."""
    moved = np.any(np.abs(np.diff(demands, axis=0)) > 1e-9, axis=1)
    inside = np.flatnonzero(moved)
    return int(np.count_nonzero(~moved[inside[0] : inside[-1] + 1]))
