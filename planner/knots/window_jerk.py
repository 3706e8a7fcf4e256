"""The jerk a drive executes: the 10-ms-window jerk of its reconstruction.

A drive's cubic PVT is C1: its acceleration is linear inside a segment and jumps at every record
(a cubic's c3 over a few ms, from integer counts, can be tens of times a jerk limit). What a
machine feels is the acceleration's change over a short span, so the jerk limit is judged on the
window jerk ``max_t |a(t + W) - a(t)| / W`` (W = 10 ms) of the reconstruction the drive builds from
the records (``AxisProgram.reconstruction``, ``axes.drive.interpolation``), not on single segments.

``a`` is piecewise linear between the segments' ends, so ``a(t + W) - a(t)`` is piecewise linear
between the ends and the ends less W: its peak is at one of those instants, one-sided (the
acceleration before a record and after it). Before the first segment and after the last the drive
stands still (a = 0).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import PiecewiseCubic
from pvtflow.planner.smooth_kernels import window_jerk_peaks

WINDOW_MS = 10.0  # the span over which a machine feels an acceleration change


def window_jerk_profile(
    recon: PiecewiseCubic, window_ms: float = WINDOW_MS
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(t, |a(t + W) - a(t)| / W) at every instant where it can peak (qc/ms^3), the larger side
    (``smooth_kernels.window_jerk_peaks``, on the reconstruction's own coefficients)."""
    return window_jerk_peaks(recon.start, recon.duration, recon.c2, recon.c3, float(window_ms))


def window_jerk(recon: PiecewiseCubic, window_ms: float = WINDOW_MS) -> float:
    """Peak over t of |a(t + W) - a(t)| / W of a reconstruction (qc/ms^3)."""
    if not len(recon.start):
        return 0.0
    return float(window_jerk_profile(recon, window_ms)[1].max())


def segments_over(recon: PiecewiseCubic, allowed: float, window_ms: float = WINDOW_MS) -> NDArray[np.int64]:
    """The segments of ``recon`` that a window over ``allowed`` (qc/ms^3) touches, ends included:
    shorter ones there fit the plan's acceleration closer, so their jumps at the records get smaller."""
    t, jerk = window_jerk_profile(recon, window_ms)
    t = t[jerk > allowed * (1.0 + 1e-9)]
    if not len(t):
        return np.zeros(0, dtype=np.int64)
    end = recon.start + recon.duration
    touched = (recon.start[:, None] <= t[None, :] + window_ms) & (end[:, None] >= t[None, :])
    return np.flatnonzero(touched.any(axis=1))
