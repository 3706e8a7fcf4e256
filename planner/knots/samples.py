"""The plan in drive units at every drive ms (qc, qc/ms), and the per-axis constants in those units."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.knots.samples_kernels import to_drive_units
from pvtflow.planner.knots.types import DriveAxis, TimedTrajectory


@dataclass(frozen=True)
class Samples:
    """The (slowed) trajectory in drive units at every ms, and its acceleration jumps."""

    scale: float
    n_ms: int  # last sample index: samples at 0..n_ms ms
    position: NDArray[np.float64]  # (dof, n_ms + 1) qc
    velocity: NDArray[np.float64]  # (dof, n_ms + 1) qc/ms
    switch_ms: NDArray[np.float64]  # breakpoint times (ms)
    jump: NDArray[np.float64]  # (len(switch_ms), dof) |acceleration jump| qc/ms^2
    window_jerk: NDArray[np.float64]  # (dof,) the drive's allowed 10-ms-window jerk, qc/ms^3 (inf: none)


def read_only(*arrays: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    for a in arrays:
        a.flags.writeable = False  # shared by every plan on these axes
    return arrays


@functools.lru_cache(maxsize=64)
def _unit_conversions(axes: tuple[DriveAxis, ...]) -> tuple[NDArray[np.float64], ...]:
    """Joint units to drive units, per axis: every conversion is affine, so (position offset,
    position at 1, velocity gain, acceleration gain) from each axis's scaling, once per set of axes."""
    unit = np.array([0.0, 1.0])
    pos_0, pos_1 = np.array([a.scaling.position_to_qc(unit) for a in axes]).T
    vel_1 = np.array([a.scaling.drive_velocity_to_qc_per_ms(a.scaling.velocity_to_drive(1.0)) for a in axes])
    acc_1 = np.array([a.scaling.rpm_s_to_qc_per_ms2(a.scaling.acceleration_to_rpm_s(1.0)) for a in axes])
    return read_only(pos_0.copy(), pos_1.copy(), vel_1, acc_1)


@functools.lru_cache(maxsize=64)
def axis_constants(axes: tuple[DriveAxis, ...]) -> tuple[NDArray[np.float64], ...]:
    """The per-axis constants of ``Flat`` (f, amax, vmax, v_units, pos_lo, pos_hi, rv_per, ra_per),
    once per set of axes."""
    sc = [a.scaling for a in axes]
    lim = [a.limits for a in axes]
    pairs = list(zip(sc, lim, strict=True))
    return read_only(
        np.array([s.qc_per_ms_per_velocity_unit for s in sc]),
        np.array([float(s.rpm_s_to_qc_per_ms2(m.max_acceleration_rpm_s)) for s, m in pairs]),
        np.array([float(s.rpm_to_qc_per_ms(m.max_profile_velocity_rpm)) for s, m in pairs]),
        np.array([math.floor(m.max_profile_velocity_rpm / s.velocity_unit_rpm + 1e-9) for s, m in pairs], dtype=float),
        np.array([float(m.min_position_qc) for m in lim]),
        np.array([float(m.max_position_qc) for m in lim]),
        np.array([float(s.qc_per_ms_to_rpm(1.0)) / m.max_profile_velocity_rpm for s, m in pairs]),
        np.array([float(s.qc_per_ms2_to_rpm_s(1.0)) / m.max_acceleration_rpm_s for s, m in pairs]),
    )


def sample_trajectory(
    traj: TimedTrajectory,
    axes: Sequence[DriveAxis],
    scale: float,
    max_jerk: Sequence[float] | None = None,
    window_jerk_ratio: float = 1.2,
) -> Samples:
    """The plan slowed down by ``scale`` at every drive ms; ``max_jerk`` (joint units/s^3 per
    axis) times ``window_jerk_ratio``, in qc/ms^3, is what the drive's window jerk may reach (the
    limit of the plan, not of the slowed motion: a slower one only has more room)."""
    duration_ms = traj.duration * 1000.0 * scale
    n = max(1, math.ceil(duration_ms - 1e-6))
    q, qd = traj.states(np.arange(n + 1) / (1000.0 * scale))  # trajectory time of each drive ms
    switch_s, jump_joint = traj.acceleration_jumps()
    pos_0, pos_1, vel_1, acc_1 = _unit_conversions(tuple(axes))
    q, qd = np.ascontiguousarray(q), np.ascontiguousarray(qd)  # one compiled signature
    to_drive_units(q, qd, pos_0, pos_1, vel_1 / scale)
    jerk = np.full(len(axes), np.inf)
    if max_jerk is not None:  # a hair below the allowance: the same numbers in other units never read over it
        jerk = np.asarray(max_jerk, dtype=float) * np.abs(acc_1) * (1e-3 * window_jerk_ratio * (1.0 - 1e-6))
    return Samples(scale, n, q, qd, switch_s * 1000.0 * scale, jump_joint * (np.abs(acc_1) / (scale * scale)), jerk)
