"""Checks of a PVT program against the rules its drives enforce: the one validator.

The CLI, the service and the tests all call :func:`validate_program`. Every motion check runs on
what the drive itself will execute, ``AxisProgram.reconstruction()`` (axes.interpolation),
never on a formula of its own: exactly (closed-form extrema per segment) and at the drive's 1 kHz
samples. Errors are what makes a drive refuse or fault (0x607F, 0x60C5, 0x607D, record ranges,
the start and end rules); warnings are what only sets a warning bit (0x6081, 0x6083).

The planner validates every program it emits, so the common case, nothing to report, is fast: the
EPOS2 axes' worst values come from one compiled pass over all their segments (``epos2_segment``
and ``hermite``, as ``epos2_pvt`` builds them, and the same closed-form extrema: the very same
numbers), and only an axis with something to report is gone through segment by
segment on its ``reconstruction()``.

Each finding carries a stable rule code, so that tools can react to it without parsing text:

=======================  =========================================================================
``record-range``         position outside int32, velocity outside int24, time outside 0..255
``time-range``           a motion record's time outside 1..255 ms (0 ends interpolation early)
``start-record``         records[0] must be the start point at rest (velocity 0)
``end-record``           the program must end at rest (EPOS2: with a time-0 record)
``period``               a fixed-period profile's record times must all equal its period
``position-limit``       the reconstruction leaves 0x607D
``velocity-limit``       |velocity| of the reconstruction above 0x607F (the drive faults)
``acceleration-limit``   |acceleration| of the reconstruction above 0x60C5 (the drive faults)
``profile-velocity``     |velocity| above 0x6081 (warning bit only)
``profile-acceleration`` |acceleration| above 0x6083 (warning bit only)
=======================  =========================================================================
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from axes.interpolation import (
    DRIVE_SAMPLE_MS,
    LINEAR_QUANTIZATION_QC,
    Interpolation,
    PiecewiseCubic,
    cubic_peak_acceleration,
    cubic_peak_speed,
    cubic_position_range,
    epos2_end,
    epos2_segment,
    exceeds,
    hermite,
    linear_span_excess,
)
from axes.program import TIME_MAX_MS, AxisProgram, PvtProgram
from axes.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN


class Severity(StrEnum):
    """What a finding means for the drive: an error makes it refuse or fault, a warning only sets a bit."""

    ERROR = "error"
    WARNING = "warning"


class Rule(StrEnum):
    """The stable rule codes of the findings (the table in the module docstring)."""

    RECORD_RANGE = "record-range"
    TIME_RANGE = "time-range"
    START_RECORD = "start-record"
    END_RECORD = "end-record"
    PERIOD = "period"
    POSITION_LIMIT = "position-limit"
    VELOCITY_LIMIT = "velocity-limit"
    ACCELERATION_LIMIT = "acceleration-limit"
    PROFILE_VELOCITY = "profile-velocity"
    PROFILE_ACCELERATION = "profile-acceleration"


# At most this many findings of one rule per axis are listed in the text report.
_TEXT_FINDINGS_PER_RULE = 8


@dataclass(frozen=True)
class Finding:
    """One broken rule: on which axis, at which record, by how much.

    ``record`` is the index of the record concerned (for a motion check: the record that ends the
    segment where the worst value occurs), or None for a whole-axis finding. ``amount`` is by how
    much the value exceeds the limit, in ``unit``; ``value``/``limit`` are the numbers compared.
    """

    severity: Severity
    rule: Rule
    axis: str
    record: int | None
    message: str
    amount: float = 0.0
    value: float | None = None
    limit: float | None = None
    unit: str = ""
    time_ms: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "severity": self.severity,
            "rule": self.rule,
            "axis": self.axis,
            "record": self.record,
            "message": self.message,
            "amount": self.amount,
            "value": self.value,
            "limit": self.limit,
            "unit": self.unit,
            "time_ms": self.time_ms,
        }

    def format(self) -> str:
        where = f"record {self.record}" if self.record is not None else "axis"
        return f"{self.severity}: {self.axis} {where}: [{self.rule}] {self.message}"


@dataclass(frozen=True)
class AxisSummary:
    """Worst values of one axis's reconstruction, in drive units and as fractions of its limits."""

    axis: str
    profile: str
    records: int
    duration_ms: float
    max_velocity_rpm: float | None = None  # exact, over the whole reconstruction
    max_acceleration_rpm_s: float | None = None
    velocity_ratio: float | None = None  # max |v| / 0x607F
    acceleration_ratio: float | None = None  # max |a| / 0x60C5
    sampled_velocity_ratio: float | None = None  # the same at the drive's 1 kHz samples
    sampled_acceleration_ratio: float | None = None
    min_position_qc: float | None = None
    max_position_qc: float | None = None

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class ValidationReport:
    """Everything found in one program. ``ok`` means no errors (warnings allowed)."""

    cell: str
    errors: tuple[Finding, ...]
    warnings: tuple[Finding, ...]
    axes: tuple[AxisSummary, ...] = field(default_factory=tuple)
    source: str | None = None  # the file it came from, when there is one

    @property
    def ok(self) -> bool:
        return not self.errors

    @property
    def findings(self) -> tuple[Finding, ...]:
        return self.errors + self.warnings

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "ok": self.ok,
            "cell": self.cell,
            "errors": [f.to_json() for f in self.errors],
            "warnings": [f.to_json() for f in self.warnings],
            "axes": [a.to_json() for a in self.axes],
        }
        if self.source is not None:
            out["source"] = self.source
        return out

    def format_text(self) -> str:
        """A report for a person: verdict first, then every finding (grouped per axis and rule)."""
        name = self.source or f"program of cell {self.cell!r}"
        verdict = "VALID" if self.ok else "INVALID"
        lines = [f"{name}: {verdict} ({len(self.errors)} error(s), {len(self.warnings)} warning(s))"]
        for a in self.axes:
            parts = [f"{a.axis} [{a.profile}]: {a.records} records, {a.duration_ms:.0f} ms"]
            if a.velocity_ratio is not None and a.acceleration_ratio is not None:
                parts.append(f"max |v| {a.max_velocity_rpm:.1f} rpm ({100 * a.velocity_ratio:.1f}% of 0x607F)")
                parts.append(
                    f"max |a| {a.max_acceleration_rpm_s:.0f} rpm/s ({100 * a.acceleration_ratio:.1f}% of 0x60C5)"
                )
            lines.append("  " + ", ".join(parts))
        shown: Counter[tuple[str, str]] = Counter()
        hidden: Counter[tuple[str, str]] = Counter()
        for f in self.findings:
            key = (f.axis, f.rule)
            if shown[key] < _TEXT_FINDINGS_PER_RULE:
                shown[key] += 1
                lines.append("  " + f.format())
            else:
                hidden[key] += 1
        for (axis, rule), n in hidden.items():
            lines.append(f"  ... and {n} more [{rule}] finding(s) on {axis}")
        return "\n".join(lines)


# --- the checks ------------------------------------------------------------------------------------
def validate_program(
    program: PvtProgram,
    *,
    sample_period_ms: float | None = DRIVE_SAMPLE_MS,
    source: str | None = None,
) -> ValidationReport:
    """Check every axis of ``program`` against its drive's rules; never raises for a bad program.

    ``sample_period_ms=None`` skips the look at the drive's own samples: the exact checks alone
    decide (they bound the samples), which is what the planner's last check before output needs.
    All axes' records are looked at once (:func:`_screen`); an axis is gone through segment by
    segment only where that look finds something to report.
    """
    errors: list[Finding] = []
    warnings: list[Finding] = []
    summaries: list[AxisSummary] = []
    records = [np.asarray(axis.records, dtype=np.int64) for axis in program.axes]
    for axis, r, screen in zip(program.axes, records, _screen(program.axes, records), strict=True):
        found, summary = _validate_axis(axis, r, sample_period_ms, screen)
        for f in found:
            (errors if f.severity == Severity.ERROR else warnings).append(f)
        summaries.append(summary)
    return ValidationReport(program.cell, tuple(errors), tuple(warnings), tuple(summaries), source)


# The fields of a record and their ranges: (column, what, lowest, highest, unit, kind).
_RECORD_FIELDS = (
    (0, "position", INT32_MIN, INT32_MAX, "qc", "int32"),
    (1, "velocity", INT24_MIN, INT24_MAX, "velocity units", "int24"),
    (2, "time", 0, TIME_MAX_MS, "ms", "0..255 (uint8)"),
)
_FIELD_LO = np.array([lo for _, _, lo, _, _, _ in _RECORD_FIELDS], dtype=np.int64)
_FIELD_HI = np.array([hi for _, _, _, hi, _, _ in _RECORD_FIELDS], dtype=np.int64)


def _outside_ranges(r: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per record and field, whether the value is outside the field's range (the record-range rule)."""
    return (r < _FIELD_LO) | (r > _FIELD_HI)


def _outside_motion_time(t: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per record time, whether it is outside a motion record's 1..255 ms (the time-range rule)."""
    return (t < 1) | (t > TIME_MAX_MS)


class _Worst(NamedTuple):
    """The worst values of an axis's EPOS2 reconstruction over all its segments (exact: closed forms)."""

    speed: float  # max |v|, qc/ms
    acceleration: float  # max |a|, qc/ms^2
    lowest: float  # min position, qc
    highest: float  # max position, qc
    end_ms: float  # the reconstruction's end time


@dataclass(frozen=True)
class _Screen:
    """What the look at all axes' records at once found about one axis."""

    in_range: bool  # every field of every record is in range: no record-range finding
    bad_inner_times: list[int]  # records 1..N-2 whose time is outside 1..255 ms, in order
    worst: _Worst | None  # None: not EPOS2 PVT, or no reconstruction to check


def _has_motion(r: NDArray[np.int64], in_range: bool) -> bool:
    """(N >= 2, 3) records that have a reconstruction to check (the rest gets its structural findings
    only): a first segment, and no negative time (which records in range cannot have)."""
    return bool(r[0, 2] >= 1) and (in_range or not np.any(r[:, 2] < 0))


def _screen(axes: tuple[AxisProgram, ...], records: list[NDArray[np.int64]]) -> list[_Screen]:
    """Per axis, whether its records are all in range, which motion records have a time outside
    1..255 ms, and the worst values of its EPOS2 reconstruction: one check of each rule over all
    axes' records at once and one compiled pass over all EPOS2 axes' segments
    (:func:`_epos2_worst`), instead of a dozen numpy calls per axis."""
    shaped = [i for i, r in enumerate(records) if r.ndim == 2 and r.shape[1] == 3 and len(r) >= 2]
    screens = [_Screen(False, [], None)] * len(axes)  # the others fail the shape check before any use
    if not shaped:
        return screens
    rows = np.ascontiguousarray(np.concatenate([records[i] for i in shaped]))  # C order: one compiled signature
    first = np.cumsum([0] + [len(records[i]) for i in shaped])  # each shaped axis's first row (and the end)
    outside = _outside_ranges(rows)
    if outside.any():
        in_range = [not outside[first[j] : first[j + 1]].any() for j in range(len(shaped))]
    else:
        in_range = [True] * len(shaped)
    # the rows with a time outside 1..255 ms (usually just the end records, whose time is 0), and
    # where each axis's begin among them
    bad_time = np.flatnonzero(_outside_motion_time(rows[:, 2]))
    bad_time_cut = np.searchsorted(bad_time, first).tolist()
    bad_time_rows, bounds = bad_time.tolist(), first.tolist()
    epos2 = [j for j, i in enumerate(shaped) if axes[i].profile.buffered and _has_motion(records[i], in_range[j])]
    worst: dict[int, _Worst] = {}
    if epos2:
        factor = np.array([axes[shaped[j]].scaling.qc_per_ms_per_velocity_unit for j in epos2], dtype=np.float64)
        js = np.array(epos2, dtype=np.intp)
        found = _epos2_worst(rows, first[js], first[js + 1], factor)
        worst = {j: _Worst(*w) for j, w in zip(epos2, found.tolist(), strict=True)}
    for j, i in enumerate(shaped):
        begin, end = bounds[j], bounds[j + 1]
        inner = [g - begin for g in bad_time_rows[bad_time_cut[j] : bad_time_cut[j + 1]] if begin < g < end - 1]
        screens[i] = _Screen(in_range[j], inner, worst.get(j))
    return screens


@njit(cache=True)
def _epos2_worst(
    rows: NDArray[np.int64], begin: NDArray[np.int64], end: NDArray[np.int64], factor: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per axis (records rows[begin:end], velocity factor qc/ms per unit), the :class:`_Worst` of its
    EPOS2 reconstruction: the segments as ``epos2_pvt`` builds them (``epos2_segment`` up to
    ``epos2_end``, ``hermite``), judged by ``cubic_peak_speed``, ``cubic_peak_acceleration``,
    ``cubic_position_range``.
    An axis with a value that is not finite gets NaN (it is then gone through segment by segment).
    """
    out = np.empty((len(begin), 5))
    for a in range(len(begin)):
        f = factor[a]
        speed, accel, lowest, highest = -math.inf, -math.inf, math.inf, -math.inf
        end_ms = 0.0
        finite = True
        for k in range(begin[a], epos2_end(rows, begin[a], end[a])):
            p0, v0, p1, v1, T = epos2_segment(rows, begin[a], k, f)
            c0, c1, c2, c3 = hermite(p0, v0, p1, v1, T)
            s = cubic_peak_speed(c1, c2, c3, T)
            acc = cubic_peak_acceleration(c2, c3, T)
            lo, hi = cubic_position_range(c0, c1, c2, c3, T)
            finite = finite and math.isfinite(s) and math.isfinite(acc) and math.isfinite(lo) and math.isfinite(hi)
            speed, accel = max(speed, s), max(accel, acc)
            lowest, highest = min(lowest, lo), max(highest, hi)
            end_ms += T
        out[a, 0], out[a, 1], out[a, 2], out[a, 3], out[a, 4] = speed, accel, lowest, highest, end_ms
        if not finite:
            out[a, :] = math.nan
    return out


def _bare_summary(axis: AxisProgram, r: NDArray[np.int64]) -> AxisSummary:
    """The summary of an axis without a reconstruction to check."""
    shaped = r.ndim == 2 and r.shape[1] == 3 and len(r)
    return AxisSummary(axis.joint, axis.profile, len(r), float(r[:, 2].sum()) if shaped else 0.0)


def _validate_axis(
    axis: AxisProgram, r: NDArray[np.int64], sample_period_ms: float | None, screen: _Screen
) -> tuple[list[Finding], AxisSummary]:
    out: list[Finding] = []
    if r.ndim != 2 or r.shape[1] != 3 or len(r) < 2:
        bare = _bare_summary(axis, r)
        out.append(
            Finding(
                Severity.ERROR,
                Rule.RECORD_RANGE,
                axis.joint,
                None,
                f"needs at least 2 records [position_qc, velocity, time_ms], has {len(r)}"
                if r.ndim == 2 and r.shape[1] == 3
                else f"records are rows of [position_qc, velocity, time_ms]: got an array of shape {r.shape}",
            )
        )
        return out, bare
    if not screen.in_range:
        out.extend(_check_ranges(axis.joint, r))
    fixed = axis.profile.fixed_period
    structural = _check_fixed_period(axis, r) if fixed else _check_epos2(axis.joint, r, screen.bad_inner_times)
    out.extend(structural)
    if not _has_motion(r, screen.in_range):
        # no first segment (or negative durations): there is no reconstruction to check
        return out, _bare_summary(axis, r)
    found, summary = _check_motion(axis, sample_period_ms, screen.worst)
    out.extend(found)
    return out, summary


def _check_ranges(name: str, r: NDArray[np.int64]) -> list[Finding]:
    out = []
    outside = _outside_ranges(r)
    for col, what, lo, hi, unit, kind in _RECORD_FIELDS:
        for k in np.flatnonzero(outside[:, col]):
            v = int(r[k, col])
            over = v - hi if v > hi else lo - v
            out.append(
                Finding(
                    Severity.ERROR,
                    Rule.RECORD_RANGE,
                    name,
                    int(k),
                    f"{what} {v} {unit} is outside {kind} [{lo}, {hi}] by {over}",
                    float(over),
                    float(v),
                    float(hi if v > hi else lo),
                    unit,
                )
            )
    return out


def _check_start_at_rest(name: str, r: NDArray[np.int64]) -> list[Finding]:
    """Every profile: records[0] is where the axis stands when the program starts, at rest."""
    if r[0, 1] == 0:
        return []
    return [
        Finding(
            Severity.ERROR,
            Rule.START_RECORD,
            name,
            0,
            f"the start record must have velocity 0 (the axis is at rest), has {int(r[0, 1])}",
            float(abs(r[0, 1])),
            float(r[0, 1]),
            0.0,
            "velocity units",
        )
    ]


def _check_epos2(name: str, r: NDArray[np.int64], bad_inner_times: list[int]) -> list[Finding]:
    """records[0]: start at rest, dwell >= 1 ms; motion records 1..255 ms (``bad_inner_times``: those
    outside, from :func:`_screen`); last: time 0 at rest."""
    out = []
    n = len(r)
    out.extend(_check_start_at_rest(name, r))
    if not 1 <= r[0, 2] <= TIME_MAX_MS:
        out.append(
            Finding(
                Severity.ERROR,
                Rule.TIME_RANGE,
                name,
                0,
                f"the start record's time (dwell before the first segment) must be in 1..255 ms, is {int(r[0, 2])}",
                float(1 - r[0, 2] if r[0, 2] < 1 else r[0, 2] - TIME_MAX_MS),
                float(r[0, 2]),
                1.0 if r[0, 2] < 1 else float(TIME_MAX_MS),
                "ms",
            )
        )
    for k in bad_inner_times:
        t = int(r[k, 2])
        if t == 0:
            out.append(
                Finding(
                    Severity.ERROR,
                    Rule.TIME_RANGE,
                    name,
                    k,
                    f"time 0 ends interpolation here, before the last record: records {k + 1}..{n - 1} would never run",
                    1.0,
                    0.0,
                    1.0,
                    "ms",
                )
            )
        elif not 1 <= t <= TIME_MAX_MS:
            over = 1 - t if t < 1 else t - TIME_MAX_MS
            out.append(
                Finding(
                    Severity.ERROR,
                    Rule.TIME_RANGE,
                    name,
                    k,
                    f"segment time {t} ms is outside 1..255 ms by {over}",
                    float(over),
                    float(t),
                    1.0 if t < 1 else float(TIME_MAX_MS),
                    "ms",
                )
            )
    last = n - 1
    if r[last, 2] != 0:
        out.append(
            Finding(
                Severity.ERROR,
                Rule.END_RECORD,
                name,
                last,
                f"the last record must have time 0 (it ends interpolation; without it the drive "
                f"runs its buffer empty and faults with an underflow), has {int(r[last, 2])} ms",
            )
        )
    else:
        if r[last, 1] != 0 or r[last - 1, 1] != 0:
            k = last if r[last, 1] != 0 else last - 1
            out.append(
                Finding(
                    Severity.ERROR,
                    Rule.END_RECORD,
                    name,
                    k,
                    f"the motion must end at rest: record {k} has velocity {int(r[k, 1])}",
                    float(abs(r[k, 1])),
                    float(r[k, 1]),
                    0.0,
                    "velocity units",
                )
            )
        if last >= 1:
            out.extend(_repeats_final_position(name, r, "the end record must repeat the final position {} qc"))
    return out


def _repeats_final_position(name: str, r: NDArray[np.int64], rule: Rule) -> list[Finding]:
    """The end-record finding when the last record does not repeat the one before's position
    (``rule`` words it for the profile, ``{}`` for that position)."""
    last = len(r) - 1
    if r[last, 0] == r[last - 1, 0]:
        return []
    d = int(r[last, 0] - r[last - 1, 0])
    return [
        Finding(
            Severity.ERROR,
            Rule.END_RECORD,
            name,
            last,
            rule.format(int(r[last - 1, 0])) + f", differs by {d} qc",
            float(abs(d)),
            float(r[last, 0]),
            float(r[last - 1, 0]),
            "qc",
        )
    ]


def _check_fixed_period(axis: AxisProgram, r: NDArray[np.int64]) -> list[Finding]:
    """One setpoint per period: every time equals the period; the program starts and ends at rest."""
    out = []
    name = axis.joint
    period = int(r[0, 2])
    if not 1 <= period <= TIME_MAX_MS:
        out.append(
            Finding(
                Severity.ERROR,
                Rule.PERIOD,
                name,
                0,
                f"the period (time of every record) must be in 1..255 ms, is {period}",
                0.0,
                float(period),
                None,
                "ms",
            )
        )
    else:
        for k in np.flatnonzero(r[:, 2] != period):
            d = int(r[k, 2]) - period
            out.append(
                Finding(
                    Severity.ERROR,
                    Rule.PERIOD,
                    name,
                    int(k),
                    f"time {int(r[k, 2])} ms differs from the axis's period {period} ms by {d:+d} ms "
                    f"({axis.profile} takes one setpoint per period)",
                    float(abs(d)),
                    float(r[k, 2]),
                    float(period),
                    "ms",
                )
            )
    out.extend(_check_start_at_rest(name, r))
    last = len(r) - 1
    if r[last, 1] != 0:
        out.append(
            Finding(
                Severity.ERROR,
                Rule.END_RECORD,
                name,
                last,
                f"the motion must end at rest: the last record has velocity {int(r[last, 1])}",
                float(abs(r[last, 1])),
                float(r[last, 1]),
                0.0,
                "velocity units",
            )
        )
    out.extend(
        _repeats_final_position(
            name, r, "the motion must end at rest: the last setpoint must repeat the one before ({} qc)"
        )
    )
    return out


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


def _summary_within_limits(axis: AxisProgram, worst: _Worst, sample_period_ms: float | None) -> AxisSummary | None:
    """The axis's summary if its worst values are within every limit (then no segment has a motion
    finding), else None.

    The unit conversions are monotonic, so the converted worst value is the worst converted value:
    these are the very numbers the segment-by-segment check reports.
    """
    s = axis.scaling
    lim = axis.limits
    vmax = float(s.qc_per_ms_to_rpm(worst.speed))
    amax = float(s.qc_per_ms2_to_rpm_s(worst.acceleration))
    if not all(math.isfinite(x) for x in worst):
        return None  # a segment's NaN would hide behind the worst value: look at each one
    value = {"velocity": vmax, "acceleration": amax}
    if any(exceeds(value[m.kind], m.limit) for m in _motion_limits(axis)):
        return None
    if worst.lowest < lim.min_position_qc or worst.highest > lim.max_position_qc:
        return None
    sv = sa = np.zeros(0)
    if sample_period_ms:
        _, sv, sa = _samples(axis, axis.reconstruction(), sample_period_ms)
    return _summary(axis, worst.end_ms, vmax, amax, sv, sa, worst.lowest, worst.highest)


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


def _check_motion(
    axis: AxisProgram, sample_period_ms: float | None, worst: _Worst | None = None
) -> tuple[list[Finding], AxisSummary]:
    """0x607D, 0x607F, 0x60C5 (errors) and 0x6081, 0x6083 (warnings) along the reconstruction.

    With the ``worst`` values of an EPOS2 axis, only an axis that breaks a limit is gone through
    segment by segment.
    """
    if worst is not None:
        summary = _summary_within_limits(axis, worst, sample_period_ms)
        if summary is not None:
            return [], summary
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
