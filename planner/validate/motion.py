"""The rules on the motion the drive executes: 0x607D, 0x607F, 0x60C5 (errors) and 0x6081, 0x6083
(warnings) along ``AxisProgram.reconstruction()``, exactly (closed-form extrema per segment) and at
the drive's own samples, and the summary of each axis's worst values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import (
    LINEAR_QUANTIZATION_QC,
    Interpolation,
    PiecewiseCubic,
    exceeds,
    linear_span_excess,
)
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.planner.validate.report import AxisSummary, Finding, Rule, Severity
from pvtflow.planner.validate.screen import Worst


def _samples(
    axis: AxisProgram, recon: PiecewiseCubic, sample_period_ms: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The drive's sampling instants and |velocity| (rpm), |acceleration| (rpm/s) there."""
    s = axis.scaling
    t = recon.sample_times(sample_period_ms)
    sv = np.abs(np.asarray(s.qc_per_ms_to_rpm(recon.velocity(t))))
    sa = np.abs(np.asarray(s.qc_per_ms2_to_rpm_s(recon.acceleration(t))))
    return t, sv, sa


def _summary(
    axis: AxisProgram,
    duration_ms: float,
    vmax: float,
    amax: float,
    sv: NDArray[np.float64],
    sa: NDArray[np.float64],
    lowest: float,
    highest: float,
) -> AxisSummary:
    lim = axis.limits
    return AxisSummary(
        axis=axis.joint,
        profile=axis.profile,
        records=len(axis.records),
        duration_ms=duration_ms,
        max_velocity_rpm=vmax,
        max_acceleration_rpm_s=amax,
        velocity_ratio=vmax / lim.max_profile_velocity_rpm,
        acceleration_ratio=amax / lim.max_acceleration_rpm_s,
        sampled_velocity_ratio=float(sv.max()) / lim.max_profile_velocity_rpm if len(sv) else 0.0,
        sampled_acceleration_ratio=float(sa.max()) / lim.max_acceleration_rpm_s if len(sa) else 0.0,
        min_position_qc=lowest,
        max_position_qc=highest,
    )


class _MotionLimit(NamedTuple):
    """A limit on |velocity| or |acceleration| along the reconstruction, and how a breach is reported."""

    kind: str  # "velocity" or "acceleration"
    rule: Rule
    severity: Severity
    limit: float
    obj: str
    unit: str


def _motion_limits(axis: AxisProgram) -> list[_MotionLimit]:
    """0x607F and 0x60C5 (errors), and 0x6081 and 0x6083 where the axis has them (warnings)."""
    lim = axis.limits
    out = [
        _MotionLimit("velocity", Rule.VELOCITY_LIMIT, Severity.ERROR, lim.max_profile_velocity_rpm, "0x607F", "rpm"),
        _MotionLimit(
            "acceleration", Rule.ACCELERATION_LIMIT, Severity.ERROR, lim.max_acceleration_rpm_s, "0x60C5", "rpm/s"
        ),
    ]
    if lim.profile_velocity_rpm is not None:
        out.append(
            _MotionLimit("velocity", Rule.PROFILE_VELOCITY, Severity.WARNING, lim.profile_velocity_rpm, "0x6081", "rpm")
        )
    if lim.profile_acceleration_rpm_s is not None:
        out.append(
            _MotionLimit(
                "acceleration",
                Rule.PROFILE_ACCELERATION,
                Severity.WARNING,
                lim.profile_acceleration_rpm_s,
                "0x6083",
                "rpm/s",
            )
        )
    return out


def summaries_within_limits(
    axes: Sequence[AxisProgram], worsts: Sequence[Worst], sample_period_ms: float | None
) -> list[AxisSummary] | None:
    """The axes' summaries if each one's worst values are within every limit (then no segment has
    a motion finding), else None: every axis's values against its limits in one comparison.

    The unit conversions are monotonic, so the converted worst value is the worst converted value:
    these are the very numbers the segment-by-segment check reports.
    """
    values: list[float] = []
    limits: list[float] = []
    converted = []
    for axis, worst in zip(axes, worsts, strict=True):
        if not all(map(math.isfinite, worst)):
            return None  # a segment's NaN would hide behind the worst value: look at each one
        lim = axis.limits
        if worst.lowest < lim.min_position_qc or worst.highest > lim.max_position_qc:
            return None
        s = axis.scaling
        vmax = float(s.qc_per_ms_to_rpm(worst.speed))
        amax = float(s.qc_per_ms2_to_rpm_s(worst.acceleration))
        converted.append((vmax, amax))
        for m in _motion_limits(axis):
            values.append(vmax if m.kind == "velocity" else amax)
            limits.append(m.limit)
    if exceeds(np.array(values), np.array(limits)).any():
        return None
    if sample_period_ms:
        out = []
        for axis, worst, (vmax, amax) in zip(axes, worsts, converted, strict=True):
            _, sv, sa = _samples(axis, axis.reconstruction(), sample_period_ms)
            out.append(_summary(axis, worst.end_ms, vmax, amax, sv, sa, worst.lowest, worst.highest))
        return out
    return [
        _summary(axis, worst.end_ms, vmax, amax, _NO_SAMPLES, _NO_SAMPLES, worst.lowest, worst.highest)
        for axis, worst, (vmax, amax) in zip(axes, worsts, converted, strict=True)
    ]


_NO_SAMPLES = np.zeros(0)  # no look at the drive's samples (read only: ``_summary`` takes its length)


def _linear_spans(axis: AxisProgram, recon: PiecewiseCubic) -> list[Finding]:
    """A linear reconstruction's velocity change over any span of periods, against 0x60C5 with the
    rounding of whole counts allowed once (``linear_span_excess``): the steps alone, each net of that
    rounding, would let a run of one-count steps accelerate past 0x60C5 for ever."""
    s = axis.scaling
    T = float(recon.duration[0])
    a_max = float(s.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s))
    first, last, excess = linear_span_excess(recon.c1, T, a_max)
    allowed = a_max * (last - first + 1) * T
    if not exceeds(allowed + excess, allowed):
        return []
    span_ms = (last - first + 1) * T
    rounding = LINEAR_QUANTIZATION_QC / T
    value = float(s.qc_per_ms2_to_rpm_s((allowed + excess) / span_ms))
    limit = axis.limits.max_acceleration_rpm_s
    return [
        Finding(
            Severity.ERROR,
            Rule.ACCELERATION_LIMIT,
            axis.joint,
            int(last),
            f"the velocity changes by {excess + allowed + rounding:.4g} qc/ms over the {last - first + 1} periods "
            f"{recon.start[first]:.0f}..{recon.start[last] + T:.0f} ms ending here: {value:.6g} rpm/s on average "
            f"less the rounding of whole counts ({rounding:.3g} qc/ms), above 0x60C5 {limit:.6g} rpm/s",
            value - limit,
            value,
            limit,
            "rpm/s",
            float(recon.start[last]),
        )
    ]


def check_motion(
    axis: AxisProgram, sample_period_ms: float | None, worst: Worst | None = None
) -> tuple[list[Finding], AxisSummary]:
    """0x607D, 0x607F, 0x60C5 (errors) and 0x6081, 0x6083 (warnings) along the reconstruction.

    With the ``worst`` values of an EPOS2 axis, only an axis that breaks a limit is gone through
    segment by segment.
    """
    if worst is not None:
        summary = summaries_within_limits((axis,), (worst,), sample_period_ms)
        if summary is not None:
            return [], summary[0]
    s = axis.scaling
    lim = axis.limits
    name = axis.joint
    out: list[Finding] = []
    recon = axis.reconstruction()

    # exact per-segment extrema, converted to the drive's units through the axis scaling
    seg_v = np.asarray(s.qc_per_ms_to_rpm(recon.max_abs_velocity()))
    seg_a = np.asarray(s.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration()))
    lo, hi = recon.position_range()
    # and what the drive computes at its own 1 kHz samples
    if sample_period_ms:
        t, sv, sa = _samples(axis, recon, sample_period_ms)
        seg_of_sample = np.clip(np.searchsorted(recon.start, t, side="right") - 1, 0, len(recon.start) - 1)
    else:  # the exact checks alone (they bound the samples)
        sv = sa = np.zeros(0)
        seg_of_sample = np.zeros(0, dtype=np.intp)

    # the record that ends each reconstruction segment (cubic_p starts one period late: same index)
    records_of_segment = np.arange(len(recon.start))

    def over_limit(
        kind: str,
        rule: Rule,
        severity: Severity,
        seg: NDArray[np.float64],
        sampled: NDArray[np.float64],
        limit: float,
        obj: str,
        unit: str,
    ) -> None:
        bad = np.flatnonzero(exceeds(seg, limit))
        for k in bad:
            in_seg = seg_of_sample == k
            worst_sample = float(sampled[in_seg].max()) if in_seg.any() else 0.0
            seen = "also" if exceeds(worst_sample, limit) else "not"
            samples = (
                f"; {seen} at the drive's {sample_period_ms:g} ms samples (worst {worst_sample:.6g})"
                if sample_period_ms
                else ""
            )
            value = float(seg[k])
            out.append(
                Finding(
                    severity,
                    rule,
                    name,
                    int(records_of_segment[k]),
                    f"|{kind}| reaches {value:.6g} {unit} on the segment ending here ({recon.start[k]:.0f}.."
                    f"{recon.start[k] + recon.duration[k]:.0f} ms): above {obj} {limit:.6g} {unit} by "
                    f"{value - limit:.4g} {unit} ({100 * (value / limit - 1):.2f}%){samples}",
                    value - limit,
                    value,
                    limit,
                    unit,
                    float(recon.start[k]),
                )
            )

    per_kind = {"velocity": (seg_v, sv), "acceleration": (seg_a, sa)}
    for m in _motion_limits(axis):
        over_limit(m.kind, m.rule, m.severity, *per_kind[m.kind], m.limit, m.obj, m.unit)
    if recon.interpolation is Interpolation.LINEAR and len(recon.start):
        out.extend(_linear_spans(axis, recon))

    for k in np.flatnonzero((lo < lim.min_position_qc) | (hi > lim.max_position_qc)):
        if hi[k] > lim.max_position_qc:
            value, limit, side = float(hi[k]), float(lim.max_position_qc), "above 0x607D:02"
        else:
            value, limit, side = float(lo[k]), float(lim.min_position_qc), "below 0x607D:01"
        out.append(
            Finding(
                Severity.ERROR,
                Rule.POSITION_LIMIT,
                name,
                int(records_of_segment[k]),
                f"position reaches {value:.1f} qc on the segment ending here ({recon.start[k]:.0f}.."
                f"{recon.start[k] + recon.duration[k]:.0f} ms): {side} {limit:.0f} qc "
                f"by {abs(value - limit):.1f} qc",
                abs(value - limit),
                value,
                limit,
                "qc",
                float(recon.start[k]),
            )
        )

    vmax = float(seg_v.max()) if len(seg_v) else 0.0
    amax = float(seg_a.max()) if len(seg_a) else 0.0
    return out, _summary(axis, recon.end_time, vmax, amax, sv, sa, float(lo.min()), float(hi.max()))
