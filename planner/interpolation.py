"""What a drive makes of the records it is given: the drive-side reconstructions.

This is the single implementation of every drive's interpolation. The validator, the knot
placement, the simulated drives and the tests all call it, so that "what the drive will execute"
means one thing everywhere.

All reconstructions work in drive-internal units: qc, qc/ms, qc/ms^2 and ms. A reconstruction is
a piecewise cubic in absolute time from the start SYNC (t = 0).

The EPOS2 note's printed coefficients (app note 2.3) do not reproduce the segment's start point
for its own sign convention; the Hermite cubic below is derived directly from the four end
conditions p(0) = P0, p'(0) = V0, p(T) = P1, p'(T) = V1.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

DRIVE_SAMPLE_MS = 1.0  # the EPOS2 (and the simulated drives) interpolate at 1 kHz

# A value within this relative distance of a limit is AT the limit, not over it: float round-off of
# the same exact cubic must not make the validator pass what the (simulated) drive faults on, or the
# other way round. Both sides of the bus judge a limit with exceeds().
LIMIT_RTOL = 1e-9


def exceeds(value: ArrayLike, limit: ArrayLike) -> NDArray[np.bool_]:
    """value > limit, with the shared round-off allowance LIMIT_RTOL."""
    return np.asarray(value) > np.asarray(limit) * (1.0 + LIMIT_RTOL)


class Interpolation(Enum):
    """How the drive joins its setpoints."""

    CUBIC = "cubic"
    LINEAR = "linear"
    STEP = "step"


@dataclass(frozen=True)
class PiecewiseCubic:
    """Segments p_k(tau) = c0 + c1 tau + c2 tau^2 + c3 tau^3 for tau in [0, T_k], back to back.

    ``start[k]`` is the absolute start time of segment k in ms. Before the first segment and after
    the last one the position holds (at c0[0] and at the end point, respectively).
    """

    start: NDArray[np.float64]
    duration: NDArray[np.float64]
    c0: NDArray[np.float64]
    c1: NDArray[np.float64]
    c2: NDArray[np.float64]
    c3: NDArray[np.float64]
    interpolation: Interpolation = Interpolation.CUBIC

    @property
    def end_time(self) -> float:
        return float(self.start[-1] + self.duration[-1]) if len(self.start) else 0.0

    @property
    def end_position(self) -> float:
        T = self.duration[-1]
        return float(self.c0[-1] + T * (self.c1[-1] + T * (self.c2[-1] + T * self.c3[-1])))

    def _locate(self, t: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, len(self.start) - 1)
        tau = np.clip(t - self.start[k], 0.0, self.duration[k])
        moving = (t >= self.start[0]) & (t <= self.end_time)
        return k, tau, moving

    def position(self, t: ArrayLike) -> NDArray[np.float64]:
        k, tau, _ = self._locate(t)
        return self.c0[k] + tau * (self.c1[k] + tau * (self.c2[k] + tau * self.c3[k]))

    def velocity(self, t: ArrayLike) -> NDArray[np.float64]:
        k, tau, moving = self._locate(t)
        return np.where(moving, self.c1[k] + tau * (2.0 * self.c2[k] + 3.0 * tau * self.c3[k]), 0.0)

    def acceleration(self, t: ArrayLike) -> NDArray[np.float64]:
        k, tau, moving = self._locate(t)
        return np.where(moving, 2.0 * self.c2[k] + 6.0 * self.c3[k] * tau, 0.0)

    # --- exact extrema per segment ---------------------------------------------------------------
    def max_abs_velocity(self) -> NDArray[np.float64]:
        """Per segment, the largest |velocity| on [0, T] (closed form: ends or the vertex)."""
        return max_abs_cubic_velocity(self.c1, self.c2, self.c3, self.duration)

    def max_abs_acceleration(self) -> NDArray[np.float64]:
        """Per segment, the largest |acceleration|.

        A cubic's acceleration is linear, so its extremum is at an end. A linear interpolator has
        none inside a segment; what the position loop sees is the velocity step at the segment
        start spread over the segment, so that is what is reported (the first segment steps from
        rest).
        """
        if self.interpolation is Interpolation.CUBIC:
            T = self.duration
            return np.maximum(np.abs(2.0 * self.c2), np.abs(2.0 * self.c2 + 6.0 * self.c3 * T))
        v_prev = np.concatenate(([0.0], self.c1[:-1]))
        return np.abs(self.c1 - v_prev) / self.duration

    def position_range(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per segment, exact (min, max) of the position."""
        T = self.duration
        p_end = self.c0 + T * (self.c1 + T * (self.c2 + T * self.c3))
        lo = np.minimum(self.c0, p_end)
        hi = np.maximum(self.c0, p_end)
        # interior stationary points: c1 + 2 c2 tau + 3 c3 tau^2 = 0
        for tau in _velocity_roots(self.c1, self.c2, self.c3):
            inside = np.isfinite(tau) & (tau > 0.0) & (tau < T)
            tt = np.where(inside, tau, 0.0)
            p = self.c0 + tt * (self.c1 + tt * (self.c2 + tt * self.c3))
            lo = np.where(inside, np.minimum(lo, p), lo)
            hi = np.where(inside, np.maximum(hi, p), hi)
        return lo, hi

    def sample_times(self, period_ms: float = DRIVE_SAMPLE_MS) -> NDArray[np.float64]:
        """The drive's own sampling instants over the motion (1 kHz from the start SYNC)."""
        n = int(np.floor(self.end_time / period_ms + 1e-9))
        return np.arange(n + 1, dtype=float) * period_ms


def _velocity_roots(
    c1: NDArray[np.float64], c2: NDArray[np.float64], c3: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Both roots of c1 + 2 c2 tau + 3 c3 tau^2 (NaN where there is none)."""
    a, b, c = 3.0 * c3, 2.0 * c2, c1
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        disc = b * b - 4.0 * a * c
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        # the cancellation-free form: a parabola's c3 is float noise (1e-18), where (-b + sq) / 2a
        # would lose the root entirely
        q = -0.5 * (b + np.where(b >= 0.0, sq, -sq))
        r1 = np.where(a != 0.0, q / a, np.where(b != 0.0, -c / b, np.nan))
        r2 = np.where(q != 0.0, c / q, np.where(a != 0.0, 0.0, np.nan))
    return r1, r2


def max_abs_cubic_velocity(
    c1: NDArray[np.float64], c2: NDArray[np.float64], c3: NDArray[np.float64], T: NDArray[np.float64]
) -> NDArray[np.float64]:
    """max |c1 + 2 c2 tau + 3 c3 tau^2| over tau in [0, T]: the ends, or the vertex -c2 / (3 c3)."""
    v_end = c1 + T * (2.0 * c2 + 3.0 * c3 * T)
    best = np.maximum(np.abs(c1), np.abs(v_end))
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(c3 != 0.0, -c2 / (3.0 * c3), np.nan)
    inside = np.isfinite(tau) & (tau > 0.0) & (tau < T)
    tt = np.where(inside, tau, 0.0)
    v_vertex = c1 + tt * (2.0 * c2 + 3.0 * c3 * tt)
    return np.where(inside, np.maximum(best, np.abs(v_vertex)), best)


def hermite_coefficients(
    p0: ArrayLike, v0: ArrayLike, p1: ArrayLike, v1: ArrayLike, T: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The cubic through (p0, v0) at tau = 0 and (p1, v1) at tau = T: THE drive cubic formula."""
    p0, v0, p1, v1, T = (np.asarray(x, dtype=float) for x in (p0, v0, p1, v1, T))
    dp = p1 - p0
    c2 = (3.0 * dp - (2.0 * v0 + v1) * T) / (T * T)
    c3 = (-2.0 * dp + (v0 + v1) * T) / (T * T * T)
    return p0, v0, c2, c3


def _segments_from_points(
    positions: NDArray[np.float64],
    velocities: NDArray[np.float64] | None,
    durations: NDArray[np.float64],
    first_start: float,
    interpolation: Interpolation,
) -> PiecewiseCubic:
    """Segments joining point k-1 to point k over durations[k-1], starting at ``first_start``."""
    p0, p1 = positions[:-1], positions[1:]
    starts = first_start + np.concatenate(([0.0], np.cumsum(durations)[:-1]))
    if interpolation is Interpolation.CUBIC:
        assert velocities is not None
        c0, c1, c2, c3 = hermite_coefficients(p0, velocities[:-1], p1, velocities[1:], durations)
    else:
        c0 = p0.astype(float)
        c1 = (p1 - p0) / durations
        c2 = np.zeros_like(c0)
        c3 = np.zeros_like(c0)
    return PiecewiseCubic(starts, durations.astype(float), c0, c1, c2, c3, interpolation)


def epos2_pvt(records: ArrayLike, qc_per_ms_per_velocity_unit: float) -> PiecewiseCubic:
    """EPOS2 cubic PVT (app note 2.3) of a program's records [position_qc, velocity, time_ms].

    records[0] is the start point at rest: its time is a dwell from the start SYNC. Record k ends a
    segment of records[k].time ms begun at record k-1. Interpolation stops at a time-0 record.
    """
    r = np.asarray(records, dtype=np.int64)
    if r.ndim != 2 or r.shape[1] != 3 or len(r) < 2:
        raise ValueError("records must be an (N >= 2, 3) array of [position_qc, velocity, time_ms]")
    times = r[:, 2]
    zero = np.flatnonzero(times[1:] == 0)
    n = zero[0] + 1 if len(zero) else len(r)  # records up to (excluding) the end marker
    positions = np.concatenate(([r[0, 0]], r[:n, 0])).astype(float)
    velocities = np.concatenate(([0.0], r[:n, 1] * qc_per_ms_per_velocity_unit))
    durations = times[:n].astype(float)
    return _segments_from_points(positions, velocities, durations, 0.0, Interpolation.CUBIC)


def _fixed_period(records: ArrayLike) -> NDArray[np.int64]:
    r = np.asarray(records, dtype=np.int64)
    if r.ndim != 2 or r.shape[1] != 3 or len(r) < 1:
        raise ValueError("records must be an (N >= 1, 3) array of [position_qc, velocity, time_ms]")
    return r


def linear(records: ArrayLike, period_ms: float) -> PiecewiseCubic:
    """A linear interpolator with one setpoint per period (CiA 402 linear IP, sync_setpoint,
    Parker 0x60C0 = 0): record k is reached at (k + 1) periods, on the program's timeline.

    The fixed-period drives reach a setpoint one or two periods after the SYNC that validated it
    (``delay_periods`` of their profile); the feeder sends that many periods ahead, so on the
    program's timeline the reconstruction is the same for all of them.
    """
    r = _fixed_period(records)
    positions = np.concatenate(([r[0, 0]], r[:, 0])).astype(float)
    durations = np.full(len(r), float(period_ms))
    return _segments_from_points(positions, None, durations, 0.0, Interpolation.LINEAR)


def cubic_pv(records: ArrayLike, period_ms: float, qc_per_ms_per_velocity_unit: float) -> PiecewiseCubic:
    """Parker SLVDN mode 202, 0x60C0 = -1: cubic through position + velocity (one cycle of delay)."""
    r = _fixed_period(records)
    positions = np.concatenate(([r[0, 0]], r[:, 0])).astype(float)
    velocities = np.concatenate(([0.0], r[:, 1] * qc_per_ms_per_velocity_unit))
    durations = np.full(len(r), float(period_ms))
    return _segments_from_points(positions, velocities, durations, 0.0, Interpolation.CUBIC)


def cubic_p(records: ArrayLike, period_ms: float) -> PiecewiseCubic:
    """Parker SLVDN mode 202, 0x60C0 = -2: cubic through positions only (two cycles of delay).

    The drive has no velocity, so it needs the following point to form one: the velocity at point
    k is the central difference (P[k+1] - P[k-1]) / 2T, at rest at both ends. That is why it lags
    one cycle more than the other submodes.
    """
    r = _fixed_period(records)
    positions = np.concatenate(([r[0, 0]], r[:, 0])).astype(float)
    padded = np.concatenate((positions, [positions[-1]]))
    velocities = np.empty_like(positions)
    velocities[0] = 0.0
    velocities[1:] = (padded[2:] - padded[:-2]) / (2.0 * period_ms)
    velocities[-1] = 0.0
    durations = np.full(len(r), float(period_ms))
    return _segments_from_points(positions, velocities, durations, period_ms, Interpolation.CUBIC)
