"""The rules on the records themselves, before any motion: each field in its range, the start
record at rest, and the end and time rules of each kind of profile (EPOS2 PVT: motion records
1..255 ms, a time-0 end record; fixed period: every time equal to the period).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import TIME_MAX_MS, AxisProgram
from pvtflow.axes.drive.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN
from pvtflow.planner.validate.report import Finding, Rule, Severity

# The fields of a record and their ranges: (column, what, lowest, highest, unit, kind).
_RECORD_FIELDS = (
    (0, "position", INT32_MIN, INT32_MAX, "qc", "int32"),
    (1, "velocity", INT24_MIN, INT24_MAX, "velocity units", "int24"),
    (2, "time", 0, TIME_MAX_MS, "ms", "0..255 (uint8)"),
)
_FIELD_LO = np.array([lo for _, _, lo, _, _, _ in _RECORD_FIELDS], dtype=np.int64)
_FIELD_HI = np.array([hi for _, _, _, hi, _, _ in _RECORD_FIELDS], dtype=np.int64)


def outside_ranges(r: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per record and field, whether the value is outside the field's range (the record-range rule)."""
    return (r < _FIELD_LO) | (r > _FIELD_HI)


def outside_motion_time(t: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per record time, whether it is outside a motion record's 1..255 ms (the time-range rule)."""
    return (t < 1) | (t > TIME_MAX_MS)


def check_ranges(name: str, r: NDArray[np.int64]) -> list[Finding]:
    out = []
    outside = outside_ranges(r)
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


def check_epos2(name: str, r: NDArray[np.int64], bad_inner_times: list[int]) -> list[Finding]:
    """records[0]: start at rest, dwell >= 1 ms; motion records 1..255 ms (``bad_inner_times``: those
    outside, from :func:`screen_axes`); last: time 0 at rest."""
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


def check_fixed_period(axis: AxisProgram, r: NDArray[np.int64]) -> list[Finding]:
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
