"""A timed trajectory plus the cell's axes -> a validated PVT program (pure: no I/O).

The program is checked by the same validator the CLI and the service use before it is handed
out: a program that would fault a drive is never returned.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from axes.program import PvtProgram
from planner.knots import DriveAxis, KnotError, KnotOptions, KnotResult, TimedTrajectory, place_knots
from planner.validate import ValidationReport, validate_program


class BuildError(ValueError):
    """No executable program for this trajectory on these axes (the message says which axis, why)."""


@dataclass(frozen=True)
class BuildOutput:
    program: PvtProgram
    knots: KnotResult
    report: ValidationReport
    timing: Mapping[str, float] = field(default_factory=dict)  # s: "knots" (placement), "validation"


def build_program(
    trajectory: TimedTrajectory,
    axes: Sequence[DriveAxis],
    cell: str,
    options: KnotOptions | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> BuildOutput:
    """Place the knots, assemble the program, validate it; BuildError if any of that fails."""
    opts = options or KnotOptions()
    start = time.perf_counter()
    try:
        knots = place_knots(trajectory, axes, opts)
    except KnotError as exc:
        raise BuildError(str(exc)) from None
    placed = time.perf_counter()
    meta: dict[str, Any] = {
        "duration_ms": knots.duration_ms + opts.dwell_ms,
        "planned_duration_ms": round(trajectory.duration * 1000.0, 3),
        "time_scale": knots.time_scale,
        "tolerance_qc": opts.tolerance_qc,
        "deviation_qc": {a.name: round(a.deviation_qc, 4) for a in knots.axes},
    }
    meta.update(metadata or {})
    program = PvtProgram(cell, tuple(ax.program(k.records) for ax, k in zip(axes, knots.axes, strict=True)), meta)
    report = validate_program(program, sample_period_ms=None)  # exact checks: they bound the samples
    if not report.ok:  # knot placement checks the same rules: this would be a bug, never shipped
        raise BuildError("the placed knots do not validate: " + "; ".join(f.format() for f in report.errors[:3]))
    timing = {"knots": placed - start, "validation": time.perf_counter() - placed}
    return BuildOutput(program, knots, report, timing)
