"""One look at every axis's records at once, so that a program with nothing to report is fast.

The planner validates every program it emits. Each rule is checked once over all axes' records
together, and the EPOS2 axes' worst values come from one compiled pass over all their segments
(``epos2_segment`` and ``hermite``, as ``epos2_pvt`` builds them, and the same closed-form extrema:
the very same numbers the segment-by-segment check reports). Only an axis with something to
report is then gone through segment by segment. The pass inlines the drive's cubic: this file is
one of ``planner.kernel_cache.KERNEL_SOURCES``.

A program of EPOS2 axes only (every program the planner emits) gets one compiled call for all of
it (``_epos2_screen``): the rules on the records (ranges, start, times, end) and the worst values
together; the numpy rules run only where that call finds something. This is still the validator's
own look at the records: it shares the drive's reconstruction with the knot placement, not the
placement's verdicts. The exact position range is solved only for segments that can reach past the
band of the segment starts (the cheap bound the placement's 0x607D check uses): every start is a
value of the reconstruction, so the others change neither extreme.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import (
    cubic_peak_acceleration,
    cubic_peak_speed,
    cubic_position_range,
    epos2_end,
    epos2_segment,
    hermite,
)
from pvtflow.axes.drive.program import TIME_MAX_MS, AxisProgram
from pvtflow.planner.validate.records import _FIELD_HI, _FIELD_LO, outside_motion_time, outside_ranges


class Worst(NamedTuple):
    """The worst values of an axis's EPOS2 reconstruction over all its segments (exact: closed forms)."""

    speed: float  # max |v|, qc/ms
    acceleration: float  # max |a|, qc/ms^2
    lowest: float  # min position, qc
    highest: float  # max position, qc
    end_ms: float  # the reconstruction's end time


@dataclass(frozen=True)
class Screen:
    """What the look at all axes' records at once found about one axis."""

    in_range: bool  # every field of every record is in range: no record-range finding
    bad_inner_times: list[int]  # records 1..N-2 whose time is outside 1..255 ms, in order
    worst: Worst | None  # None: not EPOS2 PVT, or no reconstruction to check


def has_motion(r: NDArray[np.int64], in_range: bool) -> bool:
    """(N >= 2, 3) records that have a reconstruction to check (the rest gets its structural findings
    only): a first segment, and no negative time (which records in range cannot have)."""
    return bool(r[0, 2] >= 1) and (in_range or not np.any(r[:, 2] < 0))


def clean_worsts(axes: tuple[AxisProgram, ...], records: list[NDArray[np.int64]]) -> list[Worst] | None:
    """For a program of EPOS2 axes only (every program the planner emits) whose records keep every
    rule on records, each axis's :class:`Worst`, in one compiled call (:func:`_epos2_screen`); None
    for any other program (then :func:`screen_axes` and the rules say what is wrong)."""
    if not axes or any(a.profile.fixed_period for a in axes):
        return None
    if not all(r.ndim == 2 and r.shape[1] == 3 and len(r) >= 2 for r in records):
        return None
    rows = np.ascontiguousarray(np.concatenate(records))
    first = np.zeros(len(records) + 1, dtype=np.int64)
    np.cumsum([len(r) for r in records], out=first[1:])
    factor = np.array([a.scaling.qc_per_ms_per_velocity_unit for a in axes], dtype=np.float64)
    found, clean = _epos2_screen(rows, first[:-1], first[1:], factor, _FIELD_LO, _FIELD_HI, TIME_MAX_MS)
    if not clean.all():
        return None
    return [Worst(*w) for w in found.tolist()]


def screen_axes(axes: tuple[AxisProgram, ...], records: list[NDArray[np.int64]]) -> list[Screen]:
    """Per axis, whether its records are all in range, which motion records have a time outside
    1..255 ms, and the worst values of its EPOS2 reconstruction: one check of each rule over all
    axes' records at once and one compiled pass over all EPOS2 axes' segments
    (:func:`_epos2_worst`), instead of a dozen numpy calls per axis."""
    shaped = [i for i, r in enumerate(records) if r.ndim == 2 and r.shape[1] == 3 and len(r) >= 2]
    screens = [Screen(False, [], None)] * len(axes)  # the others fail the shape check before any use
    if not shaped:
        return screens
    rows = np.ascontiguousarray(np.concatenate([records[i] for i in shaped]))  # C order: one compiled signature
    first = np.cumsum([0] + [len(records[i]) for i in shaped])  # each shaped axis's first row (and the end)
    outside = outside_ranges(rows)
    if outside.any():
        in_range = [not outside[first[j] : first[j + 1]].any() for j in range(len(shaped))]
    else:
        in_range = [True] * len(shaped)
    # the rows with a time outside 1..255 ms (usually just the end records, whose time is 0), and
    # where each axis's begin among them
    bad_time = np.flatnonzero(outside_motion_time(rows[:, 2]))
    bad_time_cut = np.searchsorted(bad_time, first).tolist()
    bad_time_rows, bounds = bad_time.tolist(), first.tolist()
    epos2 = [j for j, i in enumerate(shaped) if axes[i].profile.buffered and has_motion(records[i], in_range[j])]
    worst: dict[int, Worst] = {}
    if epos2:
        factor = np.array([axes[shaped[j]].scaling.qc_per_ms_per_velocity_unit for j in epos2], dtype=np.float64)
        js = np.array(epos2, dtype=np.intp)
        found = _epos2_worst(rows, first[js], first[js + 1], factor)
        worst = {j: Worst(*w) for j, w in zip(epos2, found.tolist(), strict=True)}
    for j, i in enumerate(shaped):
        begin, end = bounds[j], bounds[j + 1]
        inner = [g - begin for g in bad_time_rows[bad_time_cut[j] : bad_time_cut[j + 1]] if begin < g < end - 1]
        screens[i] = Screen(in_range[j], inner, worst.get(j))
    return screens


@njit(cache=True)
def _axis_worst(rows: NDArray[np.int64], begin: int, end: int, f: float, out: NDArray[np.float64]) -> None:
    """The :class:`Worst` of the EPOS2 reconstruction of records rows[begin:end] (velocity factor
    ``f``, qc/ms per unit) into ``out``: the segments as ``epos2_pvt`` builds them
    (``epos2_segment`` up to ``epos2_end``, ``hermite``), judged by ``cubic_peak_speed``,
    ``cubic_peak_acceleration``, ``cubic_position_range``; NaN where a value is not finite.

    A segment's exact position range is solved only where it can reach past the lowest or
    highest segment start: a Hermite cubic stays within T (|V0| + |V1|) 4/27 of its end points,
    and every segment start is a value of the reconstruction, so a segment inside that band (with
    room for round-off) changes neither extreme."""
    stop = epos2_end(rows, begin, end)
    low, high = math.inf, -math.inf  # the segment starts' (each segment's c0)
    for k in range(begin, stop):
        p0 = float(rows[k - 1, 0]) if k > begin else float(rows[k, 0])
        low, high = min(low, p0), max(high, p0)
    speed, accel, lowest, highest = -math.inf, -math.inf, math.inf, -math.inf
    end_ms = 0.0
    finite = True
    for k in range(begin, stop):
        p0, v0, p1, v1, T = epos2_segment(rows, begin, k, f)
        c0, c1, c2, c3 = hermite(p0, v0, p1, v1, T)
        s = cubic_peak_speed(c1, c2, c3, T)
        acc = cubic_peak_acceleration(c2, c3, T)
        reach = T * (abs(v0) + abs(v1)) * (4.0 / 27.0)
        room = 1e-9 * (abs(p0) + abs(p1) + reach + 1.0)
        if min(p0, p1) - reach - room > low and max(p0, p1) + reach + room < high:
            lo, hi = p0, p0  # inside the band: c0 is its one value that counts
        else:
            lo, hi = cubic_position_range(c0, c1, c2, c3, T)
        finite = finite and math.isfinite(s) and math.isfinite(acc) and math.isfinite(lo) and math.isfinite(hi)
        speed, accel = max(speed, s), max(accel, acc)
        lowest, highest = min(lowest, lo), max(highest, hi)
        end_ms += T
    out[0], out[1], out[2], out[3], out[4] = speed, accel, lowest, highest, end_ms
    if not finite:
        out[:] = math.nan


@njit(cache=True)
def _epos2_worst(
    rows: NDArray[np.int64], begin: NDArray[np.int64], end: NDArray[np.int64], factor: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per axis (records rows[begin:end], velocity factor qc/ms per unit), the :class:`Worst` of its
    EPOS2 reconstruction (:func:`_axis_worst`). An axis with a value that is not finite gets NaN
    (it is then gone through segment by segment).
    """
    out = np.empty((len(begin), 5))
    for a in range(len(begin)):
        _axis_worst(rows, begin[a], end[a], factor[a], out[a])
    return out


@njit(cache=True)
def _epos2_screen(
    rows: NDArray[np.int64],
    begin: NDArray[np.int64],
    end: NDArray[np.int64],
    factor: NDArray[np.float64],
    field_lo: NDArray[np.int64],
    field_hi: NDArray[np.int64],
    time_max: int,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per EPOS2 axis (records rows[begin:end], at least 2), whether its records keep every rule on
    records (``records.outside_ranges`` and ``records.check_epos2``: each field within
    ``field_lo``/``field_hi``, the start record at rest with a dwell of 1..``time_max`` ms, every
    motion record 1..``time_max`` ms, the last one time 0, at rest after a record at rest, at its
    position), and where it does, its :class:`Worst` (:func:`_axis_worst`); NaN where not finite."""
    n = len(begin)
    out = np.full((n, 5), math.nan)
    clean = np.zeros(n, dtype=np.bool_)
    for a in range(n):
        b, e = begin[a], end[a]
        ok = True
        for k in range(b, e):
            for c in range(3):
                if rows[k, c] < field_lo[c] or rows[k, c] > field_hi[c]:
                    ok = False
        for k in range(b, e - 1):  # the dwell and every motion record
            if rows[k, 2] < 1 or rows[k, 2] > time_max:
                ok = False
        last = e - 1
        if rows[b, 1] != 0 or rows[last, 2] != 0 or rows[last, 1] != 0 or rows[last - 1, 1] != 0:
            ok = False
        if rows[last, 0] != rows[last - 1, 0]:
            ok = False
        if not ok:
            continue
        _axis_worst(rows, b, e, factor[a], out[a])
        clean[a] = True
    return out, clean
