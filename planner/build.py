"""A timed trajectory plus the cell's axes -> a validated PVT program (pure: no I/O).

The program is checked by the same validator the CLI and the service use before it is handed
out: a program that would fault a drive is never returned.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.planner.knots import DriveAxis, KnotError, KnotOptions, KnotResult, TimedTrajectory, place_knots
from pvtflow.planner.validate import ValidationReport, validate_program


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
    velocity_scale: float = 1.0,
    acceleration_scale: float = 1.0,
) -> BuildOutput:
    """Place the knots, assemble the program, validate it; BuildError if any of that fails.

    ``velocity_scale``, ``acceleration_scale``: the speed override the trajectory was planned with.
    The knots are placed so that the drives' reconstruction stays inside 0x607F and 0x60C5 scaled
    by it (a 0.5 plan stays under half the drives' speed on the drive too, not only in the plan);
    the program carries the drives' own objects, which is what the drives are checked against.
    """
    opts = options or KnotOptions()
    start = time.perf_counter()
    placing = axes
    if (velocity_scale, acceleration_scale) != (1.0, 1.0):
        placing = [replace(a, limits=a.limits.scaled(velocity_scale, acceleration_scale)) for a in axes]
    try:
        knots = place_knots(trajectory, placing, opts)
    except KnotError as exc:
        raise BuildError(str(exc)) from None
    placed = time.perf_counter()
    meta: dict[str, Any] = {
        "duration_ms": knots.duration_ms + opts.dwell_ms,
        "planned_duration_ms": round(trajectory.duration * 1000.0, 3),
        "time_scale": knots.time_scale,
        "tolerance_qc": opts.tolerance_qc,
        "deviation_qc": {a.name: round(a.deviation_qc, 4) for a in knots.axes},
        "velocity_scale": velocity_scale,
        "acceleration_scale": acceleration_scale,
    }
    meta.update(metadata or {})
    program = PvtProgram(
        cell, tuple(AxisProgram.of(ax, k.records) for ax, k in zip(axes, knots.axes, strict=True)), meta
    )
    report = validate_program(program, sample_period_ms=None)  # exact checks: they bound the samples
    if not report.ok:  # knot placement checks the same rules: this would be a bug, never shipped
        raise BuildError("the placed knots do not validate: " + "; ".join(f.format() for f in report.errors[:3]))
    timing = {"knots": placed - start, "validation": time.perf_counter() - placed}
    return BuildOutput(program, knots, report, timing)
