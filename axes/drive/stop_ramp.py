"""The stop of a drive that makes no ramp of its own: braking setpoints from the master, then hold.

The bufferless servodrive (seed servodrive-ip-no-buffer: "profile parameters don't influence
trajectory generation; the master is responsible of limiting speed/acceleration/deceleration in
this mode") and the Parker SLVDN below a 2.5 ms cycle (its position loop takes each setpoint as the
SYNC brings it) have no halt ramp: the halt bit with no more setpoints stops them as fast as their
loop can. So on a halt or a stop the master goes on feeding them one setpoint per SYNC, braking at
constant deceleration from the last position and velocity it commanded to rest, and then sends
nothing more: the drive holds the last one.

The deceleration is the drive's own limit as the master wrote it (``expected_settings``): 0x60C5 for
a stop; for the halt on a fault, the quick stop deceleration 0x6085 where it is smaller (pvtflow
writes 0x6085 = 0x60C5, ``Profile.supervise_master``, so today both are one value). The curve is the
drive cubic (``axes.drive.interpolation``) from (last, v0) to rest on the first whole count at or past the
natural stop, sampled once per period: its deceleration is at most the limit, and the whole counts'
rounding of the setpoints is what a drive's judgement of a linear reconstruction allows
(``LINEAR_QUANTIZATION_QC``), as for any program.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import Interpolation, PiecewiseCubic, hermite_coefficients
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits


def stop_deceleration_rpm_s(limits: DriveLimits, quick: bool) -> float:
    """The deceleration (rpm/s) of the master's stop ramp: 0x60C5; a quick stop: min(0x60C5, 0x6085)
    (0x6085 is written as 0x60C5, so they agree)."""
    written_quick_stop = float(limits.braking_rpm_s)  # 0x6085 as supervise_master writes it
    return min(limits.max_acceleration_rpm_s, written_quick_stop) if quick else limits.max_acceleration_rpm_s


def braking_positions(last: int, previous: int, period_ms: float, deceleration: float) -> NDArray[np.int64]:
    """The setpoints (qc) after ``last``, one per period, that brake the velocity the drive runs at,
    (last - previous) / period (qc/ms), to rest at ``deceleration`` (qc/ms^2) at most; the last one is
    where the axis stops (empty: it is at rest)."""
    v0 = (last - previous) / period_ms
    if v0 == 0.0:
        return np.zeros(0, dtype=np.int64)
    natural = last + v0 * abs(v0) / (2.0 * deceleration)
    stop = math.ceil(natural) if v0 > 0 else math.floor(natural)
    duration = 2.0 * abs(stop - last) / abs(v0)  # the constant deceleration that ends on ``stop``
    c0, c1, c2, c3 = (np.atleast_1d(c) for c in hermite_coefficients(last, v0, stop, 0.0, duration))
    curve = PiecewiseCubic(np.zeros(1), np.array([duration]), c0, c1, c2, c3, Interpolation.CUBIC_PV)
    n = max(1, math.ceil(duration / period_ms - 1e-9))
    positions = np.rint(curve.position(np.arange(1, n + 1) * period_ms)).astype(np.int64)
    positions[-1] = stop
    return positions


def braking_records(
    last: int, previous: int, period_ms: float, limits: DriveLimits, scaling: AxisScaling, quick: bool
) -> NDArray[np.int64]:
    """The stop ramp as program records [position qc, velocity in the drive's unit, period ms]: the
    velocity is each setpoint's step over the period (the feed-forward a Parker frame carries)."""
    a = float(scaling.rpm_s_to_qc_per_ms2(stop_deceleration_rpm_s(limits, quick)))
    positions = braking_positions(last, previous, period_ms, a)
    steps = np.diff(np.concatenate(([last], positions))) / period_ms
    velocities = np.rint(steps / scaling.qc_per_ms_per_velocity_unit).astype(np.int64)
    times = np.full(len(positions), round(period_ms), dtype=np.int64)
    return np.column_stack((positions, velocities, times)).astype(np.int64)
