"""One axis as every layer names it: the joint it moves and its drive (node id, profile, setpoint
period, submode, scaling, limit objects).

The cell file's axis (``AxisConfig``: this and how the drive is set up), a program's axis
(``AxisProgram``: this and its records) and the axis the planner places knots for are this one
description, so that nothing converts one into another.
"""

from __future__ import annotations

from dataclasses import dataclass

from pvtflow.axes.drive.drive_profile import PERIOD_RANGE_MS, DriveProfile
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits


@dataclass(frozen=True)
class DriveAxis:
    """The joint an axis moves and what its drive makes of records: profile (a cell file's name is
    turned into its ``DriveProfile``), scaling, limit objects, setpoint period and submode."""

    joint: str
    node_id: int
    profile: DriveProfile
    scaling: AxisScaling
    limits: DriveLimits
    period_ms: int | None = None  # fixed-period profiles: one record per period
    interpolation_submode: int | None = None  # 0x60C0, profiles with submodes (DriveProfile.submode)

    def __post_init__(self) -> None:
        object.__setattr__(self, "profile", DriveProfile.parse(self.profile))
        lo, hi = PERIOD_RANGE_MS
        if self.profile.fixed_period and not (self.period_ms and lo <= self.period_ms <= hi):
            raise ValueError(
                f"{self.joint}: a {self.profile} axis needs a period of {lo}..{hi} ms, got {self.period_ms}"
            )
