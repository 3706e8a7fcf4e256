"""Joint-space limits, derived from the drives' limit objects and merged with the URDF's.

Drive limits are facts about the drives; the planner's limits follow from them through the axis
scaling, never the other way round. Where the URDF is stricter, the URDF wins.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.planner.model import RobotModel


@dataclass(frozen=True)
class JointLimits:
    """Symmetric velocity/acceleration bounds and position bounds per joint (joint units)."""

    names: tuple[str, ...]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    velocity: NDArray[np.float64]
    acceleration: NDArray[np.float64]
    effort: NDArray[np.float64]

    def __post_init__(self) -> None:
        n = len(self.names)
        for name in ("lower", "upper", "velocity", "acceleration", "effort"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (n,):
                raise ValueError(f"{name} must have one entry per joint ({n}), got shape {arr.shape}")
            object.__setattr__(self, name, arr)

    @property
    def dof(self) -> int:
        return len(self.names)

    @classmethod
    def from_model(cls, model: RobotModel) -> JointLimits:
        """The URDF's limits (no acceleration limit there: inf)."""
        j = model.joints
        return cls(
            names=model.joint_names,
            lower=np.array([x.lower for x in j]),
            upper=np.array([x.upper for x in j]),
            velocity=np.array([x.velocity for x in j]),
            acceleration=np.full(len(j), np.inf),
            effort=np.array([x.effort for x in j]),
        )

    def merged_with(self, other: JointLimits) -> JointLimits:
        """The stricter of the two, joint by joint (matched by name)."""
        idx = [other.names.index(n) for n in self.names]
        return JointLimits(
            names=self.names,
            lower=np.maximum(self.lower, other.lower[idx]),
            upper=np.minimum(self.upper, other.upper[idx]),
            velocity=np.minimum(self.velocity, other.velocity[idx]),
            acceleration=np.minimum(self.acceleration, other.acceleration[idx]),
            effort=np.minimum(self.effort, other.effort[idx]),
        )

    def scaled(self, velocity: float = 1.0, acceleration: float = 1.0) -> JointLimits:
        """The same limits with the velocity and acceleration bounds multiplied by a speed override
        (``check_scale``: each in (0, 1]); positions and efforts stay."""
        v, a = check_scale("velocity_scale", velocity), check_scale("acceleration_scale", acceleration)
        return JointLimits(self.names, self.lower, self.upper, self.velocity * v, self.acceleration * a, self.effort)


def check_scale(name: str, value: object) -> float:
    """A speed override (``velocity_scale``, ``acceleration_scale``) as a float in (0, 1]; ValueError
    naming ``name`` for anything else (0, negative, above 1, NaN, not a number): an override may slow
    a motion down, never make it faster than the drives allow."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number in (0, 1], got {value!r}")
    x = float(value)
    if not 0.0 < x <= 1.0:  # NaN fails both comparisons
        raise ValueError(f"{name} must be in (0, 1], got {x:g}")
    return x


def check_max_jerk(name: str, value: object, dof: int) -> NDArray[np.float64]:
    """Per-joint jerk limits (joint units / s^3) as a float array of ``dof`` entries, each positive
    (inf: that joint unlimited); ValueError naming ``name`` for anything else (a wrong count, NaN, 0,
    negative, not a number): a jerk limit that cannot be met is refused, not ignored."""
    if isinstance(value, str | bytes) or not isinstance(value, Sequence | np.ndarray):
        raise ValueError(f"{name} must be a list of {dof} positive numbers (one per joint), got {value!r}")
    items = list(value)
    if len(items) != dof:
        raise ValueError(f"{name} has {len(items)} values, the cell has {dof} joints")
    for k, v in enumerate(items):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise ValueError(f"{name}[{k}] must be a positive number, got {v!r}")
        if not float(v) > 0.0:  # NaN fails too
            raise ValueError(f"{name}[{k}] must be positive, got {float(v):g}")
    return np.array(items, dtype=float)


def joint_limits_from_drives(
    names: Sequence[str],
    scalings: Sequence[AxisScaling],
    drives: Sequence[DriveLimits],
    shares: Sequence[float] | None = None,
) -> JointLimits:
    """0x607F [rpm], 0x60C5 [rpm/s] and 0x607D [qc] of each drive, in joint units; ``shares``: the
    factor on each drive's velocity and acceleration the plans are made with (``BusConfig.planning_share``)."""
    shares = [1.0] * len(names) if shares is None else list(shares)
    if not (len(names) == len(scalings) == len(drives) == len(shares)):
        raise ValueError("one scaling, one set of drive limits and one share per joint")
    lower, upper, vel, acc = [], [], [], []
    for s, d, share in zip(scalings, drives, shares, strict=True):
        a, b = s.qc_to_position([d.min_position_qc, d.max_position_qc])
        lower.append(min(a, b))
        upper.append(max(a, b))
        vel.append(share * abs(float(s.rpm_to_velocity(d.max_profile_velocity_rpm))))
        acc.append(share * abs(float(s.rpm_s_to_acceleration(d.max_acceleration_rpm_s))))
    n = len(names)
    return JointLimits(tuple(names), np.array(lower), np.array(upper), np.array(vel), np.array(acc), np.full(n, np.inf))
