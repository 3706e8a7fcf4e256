"""Checks of a PVT program against the rules its drives enforce: the one validator.

The CLI, the service and the tests all call :func:`validate_program`. Every motion check runs on
what the drive itself will execute, ``AxisProgram.reconstruction()`` (axes.drive.interpolation),
never on a formula of its own: exactly (closed-form extrema per segment) and at the drive's 1 kHz
samples. Errors are what makes a drive refuse or fault (0x607F, 0x60C5, 0x607D, record ranges,
the start and end rules); warnings are what only sets a warning bit (0x6081, 0x6083).

Each finding carries a stable rule code, so that tools can react to it without parsing text:

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

Where each part lives: ``report`` (the findings, each axis's summary, the report), ``records``
(the rules on the records themselves), ``screen`` (one look at all axes at once, and the compiled
pass over the EPOS2 axes' segments), ``motion`` (the rules on the reconstruction), and the
program's walk through them, :func:`validate_program`, here.

The validator imports only ``axes`` (the drives' rules are theirs), yet it stays in the planner:
its compiled pass shares the planner's kernel cache (``planner.kernel_cache``, whose stamp holds
the drive's cubic it inlines; numba alone would keep a stale pass after an edit of ``hermite``),
and it is the planner's last word on every program it emits (``planner.build``). A program from
another tool is checked by the same function (``pvtflow validate``, ``pvtflow execute``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import DRIVE_SAMPLE_MS
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.planner.validate.motion import check_motion, summaries_within_limits
from pvtflow.planner.validate.records import check_epos2, check_fixed_period, check_ranges
from pvtflow.planner.validate.report import AxisSummary, Finding, Rule, Severity, ValidationReport
from pvtflow.planner.validate.screen import Screen, clean_worsts, has_motion, screen_axes

__all__ = ["AxisSummary", "Finding", "Rule", "Severity", "ValidationReport", "validate_program"]


def validate_program(
    program: PvtProgram,
    *,
    sample_period_ms: float | None = DRIVE_SAMPLE_MS,
    source: str | None = None,
) -> ValidationReport:
    """Check every axis of ``program`` against its drive's rules; never raises for a bad program.

    ``sample_period_ms=None`` skips the look at the drive's own samples: the exact checks alone
    decide (they bound the samples), which is what the planner's last check before output needs.
    All axes' records are looked at once (:func:`clean_worsts`, else :func:`screen_axes`); an axis
    is gone through segment by segment only where that look finds something to report.
    """
    errors: list[Finding] = []
    warnings: list[Finding] = []
    summaries: list[AxisSummary] = []
    records = [np.asarray(axis.records, dtype=np.int64) for axis in program.axes]
    worsts = clean_worsts(program.axes, records)
    if worsts is not None:  # no rule on records broken: the worst values alone decide
        within = summaries_within_limits(program.axes, worsts, sample_period_ms)
        if within is not None:
            return ValidationReport(program.cell, (), (), tuple(within), source)
    for axis, r, screen in zip(program.axes, records, screen_axes(program.axes, records), strict=True):
        found, summary = _validate_axis(axis, r, sample_period_ms, screen)
        for f in found:
            (errors if f.severity == Severity.ERROR else warnings).append(f)
        summaries.append(summary)
    return ValidationReport(program.cell, tuple(errors), tuple(warnings), tuple(summaries), source)


def _bare_summary(axis: AxisProgram, r: NDArray[np.int64]) -> AxisSummary:
    """The summary of an axis without a reconstruction to check."""
    shaped = r.ndim == 2 and r.shape[1] == 3 and len(r)
    return AxisSummary(axis.joint, axis.profile, len(r), float(r[:, 2].sum()) if shaped else 0.0)


def _validate_axis(
    axis: AxisProgram, r: NDArray[np.int64], sample_period_ms: float | None, screen: Screen
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
        out.extend(check_ranges(axis.joint, r))
    fixed = axis.profile.fixed_period
    structural = check_fixed_period(axis, r) if fixed else check_epos2(axis.joint, r, screen.bad_inner_times)
    out.extend(structural)
    if not has_motion(r, screen.in_range):
        # no first segment (or negative durations): there is no reconstruction to check
        return out, _bare_summary(axis, r)
    found, summary = check_motion(axis, sample_period_ms, screen.worst)
    out.extend(found)
    return out, summary
