"""Fixed-period profiles: one record per period, its integers chosen against the drive's own
reconstruction (linear, or Parker's cubic submodes)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import LIMIT_RTOL
from pvtflow.planner.knots import fixed_period_kernels as kernels
from pvtflow.planner.knots.check import check_records, needed_scale
from pvtflow.planner.knots.quantize import round_positions, round_velocities
from pvtflow.planner.knots.samples import Samples, axis_constants
from pvtflow.planner.knots.types import AxisKnots, DriveAxis, KnotError, KnotOptions
from pvtflow.planner.slowdown import slowdown

_FP_REACH = 3  # counts (and records) a cubic's setpoint may move off the plan around a segment over a limit


def reconstruction_kind(axis: DriveAxis) -> int:
    """Which reconstruction the axis's drive makes of its setpoints, as the kernels take it
    (``DriveProfile.reconstruction``, ``Interpolation.code``)."""
    return axis.profile.reconstruction(axis.period_ms, axis.interpolation_submode).code


def record_times(axis: DriveAxis, smp: Samples) -> NDArray[np.int64]:
    """The plan's ms of each record of a fixed-period axis: one per period, the last at the goal."""
    period = int(axis.period_ms or 1)
    return np.minimum(np.arange(math.ceil(smp.n_ms / period) + 1) * period, smp.n_ms)


def _lattice(axis: DriveAxis, counts: float, what: str, obj: str) -> float:
    """A limit of ``counts`` (per period, or per period squared) over the largest whole number of
    counts within it; KnotError where there is none (no motion at all stays inside)."""
    whole = math.floor(counts * (1.0 + LIMIT_RTOL))
    if not whole:
        raise KnotError(
            f"{axis.joint}: the drive's reconstruction still exceeds its limits whatever the slow-down: at a "
            f"{axis.period_ms} ms period a setpoint one count off moves its {what} by more than {obj} allows "
            f"({counts:.3g} counts)"
        )
    return counts / whole


def drive_slowdown(axis: DriveAxis, i: int, smp: Samples) -> tuple[float, float]:
    """What a fixed-period axis's drive alone calls for on this plan, before any integer is chosen:
    (the least slow-down, the slow-down of the plan's exact samples).

    Whole counts put a linear reconstruction's velocities on multiples of 1/T qc/ms and its
    accelerations (and cubic_p's) on multiples of 1/T^2 qc/ms^2: the largest of them within
    0x607F / 0x60C5 can lie well below (at 1 ms on a 4096-count encoder, 2 qc/ms^2 is the most
    below a 0x60C5 of 40,000 rpm/s = 2.73 qc/ms^2). A plan that keeps its acceleration for more
    than a period or two cannot be followed faster than that: the least slow-down is the plan's own
    (its samples joined linearly) on that lattice. On top, a cubic through the plan's exact samples
    overshoots where the plan's acceleration jumps between two records (up to 1.5 times with the
    plan's velocities, 2 times with central ones): the second figure is the drive's reconstruction
    of the exact samples on the lattice, which the integer search usually beats.
    """
    kind = reconstruction_kind(axis)
    period = float(axis.period_ms or 1)
    f, amax, vmax, *_ = (float(x[0]) for x in axis_constants((axis,)))
    lattice_v = lattice_a = 1.0
    if kind == kernels.CUBIC_P:  # a linear step is judged net of the rounding (LINEAR_QUANTIZATION_QC)
        lattice_a = _lattice(axis, amax * period * period, "acceleration", "0x60C5")
    if kind == kernels.LINEAR:
        lattice_v = _lattice(axis, vmax * period, "velocity", "0x607F")
    t_ms = record_times(axis, smp)
    p = smp.position[i, t_ms]
    v = smp.velocity[i, t_ms] / f
    args = (smp.position[i], int(period), f, *(float(x[0]) for x in axis_constants((axis,))[6:8]), -math.inf, math.inf)
    out = []
    for k in (kernels.LINEAR, kind):
        rv, ra = kernels.fixed_period_ratios(k, p, v, *args)
        out.append(max(slowdown(float(rv.max()) * lattice_v, float(ra.max()) * lattice_a), 1.0))
    return out[0], max(out)


def fixed_period_axis(axis: DriveAxis, i: int, smp: Samples, opts: KnotOptions) -> tuple[AxisKnots, float]:
    """One record per period: the plan's samples rounded, then re-chosen among the integers around
    them where the drive's reconstruction of the rounding exceeds a limit
    (``fixed_period_kernels.track_fixed_period``: exact, over the whole motion)."""
    period = int(axis.period_ms or 1)
    t_ms = record_times(axis, smp)
    P = round_positions(smp.position[i, t_ms], axis)
    if axis.profile.carries_velocity(axis.interpolation_submode):
        V = round_velocities(smp.velocity[i, t_ms], axis)
    else:
        V = np.zeros(len(P), dtype=np.int64)
    V[0] = V[-1] = 0
    f, _, _, v_units, pos_lo, pos_hi, rv_per, ra_per = (float(x[0]) for x in axis_constants((axis,)))
    kind = reconstruction_kind(axis)
    reach = _FP_REACH if kind == kernels.CUBIC_P else 1
    P, V, _ = kernels.track_fixed_period(
        kind, P, V, smp.position[i], period, f, rv_per, ra_per, pos_lo, pos_hi, v_units, reach
    )
    records = np.column_stack((np.append(P, P[-1]), np.append(V, 0), np.full(len(P) + 1, period))).astype(np.int64)
    chk, _ = check_records(axis, records, smp.position[i])
    ra = float(chk.acceleration_ratio.max())
    rv = float(chk.velocity_ratio.max())
    return AxisKnots(axis.joint, records, chk.deviation, rv, ra), needed_scale(rv, ra)
