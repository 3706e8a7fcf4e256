"""A small hand-made axis and program, for the tests of the program's rules (planner) and commands (service)."""

from __future__ import annotations

import numpy as np

from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits

# 2000 qc per motor revolution: 1 rpm = 1/30 qc/ms, 1 qc/ms^2 = 30000 rpm/s
SCALING = AxisScaling(2000, 160 / (2 * np.pi))
LIMITS = DriveLimits(
    max_profile_velocity_rpm=4000, max_acceleration_rpm_s=30000, min_position_qc=-100000, max_position_qc=100000
)

# 0 -> 100 qc in 50 ms from rest to rest: peak 3 qc/ms = 90 rpm, 0.24 qc/ms^2 = 7200 rpm/s
GOOD_RECORDS = [[0, 0, 1], [100, 0, 50], [100, 0, 0]]


def axis(
    records,
    name: str = "joint_1",
    node_id: int = 1,
    profile: str = "epos2_pvt",
    limits: DriveLimits = LIMITS,
    submode: int | None = None,
) -> AxisProgram:
    records = np.asarray(records, dtype=np.int64)
    return AxisProgram(name, node_id, profile, SCALING, limits, interpolation_submode=submode, records=records)


def program(*axes: AxisProgram) -> PvtProgram:
    return PvtProgram("test", tuple(axes))
