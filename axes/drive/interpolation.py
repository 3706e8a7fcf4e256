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

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
from numba import njit
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
    """How a drive joins its setpoints: the reconstruction kind, one encoding for every layer (a
    profile says which one its drive makes, ``axes.drive.drive_profile``; the compiled kernels take ``code``)."""

    PVT = "pvt"  # EPOS2: the cubic through each record's position and velocity, over the record's time
    LINEAR = "linear"  # one setpoint per period, joined by straight lines
    CUBIC_PV = "cubic_pv"  # one setpoint and its velocity per period, the cubic through both (Parker -1)
    CUBIC_P = "cubic_p"  # one setpoint per period, the cubic with central velocities (Parker -2)

    @property
    def cubic(self) -> bool:
        """Its segments are cubics (their acceleration is continuous inside a segment)."""
        return self is not Interpolation.LINEAR

    @property
    def code(self) -> int:
        """The kind as the numba kernels take it (planner/knots/fixed_period_kernels.py)."""
        return _KERNEL_CODES[self]


_KERNEL_CODES = {Interpolation.LINEAR: 0, Interpolation.CUBIC_PV: 1, Interpolation.CUBIC_P: 2, Interpolation.PVT: 3}


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
    interpolation: Interpolation = Interpolation.PVT

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
        """Per segment, the largest |velocity| on [0, T] (``cubic_peak_speed``)."""
        shape, flat = _flat(self.c1, self.c2, self.c3, self.duration)
        return _peak_speeds(*flat).reshape(shape)

    def max_abs_acceleration(self) -> NDArray[np.float64]:
        """Per segment, the largest |acceleration|.

        A cubic's acceleration is linear, so its extremum is at an end. A linear interpolator has
        none inside a segment; what the position loop sees is the velocity step at the segment
        start spread over the segment, so that is what is reported (the first segment steps from
        rest).
        """
        if self.interpolation.cubic:
            shape, flat = _flat(self.c2, self.c3, self.duration)
            return _peak_accelerations(*flat).reshape(shape)
        v_prev = np.concatenate(([0.0], self.c1[:-1]))
        return _linear_step_acceleration(v_prev, self.c1, self.duration)

    def position_range(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per segment, exact (min, max) of the position (``cubic_position_range``)."""
        shape, flat = _flat(self.c0, self.c1, self.c2, self.c3, self.duration)
        lo, hi = _position_ranges(*flat)
        return lo.reshape(shape), hi.reshape(shape)

    def sample_times(self, period_ms: float = DRIVE_SAMPLE_MS) -> NDArray[np.float64]:
        """The drive's own sampling instants over the motion (1 kHz from the start SYNC)."""
        n = int(np.floor(self.end_time / period_ms + 1e-9))
        return np.arange(n + 1, dtype=float) * period_ms


# --- the cubic's facts, once ---------------------------------------------------------------------
# Each is a scalar function compiled with numba: the knot placement's kernels call them per segment,
# and the array forms below (what the validator and the tests use) loop over them, so there is one
# implementation of each formula, not a numpy one and a compiled one.
def _hermite(p0: float, v0: float, p1: float, v1: float, T: float) -> tuple[float, float, float, float]:
    dp = p1 - p0
    c2 = (3.0 * dp - (2.0 * v0 + v1) * T) / (T * T)
    c3 = (-2.0 * dp + (v0 + v1) * T) / (T * T * T)
    return p0, v0, c2, c3


hermite = njit(cache=True)(_hermite)  # THE drive cubic: (p0, v0) at tau = 0, (p1, v1) at tau = T


def _linear_segment(p0: float, p1: float, T: float) -> tuple[float, float]:
    return p0, (p1 - p0) / T


linear_segment = njit(cache=True)(_linear_segment)  # a linear interpolator's segment: (c0, c1), c2 = c3 = 0


# Whole-count setpoints put a linear reconstruction's velocity step off the ideal one by up to two
# counts per period: the rounding of the three positions around it (half a count each, the middle
# one twice). What is judged against 0x60C5 is the step beyond that: the part a plan can control.
LINEAR_QUANTIZATION_QC = 2.0


def _linear_step_acceleration(v_prev: float, v: float, T: float) -> float:
    return np.maximum(np.abs(v - v_prev) - LINEAR_QUANTIZATION_QC / T, 0.0) / T  # arrays too


# A linear interpolator has no acceleration inside a segment: what the position loop sees is the
# velocity step at the segment start, spread over the segment, less the rounding of whole counts
# (over any longer span the validator holds the velocity change to 0x60C5 with the same allowance:
# ``linear_span_excess``).
linear_step_acceleration = njit(cache=True)(_linear_step_acceleration)


def linear_span_excess(velocity: NDArray[np.float64], T: float, a_max: float) -> tuple[int, int, float]:
    """The worst span of a linear reconstruction (segment velocities ``velocity``, qc/ms, from rest)
    over which the velocity changes by more than ``a_max`` (qc/ms^2) allows plus the rounding of
    whole counts: (first segment, last segment, excess in qc/ms; <= 0 when every span is inside).

    Over segments k < j: |v_j - v_k| <= a_max (j - k) T + LINEAR_QUANTIZATION_QC / T. With
    f = v - a_max k T that is f_j - min(f_k) and, the other way, max(g_k) - g_j with g = v + a_max k T:
    one pass over the segments."""
    v = np.concatenate(([0.0], np.asarray(velocity, dtype=np.float64)))
    k = np.arange(len(v)) * (a_max * T)
    f, g = v - k, v + k
    low_at = np.minimum.accumulate(f)
    high_at = np.maximum.accumulate(g)
    rise = f - low_at
    fall = high_at - g
    excess = np.maximum(rise, fall) - LINEAR_QUANTIZATION_QC / T
    j = int(np.argmax(excess))
    ref = f[: j + 1] if rise[j] >= fall[j] else -g[: j + 1]
    i = int(np.argmin(ref))
    return max(i - 1, 0), j - 1, float(excess[j])


def _central_velocity(p_prev: float, p_next: float, T: float) -> float:
    return (p_next - p_prev) / (2.0 * T)


# Parker 0x60C0 = -2 has no velocity record: its velocity at a point is the central difference of
# the neighbouring points.
central_velocity = njit(cache=True)(_central_velocity)


@njit(cache=True)
def cubic_peak_speed(c1: float, c2: float, c3: float, T: float) -> float:
    """max |c1 + 2 c2 tau + 3 c3 tau^2| over tau in [0, T]: the ends, or the vertex -c2 / (3 c3)."""
    v_end = c1 + T * (2.0 * c2 + 3.0 * c3 * T)
    best = max(abs(c1), abs(v_end))
    if c3 != 0.0:
        tau = -c2 / (3.0 * c3)
        if tau > 0.0 and tau < T:
            best = max(best, abs(c1 + tau * (2.0 * c2 + 3.0 * c3 * tau)))
    return best


@njit(cache=True)
def cubic_peak_acceleration(c2: float, c3: float, T: float) -> float:
    """A cubic's acceleration is linear: its largest magnitude is at an end."""
    return max(abs(2.0 * c2), abs(2.0 * c2 + 6.0 * c3 * T))


@njit(cache=True)
def cubic_position_range(c0: float, c1: float, c2: float, c3: float, T: float) -> tuple[float, float]:
    """Exact (min, max) of c0 + c1 tau + c2 tau^2 + c3 tau^3 over tau in [0, T]."""
    p_end = c0 + T * (c1 + T * (c2 + T * c3))
    lo, hi = min(c0, p_end), max(c0, p_end)
    # interior stationary points: c1 + 2 c2 tau + 3 c3 tau^2 = 0, in the cancellation-free form (a
    # parabola's c3 is float noise, 1e-18, where (-b + sq) / 2a would lose the root entirely)
    a, b, c = 3.0 * c3, 2.0 * c2, c1
    disc = b * b - 4.0 * a * c
    if not disc >= 0.0:
        return lo, hi
    sq = math.sqrt(disc)
    q = -0.5 * (b + (sq if b >= 0.0 else -sq))
    r1 = q / a if a != 0.0 else (-c / b if b != 0.0 else math.nan)
    r2 = c / q if q != 0.0 else (0.0 if a != 0.0 else math.nan)
    for tau in (r1, r2):
        if math.isfinite(tau) and tau > 0.0 and tau < T:
            p = c0 + tau * (c1 + tau * (c2 + tau * c3))
            lo, hi = min(lo, p), max(hi, p)
    return lo, hi


@njit(cache=True)
def _peak_speeds(
    c1: NDArray[np.float64], c2: NDArray[np.float64], c3: NDArray[np.float64], T: NDArray[np.float64]
) -> NDArray[np.float64]:
    out = np.empty(len(c1))
    for k in range(len(c1)):
        out[k] = cubic_peak_speed(c1[k], c2[k], c3[k], T[k])
    return out


@njit(cache=True)
def _peak_accelerations(
    c2: NDArray[np.float64], c3: NDArray[np.float64], T: NDArray[np.float64]
) -> NDArray[np.float64]:
    out = np.empty(len(c2))
    for k in range(len(c2)):
        out[k] = cubic_peak_acceleration(c2[k], c3[k], T[k])
    return out


@njit(cache=True)
def _position_ranges(
    c0: NDArray[np.float64],
    c1: NDArray[np.float64],
    c2: NDArray[np.float64],
    c3: NDArray[np.float64],
    T: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    lo, hi = np.empty(len(c0)), np.empty(len(c0))
    for k in range(len(c0)):
        lo[k], hi[k] = cubic_position_range(c0[k], c1[k], c2[k], c3[k], T[k])
    return lo, hi


def _flat(*xs: ArrayLike) -> tuple[tuple[int, ...], list[NDArray[np.float64]]]:
    """Broadcast to one shape and flatten (the compiled loops take 1-D float arrays)."""
    arrs = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in xs))
    return arrs[0].shape, [np.ascontiguousarray(a).ravel() for a in arrs]


def hermite_coefficients(
    p0: ArrayLike, v0: ArrayLike, p1: ArrayLike, v1: ArrayLike, T: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Elementwise ``hermite``: the cubic through (p0, v0) at tau = 0 and (p1, v1) at tau = T."""
    p0, v0, p1, v1, T = (np.asarray(x, dtype=float) for x in (p0, v0, p1, v1, T))
    return _hermite(p0, v0, p1, v1, T)  # the same source as ``hermite``, run by numpy on the arrays


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
    if interpolation.cubic:
        assert velocities is not None
        c0, c1, c2, c3 = hermite_coefficients(p0, velocities[:-1], p1, velocities[1:], durations)
    else:
        c0, c1 = _linear_segment(p0.astype(float), p1, durations)
        c2 = np.zeros_like(c0)
        c3 = np.zeros_like(c0)
    return PiecewiseCubic(starts, durations.astype(float), c0, c1, c2, c3, interpolation)


@njit(cache=True)
def epos2_end(rows: NDArray[np.int64], first: int, stop: int) -> int:
    """The row after the last one the EPOS2 interpolates of the records rows[first:stop]: it stops at
    a time-0 record (the end marker) after the first one."""
    for k in range(first + 1, stop):
        if rows[k, 2] == 0:
            return k
    return stop


@njit(cache=True)
def epos2_segment(rows: NDArray[np.int64], first: int, k: int, f: float) -> tuple[float, float, float, float, float]:
    """THE EPOS2 PVT rule (app note 2.3) for segment k of the records starting at row ``first``:
    (p0, v0, p1, v1, T) for ``hermite``. Record k ends a segment of its time (ms) begun at record
    k-1; the first record's segment is its dwell, from the start point at rest. ``f``: qc/ms per
    velocity unit."""
    p1, v1, T = float(rows[k, 0]), rows[k, 1] * f, float(rows[k, 2])
    if k == first:
        return p1, 0.0, p1, v1, T
    return float(rows[k - 1, 0]), rows[k - 1, 1] * f, p1, v1, T


@njit(cache=True)
def _epos2_cubics(rows: NDArray[np.int64], f: float) -> tuple[NDArray[np.float64], ...]:
    n = epos2_end(rows, 0, len(rows))
    start, duration = np.empty(n), np.empty(n)
    c0, c1, c2, c3 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    t = 0.0
    for k in range(n):
        p0, v0, p1, v1, T = epos2_segment(rows, 0, k, f)
        c0[k], c1[k], c2[k], c3[k] = hermite(p0, v0, p1, v1, T)
        start[k], duration[k] = t, T
        t += T
    return start, duration, c0, c1, c2, c3


def epos2_pvt(records: ArrayLike, qc_per_ms_per_velocity_unit: float) -> PiecewiseCubic:
    """EPOS2 cubic PVT (app note 2.3) of a program's records [position_qc, velocity, time_ms]:
    ``epos2_segment`` for every record up to the end marker (``epos2_end``)."""
    r = np.ascontiguousarray(records, dtype=np.int64)
    if r.ndim != 2 or r.shape[1] != 3 or len(r) < 2:
        raise ValueError("records must be an (N >= 2, 3) array of [position_qc, velocity, time_ms]")
    return PiecewiseCubic(*_epos2_cubics(r, float(qc_per_ms_per_velocity_unit)), Interpolation.PVT)


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
    return _segments_from_points(positions, velocities, durations, 0.0, Interpolation.CUBIC_PV)


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
    velocities[1:] = _central_velocity(padded[:-2], padded[2:], period_ms)
    velocities[-1] = 0.0
    durations = np.full(len(r), float(period_ms))
    return _segments_from_points(positions, velocities, durations, period_ms, Interpolation.CUBIC_P)


def reconstruct(
    kind: Interpolation, records: ArrayLike, period_ms: float, qc_per_ms_per_velocity_unit: float
) -> PiecewiseCubic:
    """The reconstruction ``kind`` of a program's records (``period_ms``: the fixed period; unused by PVT)."""
    if kind is Interpolation.PVT:
        return epos2_pvt(records, qc_per_ms_per_velocity_unit)
    if kind is Interpolation.CUBIC_PV:
        return cubic_pv(records, period_ms, qc_per_ms_per_velocity_unit)
    if kind is Interpolation.CUBIC_P:
        return cubic_p(records, period_ms)
    return linear(records, period_ms)
