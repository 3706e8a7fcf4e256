"""Joint units <-> drive units: the one place where an axis's scaling is applied.

Joint units are rad (revolute) and m (prismatic). Drive units are quad counts (qc) for
position, motor rpm (times the drive's velocity unit, see 0x608B) for velocity, rpm/s for
acceleration and ms for time. Everything in pvtflow that crosses that border calls this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
INT24_MIN, INT24_MAX = -(2**23), 2**23 - 1


@dataclass(frozen=True)
class AxisScaling:
    """How one axis turns joint motion into motor revolutions and encoder counts.

    ``motor_rev_per_joint_unit`` is the gear ratio over 2 pi for a revolute joint and the gear
    ratio over the lead (m per screw revolution) for a prismatic one; a negative value inverts
    the direction. ``position_offset_qc`` is the drive position at joint zero (after homing).
    """

    qc_per_motor_rev: float
    motor_rev_per_joint_unit: float
    velocity_unit_rpm: float = 1.0
    position_offset_qc: int = 0

    def __post_init__(self) -> None:
        for name in ("qc_per_motor_rev", "velocity_unit_rpm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not (math.isfinite(self.motor_rev_per_joint_unit) and self.motor_rev_per_joint_unit != 0):
            raise ValueError(
                f"motor_rev_per_joint_unit must be a non-zero number, got {self.motor_rev_per_joint_unit!r}"
            )

    @classmethod
    def revolute(
        cls, qc_per_motor_rev: float, gear_ratio: float, velocity_unit_rpm: float = 1.0, position_offset_qc: int = 0
    ) -> AxisScaling:
        """A rotary joint driven through a gearbox of ``gear_ratio`` motor revolutions per joint revolution."""
        return cls(qc_per_motor_rev, gear_ratio / (2.0 * math.pi), velocity_unit_rpm, position_offset_qc)

    @classmethod
    def prismatic(
        cls,
        qc_per_motor_rev: float,
        lead_m: float,
        gear_ratio: float = 1.0,
        velocity_unit_rpm: float = 1.0,
        position_offset_qc: int = 0,
    ) -> AxisScaling:
        """A linear joint: a screw or belt of ``lead_m`` metres per revolution behind a gearbox."""
        if not (math.isfinite(lead_m) and lead_m > 0):
            raise ValueError(f"lead_m must be a positive number, got {lead_m!r}")
        return cls(qc_per_motor_rev, gear_ratio / lead_m, velocity_unit_rpm, position_offset_qc)

    # --- derived factors -------------------------------------------------------------------
    @property
    def qc_per_joint_unit(self) -> float:
        return self.qc_per_motor_rev * self.motor_rev_per_joint_unit

    @property
    def rpm_per_joint_velocity(self) -> float:
        """Motor rpm for one joint unit per second."""
        return self.motor_rev_per_joint_unit * 60.0

    @property
    def qc_per_ms_per_velocity_unit(self) -> float:
        """qc/ms for one drive velocity unit: the factor the drive's interpolator uses."""
        return self.velocity_unit_rpm * self.qc_per_motor_rev / 60000.0

    # --- position --------------------------------------------------------------------------
    def position_to_qc(self, q: ArrayLike) -> NDArray[np.float64]:
        """Joint position -> drive position in qc (not rounded)."""
        return self.position_offset_qc + np.asarray(q, dtype=float) * self.qc_per_joint_unit

    def qc_to_position(self, qc: ArrayLike) -> NDArray[np.float64]:
        return (np.asarray(qc, dtype=float) - self.position_offset_qc) / self.qc_per_joint_unit

    # --- velocity --------------------------------------------------------------------------
    def velocity_to_rpm(self, qd: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(qd, dtype=float) * self.rpm_per_joint_velocity

    def rpm_to_velocity(self, rpm: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(rpm, dtype=float) / self.rpm_per_joint_velocity

    def velocity_to_drive(self, qd: ArrayLike) -> NDArray[np.float64]:
        """Joint velocity -> drive velocity units (rpm / velocity_unit_rpm), not rounded."""
        return self.velocity_to_rpm(qd) / self.velocity_unit_rpm

    def drive_to_velocity(self, v: ArrayLike) -> NDArray[np.float64]:
        return self.rpm_to_velocity(np.asarray(v, dtype=float) * self.velocity_unit_rpm)

    # --- acceleration ----------------------------------------------------------------------
    def acceleration_to_rpm_s(self, qdd: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(qdd, dtype=float) * self.rpm_per_joint_velocity

    def rpm_s_to_acceleration(self, rpm_s: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(rpm_s, dtype=float) / self.rpm_per_joint_velocity

    # --- drive-internal units (what the interpolator works in) ---------------------------------
    def drive_velocity_to_qc_per_ms(self, v: ArrayLike) -> NDArray[np.float64]:
        """Drive velocity units -> qc/ms, as the EPOS2 converts a record's V before interpolating."""
        return np.asarray(v, dtype=float) * self.qc_per_ms_per_velocity_unit

    def qc_per_ms_to_rpm(self, qc_per_ms: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(qc_per_ms, dtype=float) * 60000.0 / self.qc_per_motor_rev

    def rpm_to_qc_per_ms(self, rpm: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(rpm, dtype=float) * self.qc_per_motor_rev / 60000.0

    def qc_per_ms2_to_rpm_s(self, qc_per_ms2: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(qc_per_ms2, dtype=float) * 60000.0 * 1000.0 / self.qc_per_motor_rev

    def rpm_s_to_qc_per_ms2(self, rpm_s: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(rpm_s, dtype=float) * self.qc_per_motor_rev / (60000.0 * 1000.0)


@dataclass(frozen=True)
class DriveLimits:
    """The drive's own limit objects, in drive units, as written to its object dictionary.

    0x607F and 0x60C5 fault the drive when its interpolation exceeds them; 0x6081/0x6083 only
    raise a warning; 0x607D bounds every position demand.
    """

    max_profile_velocity_rpm: float  # 0x607F
    max_acceleration_rpm_s: float  # 0x60C5
    min_position_qc: int  # 0x607D:01
    max_position_qc: int  # 0x607D:02
    profile_velocity_rpm: float | None = None  # 0x6081
    profile_acceleration_rpm_s: float | None = None  # 0x6083

    def __post_init__(self) -> None:
        for name in ("max_profile_velocity_rpm", "max_acceleration_rpm_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name in ("profile_velocity_rpm", "profile_acceleration_rpm_s"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not (INT32_MIN <= self.min_position_qc < self.max_position_qc <= INT32_MAX):
            raise ValueError(
                f"software position limits must satisfy int32 min <= min < max <= int32 max, "
                f"got [{self.min_position_qc}, {self.max_position_qc}]"
            )

    @property
    def braking_rpm_s(self) -> int:
        """The deceleration the drive brakes on, in the whole rpm/s its objects hold: 0x60C5 as written,
        and the ramps pvtflow sets to it (quick stop 0x6085, the halt's 0x6084)."""
        return round(self.max_acceleration_rpm_s)

    def scaled(self, velocity: float, acceleration: float) -> DriveLimits:
        """0x607F and 0x60C5 multiplied by a speed override: what a scaled plan's records are held
        to. The drive keeps its own objects (a program carries those)."""
        return replace(
            self,
            max_profile_velocity_rpm=self.max_profile_velocity_rpm * velocity,
            max_acceleration_rpm_s=self.max_acceleration_rpm_s * acceleration,
        )

    def to_json(self) -> dict[str, float | int]:
        out: dict[str, float | int] = {
            "max_profile_velocity_rpm": self.max_profile_velocity_rpm,
            "max_acceleration_rpm_s": self.max_acceleration_rpm_s,
            "min_position_qc": self.min_position_qc,
            "max_position_qc": self.max_position_qc,
        }
        if self.profile_velocity_rpm is not None:
            out["profile_velocity_rpm"] = self.profile_velocity_rpm
        if self.profile_acceleration_rpm_s is not None:
            out["profile_acceleration_rpm_s"] = self.profile_acceleration_rpm_s
        return out
