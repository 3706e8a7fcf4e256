"""The plan's samples to drive units in one compiled pass (``planner.knots.samples.sample_trajectory``):
each conversion is affine per axis, and three numpy passes over every ms of every axis cost more
than the arithmetic."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

_F = NDArray[np.float64]


@njit(cache=True)
def to_drive_units(q: _F, qd: _F, pos_0: _F, pos_1: _F, vel: _F) -> None:
    """In place, per axis i (row): q <- q (pos_1 - pos_0) + pos_0 (qc), qd <- qd vel (qc/ms), the
    velocity at rest at both ends. The same operations, in the same order, as
    ``q *= (pos_1 - pos_0)[:, None]; q += pos_0[:, None]; qd *= vel[:, None]``."""
    for i in range(q.shape[0]):
        k, off, g = pos_1[i] - pos_0[i], pos_0[i], vel[i]
        for j in range(q.shape[1]):
            q[i, j] = q[i, j] * k + off
            qd[i, j] = qd[i, j] * g
        qd[i, 0] = 0.0
        qd[i, q.shape[1] - 1] = 0.0
