"""What knot placement takes and gives: the trajectory it samples, the axes (``axes.drive.axis.DriveAxis``), the
options, the records."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.axis import DriveAxis as DriveAxis  # the axes layer's one description of an axis
from pvtflow.axes.drive.program import TIME_MAX_MS


class TimedTrajectory(Protocol):
    """What knot placement needs of a trajectory (planner.timing.Trajectory): seconds, joint units."""

    @property
    def duration(self) -> float: ...

    @property
    def breakpoints(self) -> NDArray[np.float64]: ...

    def states(self, t: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...  # q, q' (dof, len(t))

    def acceleration_jumps(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...  # times, (n, dof)


class KnotError(ValueError):
    """No program within the options meets the drive's limits (e.g. more slow-down than allowed)."""


@dataclass(frozen=True)
class KnotOptions:
    tolerance_qc: float = 1.0  # max |reconstruction - plan| at the drive's 1 kHz samples
    fit_fraction: float = 0.8  # refinement target of the fits, a fraction of the tolerance (0.6: 5 % more records)
    # an acceleration jump above this fraction of 0x60C5 gets its own knot (with the flattened profile,
    # planner.speed_band, 0.01 places fewer records than 0.02: bench/RESULTS.md, issue 25 item 4)
    switch_fraction: float = 0.01
    min_switch_gap_ms: int = 8  # switch knots closer than this are merged (short segments amplify rounding)
    dwell_ms: int = 1  # time of records[0]: the wait from the start SYNC to the first segment
    max_time_scale: float = 1.05  # give up rather than slow the motion down more than this ...
    max_extra_ms: int = 50  # ... unless that is less than this much time (a short move's whole ms cost more)
    max_rounds: int = 10  # slow-down rounds
    max_splits: int = 40  # refinement rounds per axis
    # per axis (joint units/s^3; None or inf: none): the jerk limit the plan was timed with; the
    # drive's 10-ms-window jerk (``planner.knots.window_jerk``) is held to ``window_jerk_ratio`` times it
    max_jerk: Sequence[float | None] | None = None
    window_jerk_ratio: float = 1.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance_qc) and self.tolerance_qc >= 0.5):
            raise ValueError(f"tolerance_qc must be >= 0.5 count (positions are integers), got {self.tolerance_qc}")
        if self.max_jerk is not None:
            jerk = tuple(math.inf if j is None else float(j) for j in self.max_jerk)
            if not all(j > 0 for j in jerk):
                raise ValueError(f"max_jerk must be positive (None or inf: none), got {self.max_jerk}")
            object.__setattr__(self, "max_jerk", jerk if any(map(math.isfinite, jerk)) else None)
        if not 1 <= self.dwell_ms <= TIME_MAX_MS:
            raise ValueError(f"dwell_ms must be in 1..255, got {self.dwell_ms}")


@dataclass(frozen=True)
class AxisKnots:
    """The records of one axis and what their reconstruction does."""

    name: str
    records: NDArray[np.int64]
    deviation_qc: float  # worst |reconstruction - plan| at 1 kHz
    velocity_ratio: float  # exact max |v| / 0x607F of the reconstruction
    acceleration_ratio: float  # exact max |a| / 0x60C5
    jerk_ratio: float = 0.0  # 10-ms-window jerk / what the jerk limit allows (window_jerk_ratio x it; 0: none)


@dataclass(frozen=True)
class KnotResult:
    axes: tuple[AxisKnots, ...]
    time_scale: float  # slow-down applied to the trajectory (1.0: none)
    duration_ms: int  # motion time of the program (without the start dwell)
    rounds: int

    @property
    def deviation_qc(self) -> float:
        return max((a.deviation_qc for a in self.axes), default=0.0)
