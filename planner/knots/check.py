"""Step 4: the exact reconstruction of quantized records against the limits and the plan.

A segment is judged by its exact extrema (0x607F, 0x60C5, 0x607D) and at every drive ms against
the plan; the EPOS2 axes all at once (``check_knots``), a fixed-period axis by its drive's own
reconstruction (``check_records``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import PiecewiseCubic, epos2_pvt, exceeds
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.planner.knots import check_kernels as kernels
from pvtflow.planner.knots import records_kernels
from pvtflow.planner.knots.flat import Flat, Moved
from pvtflow.planner.knots.types import AxisKnots, DriveAxis
from pvtflow.planner.knots.window_jerk import window_jerk
from pvtflow.planner.slowdown import KNOT_SLOWDOWN_MARGIN, slowdown


@dataclass(frozen=True)
class Check:
    seg_deviation: NDArray[np.float64]  # per reconstruction segment, worst |recon - plan| (qc)
    velocity_ratio: NDArray[np.float64]  # per segment, exact max |v| / 0x607F
    acceleration_ratio: NDArray[np.float64]
    position_out: NDArray[np.bool_]  # per segment: leaves 0x607D

    @property
    def deviation(self) -> float:
        return float(self.seg_deviation.max()) if len(self.seg_deviation) else 0.0


def check_records(
    axis: DriveAxis, records: NDArray[np.int64], plan_qc: NDArray[np.float64]
) -> tuple[Check, PiecewiseCubic]:
    """The exact reconstruction of ``records`` against the limits and the plan.

    The plan's sample j (ms) is compared with the reconstruction at the time the drive reaches it:
    j plus the time at which records[0] is reached (the dwell, or the fixed-period delay). Every
    record time is a whole ms, so the samples of each segment are a contiguous run found by
    arithmetic (no search), and the position range is solved exactly only on the segments whose
    cheap bound (the Hermite cubic stays within T (|V0| + |V1|) 4/27 of its end points) reaches
    0x607D.
    """
    recon = AxisProgram.of(axis, records).reconstruction()
    s = axis.scaling
    lim = axis.limits
    v = np.asarray(s.qc_per_ms_to_rpm(recon.max_abs_velocity())) / lim.max_profile_velocity_rpm
    a = np.asarray(s.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration())) / lim.max_acceleration_rpm_s
    T = recon.duration
    p_end = recon.c0 + T * (recon.c1 + T * (recon.c2 + T * recon.c3))
    reach = T * (np.abs(recon.c1) + np.abs(recon.c1 + T * (2.0 * recon.c2 + 3.0 * T * recon.c3))) * (4.0 / 27.0)
    near = (np.minimum(recon.c0, p_end) - reach < lim.min_position_qc) | (
        np.maximum(recon.c0, p_end) + reach > lim.max_position_qc
    )
    out = np.zeros(len(T), dtype=bool)
    if near.any():
        m = np.flatnonzero(near)
        part = PiecewiseCubic(
            recon.start[m], T[m], recon.c0[m], recon.c1[m], recon.c2[m], recon.c3[m], recon.interpolation
        )
        lo, hi = part.position_range()
        out[m] = (lo < lim.min_position_qc) | (hi > lim.max_position_qc)
    shift = float(recon.start[0] + recon.duration[0])
    n_t = len(plan_qc)
    # sample j sits at t = j + shift; segment k holds the samples from the first t >= start[k]
    first = np.clip(np.ceil(recon.start - shift - 1e-9), 0, n_t).astype(np.int64)
    k = np.repeat(np.arange(len(first)), np.diff(np.append(first, n_t)))
    first = np.minimum(first, n_t - 1)
    tau = np.clip(np.arange(n_t) + shift - recon.start[k], 0.0, T[k])
    pos = recon.c0[k] + tau * (recon.c1[k] + tau * (recon.c2[k] + tau * recon.c3[k]))
    err = np.abs(pos - plan_qc)
    seg_dev = np.maximum.reduceat(err, first)
    empty = np.append(first[1:] <= first[:-1], False) | (recon.start > n_t - 1 + shift)
    seg_dev[empty] = 0.0
    return Check(seg_dev, v, a, out), recon


def over_limit(chk: Check) -> NDArray[np.bool_]:
    return exceeds(chk.acceleration_ratio, 1.0) | exceeds(chk.velocity_ratio, 1.0)


def needed_scale(rv: float, ra: float) -> float:
    """The slow-down the worst ratios of an axis's records call for (planner.slowdown), 1 where none."""
    k = slowdown(rv, ra)
    if k <= 1.0:  # within the limits (most axes): no need to ask ``exceeds`` about the round-off
        return 1.0
    return k * (1.0 + KNOT_SLOWDOWN_MARGIN) if exceeds(k, 1.0) else 1.0


NO_INT = np.zeros(0, dtype=np.int64)


NO_FLOAT = np.zeros(0)


@dataclass(frozen=True)
class Checked:
    """A check with the quantized knots it judged: the next check reuses the deviation of every
    segment whose two knots (times, positions, velocities) did not change."""

    knots: NDArray[np.int64]
    P: NDArray[np.int64]
    V: NDArray[np.int64]
    chk: Check
    # the chains the round's repair searched (``quantize_kernels.repair_chains_memo``): first rows, rows
    memo: tuple[NDArray[np.int64], NDArray[np.int64]] = (np.zeros(1, dtype=np.int64), np.zeros((0, 5), dtype=np.int64))


def checked_subset(
    fl: Flat, keep: NDArray[np.int64], checked: Checked | None, moved: Moved | None = None
) -> Checked | None:
    """``checked`` for the axes ``keep`` alone (``moved``: ``fl.moved_knots`` of them, if already
    taken for ``checked``'s knots)."""
    if checked is None:
        return None
    sel, knots = moved[1:] if moved is not None and moved[0] is checked.knots else fl.moved_knots(keep, checked.knots)
    seg = sel[:-1]
    c = checked.chk
    return Checked(
        knots,
        checked.P[sel],
        checked.V[sel],
        Check(c.seg_deviation[seg], c.velocity_ratio[seg], c.acceleration_ratio[seg], c.position_out[seg]),
        checked.memo,  # keyed by knot times, which the axes that stay keep
    )


def check_knots(
    fl: Flat, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], prev: Checked | None = None
) -> Checked:
    """``check_records`` of the quantized knots of all axes at once, per knot segment.

    The drive's segment between two records is THE Hermite cubic through their integer positions
    and velocities (``hermite``, as ``epos2_pvt`` builds it), judged by its exact extrema and at
    every ms against the plan (``check_kernels.check_segments``). Only the segments that differ
    from ``prev`` are judged (the same two records make the same cubic, with the same extrema and
    deviation).
    """
    if prev is None:
        old = (NO_INT, NO_INT, NO_INT, NO_FLOAT, NO_FLOAT, NO_FLOAT, np.zeros(0, dtype=bool))
    else:
        c = prev.chk
        old = (prev.knots, prev.P, prev.V, c.seg_deviation, c.velocity_ratio, c.acceleration_ratio, c.position_out)
    dev, rv, ra, out = kernels.check_segments(
        knots, P, V, fl.stride, fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.p, *old
    )
    return Checked(knots, P, V, Check(dev, rv, ra, out))


def record_knots(records: NDArray[np.int64]) -> NDArray[np.int64]:
    """The knots (ms from the first record) of an axis's records: ``axis_records`` backwards."""
    return np.concatenate(([0], np.cumsum(records[1:-1, 2]))).astype(np.int64)


def knot_records(
    fl: Flat, a: int, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], dwell_ms: int
) -> NDArray[np.int64]:
    """The records of axis ``a`` of ``fl``: the dwell, one per knot, the end record (P, 0, 0)."""
    return records_kernels.knot_records(knots, P, V, fl.stride, a, dwell_ms)


def axis_records(
    fl: Flat, a: int, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], chk: Check, dwell_ms: int
) -> tuple[AxisKnots, float]:
    """The records of axis ``a`` of ``fl``, what their reconstruction does, the slow-down it needs.

    With a jerk limit, the slow-down also brings the drive's window jerk (``window_jerk``, of its
    own reconstruction) within what ``fl.window_jerk`` allows: the motion's part of it falls with
    the cube of the slow-down.
    """
    records, dev, rv, ra = records_kernels.axis_records(
        knots, P, V, fl.stride, a, dwell_ms, chk.seg_deviation, chk.velocity_ratio, chk.acceleration_ratio
    )
    return _axis_knots(fl, a, records, dev, rv, ra)


def axes_records(
    fl: Flat,
    axes: list[int],
    knots: NDArray[np.int64],
    P: NDArray[np.int64],
    V: NDArray[np.int64],
    chk: Check,
    dwell_ms: int,
) -> dict[int, tuple[AxisKnots, float]]:
    """``axis_records`` of each of ``axes`` (one compiled call for all of them), by axis."""
    rows, first, worst = records_kernels.axes_records(
        knots, P, V, fl.stride, np.asarray(axes, dtype=np.int64), dwell_ms, chk.seg_deviation, chk.velocity_ratio,
        chk.acceleration_ratio,
    )  # fmt: skip
    return {a: _axis_knots(fl, a, rows[first[i] : first[i + 1]], *worst[i].tolist()) for i, a in enumerate(axes)}


def _axis_knots(
    fl: Flat, a: int, records: NDArray[np.int64], dev: float, rv: float, ra: float
) -> tuple[AxisKnots, float]:
    rj, scale = 0.0, needed_scale(rv, ra)
    if math.isfinite(fl.window_jerk[a]):
        rj = window_jerk(epos2_pvt(records, float(fl.f[a]))) / float(fl.window_jerk[a])
        scale = max(scale, jerk_scale(rj))
    return AxisKnots(fl.axes[a].joint, records, dev, rv, ra, rj), scale


def jerk_scale(rj: float) -> float:
    """The slow-down for a window jerk ``rj`` times what is allowed: the motion's part of the
    jerk falls with the cube of it (the records' own part does not: a first guess)."""
    return math.cbrt(rj) * (1.0 + KNOT_SLOWDOWN_MARGIN) if exceeds(rj, 1.0) else 1.0
