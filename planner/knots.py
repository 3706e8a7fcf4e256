"""PVT knot placement: from a timed trajectory to integer records the drive executes as they are.

The drive does not execute the planner's curve: it rebuilds the motion from the records with its
own interpolation (axes.interpolation), from integer ms, integer velocity units and integer
counts, and faults where that rebuild exceeds 0x607F or 0x60C5. So every candidate program is
judged here by that very reconstruction of its *quantized* records, exactly (closed-form extrema
per segment), never by the planned curve.

EPOS2 PVT (``epos2_pvt``), per axis (the axes share only the start SYNC and the end time):

1. knots at whole ms where the axis's acceleration jumps (the time-optimal profile switches
   there; a cubic across a switch overshoots), at least ``min_switch_gap_ms`` apart;
2. adaptive refinement: segments are halved while the least-squares cubics (a banded linear
   system over the knot positions and velocities, fitted to the plan at every drive ms) stray
   more than ``fit_fraction * tolerance_qc`` from the plan, or are longer than 255 ms;
3. quantization: positions to counts (inside 0x607D), velocities to the drive's unit; where that
   pushes a cubic over a limit, the records around it are re-rounded together: each may move by
   a count and two velocity units, and the best combination of a whole run is found exactly (a
   shortest path over the candidates, ``knot_kernels.repair_chains``). Integers need an integer
   search: a velocity QP (casadi/daqp) used to follow the nudges here, and a continuous optimum
   is only as good as its rounding (121 of its 122 feasible solutions were over a limit again once
   rounded); after this search came in, dropping the QP changed no program on 300 bench paths,
   and a QP held back by its rounding's reach was infeasible in all 59 calls on 800;
4. the exact reconstruction of the quantized records is checked: a segment that strays more than
   the tolerance, or stays over a limit, is split and steps 3-4 are redone. Splitting for a limit
   stops on an axis whose segments over a limit do not get fewer (more of the same costs time,
   not excess), and each axis keeps the records of its round that needed the least slow-down
   (shorter segments feel rounding more: a split can make the excess worse). Where that still
   exceeds a limit, the knots around the segments over it may move by a ms in the same exact
   search: a T-ms cubic's end accelerations are integer combinations of 6/T^2 (a count) and
   2f/T (a velocity unit), a lattice whose step at T = 16 ms is 0.05 % of arm6 joint_1's 0x60C5,
   and at a time-optimal limit the nearest point below it can be out of a nudge's reach; a
   cubic of another length has another lattice. After that, cubics through the exact samples
   (more records, more room) are tried as well, and the better is kept;
5. where the quantized reconstruction still exceeds 0x607F/0x60C5 (rounding at the limit costs a
   few tenths of a percent), the whole motion is slowed down by the smallest factor the excess
   calls for and the knots are placed again (from the previous ones, stretched). No blanket
   margin: a motion that fits is not slowed at all.

All EPOS2 axes are placed together, as one flat problem (their samples end to end), so that each
step is one set of array operations for all of them. The axes' blocks are independent: an axis
gets the records it would get alone, and leaves as soon as it is done. Work that repeats is not
redone: the check evaluates only the segments whose cubic changed, the least-squares fit reuses
the right-hand side of every unchanged segment and re-evaluates a segment's fit only where its
verdict could change.

Fixed-period profiles take one record per period and are checked by their own reconstruction
(linear, or Parker's cubic submodes) the same way. All numbers here are in drive units: qc,
velocity units (qc/ms inside the interpolation), ms.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from axes.interpolation import LIMIT_RTOL, PiecewiseCubic, exceeds, hermite_coefficients
from axes.objects import PARKER_CUBIC_THRESHOLD_US
from axes.program import FIXED_PERIOD_PROFILES, PROFILES, TIME_MAX_MS, AxisProgram
from axes.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from planner import knot_kernels as kernels


class TimedTrajectory(Protocol):
    """What knot placement needs of a trajectory (planner.timing.Trajectory): seconds, joint units."""

    @property
    def duration(self) -> float: ...

    @property
    def breakpoints(self) -> NDArray[np.float64]: ...

    def states(self, t: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...  # q, q' (dof, len(t))

    def acceleration_jumps(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...  # times, (n, dof)


class KnotError(ValueError):
    """No program within the options meets the drive's limits (e.g. more slow-down than allowed)."""


@dataclass(frozen=True)
class DriveAxis:
    """One axis as knot placement sees it: its drive's profile, scaling and limit objects."""

    name: str
    node_id: int
    profile: str
    scaling: AxisScaling
    limits: DriveLimits
    period_ms: int | None = None  # fixed-period profiles
    interpolation_submode: int | None = None  # parker_slvdn 0x60C0

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ValueError(f"unknown profile {self.profile!r}")
        if self.profile in FIXED_PERIOD_PROFILES and not (self.period_ms and 1 <= self.period_ms <= TIME_MAX_MS):
            raise ValueError(f"{self.name}: a {self.profile} axis needs a period of 1..255 ms, got {self.period_ms}")

    @classmethod
    def from_config(cls, axis: Any) -> DriveAxis:
        """From a cell's axis configuration (service.config.AxisConfig, read by attribute)."""
        return cls(
            axis.joint,
            axis.node_id,
            axis.profile,
            axis.scaling,
            axis.limits,
            axis.period_ms,
            axis.interpolation_submode,
        )

    def program(self, records: NDArray[np.int64]) -> AxisProgram:
        return AxisProgram(
            self.name, self.node_id, self.profile, self.scaling, self.limits, records, self.interpolation_submode
        )


@dataclass(frozen=True)
class KnotOptions:
    tolerance_qc: float = 1.0  # max |reconstruction - plan| at the drive's 1 kHz samples
    fit_fraction: float = 0.6  # refinement target for the exact-sample cubic, fraction of the tolerance
    switch_fraction: float = 0.02  # an acceleration jump above this fraction of 0x60C5 gets its own knot
    min_switch_gap_ms: int = 8  # switch knots closer than this are merged (short segments amplify rounding)
    dwell_ms: int = 1  # time of records[0]: the wait from the start SYNC to the first segment
    max_time_scale: float = 1.05  # give up rather than slow the motion down more than this ...
    max_extra_ms: int = 50  # ... unless that is less than this much time (a short move's whole ms cost more)
    max_rounds: int = 10  # slow-down rounds
    max_splits: int = 40  # refinement rounds per axis

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance_qc) and self.tolerance_qc >= 0.5):
            raise ValueError(f"tolerance_qc must be >= 0.5 count (positions are integers), got {self.tolerance_qc}")
        if not 1 <= self.dwell_ms <= TIME_MAX_MS:
            raise ValueError(f"dwell_ms must be in 1..255, got {self.dwell_ms}")


@dataclass(frozen=True)
class AxisKnots:
    """The records of one axis and what their reconstruction does."""

    name: str
    records: NDArray[np.int64]
    deviation_qc: float  # worst |reconstruction - plan| at 1 kHz
    velocity_ratio: float  # exact max |v| / 0x607F of the reconstruction
    acceleration_ratio: float  # exact max |a| / 0x60C5


@dataclass(frozen=True)
class KnotResult:
    axes: tuple[AxisKnots, ...]
    time_scale: float  # slow-down applied to the trajectory (1.0: none)
    duration_ms: int  # motion time of the program (without the start dwell)
    rounds: int

    @property
    def deviation_qc(self) -> float:
        return max((a.deviation_qc for a in self.axes), default=0.0)


# --- sampling ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Samples:
    """The (slowed) trajectory in drive units at every ms, and its acceleration jumps."""

    scale: float
    n_ms: int  # last sample index: samples at 0..n_ms ms
    position: NDArray[np.float64]  # (dof, n_ms + 1) qc
    velocity: NDArray[np.float64]  # (dof, n_ms + 1) qc/ms
    switch_ms: NDArray[np.float64]  # breakpoint times (ms)
    jump: NDArray[np.float64]  # (len(switch_ms), dof) |acceleration jump| qc/ms^2


def _read_only(*arrays: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
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
    return _read_only(pos_0.copy(), pos_1.copy(), vel_1, acc_1)


def _sample(traj: TimedTrajectory, axes: Sequence[DriveAxis], scale: float) -> _Samples:
    duration_ms = traj.duration * 1000.0 * scale
    n = max(1, math.ceil(duration_ms - 1e-6))
    q, qd = traj.states(np.arange(n + 1) / (1000.0 * scale))  # trajectory time of each drive ms
    switch_s, jump_joint = traj.acceleration_jumps()
    pos_0, pos_1, vel_1, acc_1 = _unit_conversions(tuple(axes))
    q *= (pos_1 - pos_0)[:, None]
    q += pos_0[:, None]
    qd *= (vel_1 / scale)[:, None]
    qd[:, 0] = 0.0
    qd[:, -1] = 0.0
    return _Samples(scale, n, q, qd, switch_s * 1000.0 * scale, jump_joint * (np.abs(acc_1) / (scale * scale)))


# --- checks shared by every profile --------------------------------------------------------------------
@dataclass(frozen=True)
class _Check:
    seg_deviation: NDArray[np.float64]  # per reconstruction segment, worst |recon - plan| (qc)
    velocity_ratio: NDArray[np.float64]  # per segment, exact max |v| / 0x607F
    acceleration_ratio: NDArray[np.float64]
    position_out: NDArray[np.bool_]  # per segment: leaves 0x607D

    @property
    def deviation(self) -> float:
        return float(self.seg_deviation.max()) if len(self.seg_deviation) else 0.0


def _check(axis: DriveAxis, records: NDArray[np.int64], plan_qc: NDArray[np.float64]) -> tuple[_Check, PiecewiseCubic]:
    """The exact reconstruction of ``records`` against the limits and the plan.

    The plan's sample j (ms) is compared with the reconstruction at the time the drive reaches it:
    j plus the time at which records[0] is reached (the dwell, or the fixed-period delay). Every
    record time is a whole ms, so the samples of each segment are a contiguous run found by
    arithmetic (no search), and the position range is solved exactly only on the segments whose
    cheap bound (the Hermite cubic stays within T (|V0| + |V1|) 4/27 of its end points) reaches
    0x607D.
    """
    recon = axis.program(records).reconstruction()
    s = axis.scaling
    lim = axis.limits
    v = np.asarray(s.qc_per_ms_to_rpm(recon.max_abs_velocity())) / lim.max_profile_velocity_rpm
    a = np.asarray(s.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration())) / lim.max_acceleration_rpm_s
    T = recon.duration
    p_end = recon.c0 + T * (recon.c1 + T * (recon.c2 + T * recon.c3))
    reach = T * (np.abs(recon.c1) + np.abs(recon.c1 + T * (2.0 * recon.c2 + 3.0 * T * recon.c3))) * (4.0 / 27.0)
    near = (np.minimum(recon.c0, p_end) - reach < lim.min_position_qc) | (
        np.maximum(recon.c0, p_end) + reach > lim.max_position_qc
    )
    out = np.zeros(len(T), dtype=bool)
    if near.any():
        m = np.flatnonzero(near)
        part = PiecewiseCubic(
            recon.start[m], T[m], recon.c0[m], recon.c1[m], recon.c2[m], recon.c3[m], recon.interpolation
        )
        lo, hi = part.position_range()
        out[m] = (lo < lim.min_position_qc) | (hi > lim.max_position_qc)
    shift = float(recon.start[0] + recon.duration[0])
    n_t = len(plan_qc)
    # sample j sits at t = j + shift; segment k holds the samples from the first t >= start[k]
    first = np.clip(np.ceil(recon.start - shift - 1e-9), 0, n_t).astype(np.int64)
    k = np.repeat(np.arange(len(first)), np.diff(np.append(first, n_t)))
    first = np.minimum(first, n_t - 1)
    tau = np.clip(np.arange(n_t) + shift - recon.start[k], 0.0, T[k])
    pos = recon.c0[k] + tau * (recon.c1[k] + tau * (recon.c2[k] + tau * recon.c3[k]))
    err = np.abs(pos - plan_qc)
    seg_dev = np.maximum.reduceat(err, first)
    empty = np.append(first[1:] <= first[:-1], False) | (recon.start > n_t - 1 + shift)
    seg_dev[empty] = 0.0
    return _Check(seg_dev, v, a, out), recon


def _round_positions(p: NDArray[np.float64], axis: DriveAxis) -> NDArray[np.int64]:
    lim = axis.limits
    r = np.rint(p)
    if np.any(r < INT32_MIN) or np.any(r > INT32_MAX):
        raise KnotError(f"{axis.name}: the motion leaves the int32 position range of a record")
    return np.clip(r, lim.min_position_qc, lim.max_position_qc).astype(np.int64)


def _round_velocities(v_qc_per_ms: NDArray[np.float64], axis: DriveAxis) -> NDArray[np.int64]:
    s = axis.scaling
    v_max = math.floor(axis.limits.max_profile_velocity_rpm / s.velocity_unit_rpm + 1e-9)  # 0x607F in units
    v = np.clip(np.rint(v_qc_per_ms / s.qc_per_ms_per_velocity_unit), -v_max, v_max)
    if np.any(v < INT24_MIN) or np.any(v > INT24_MAX):
        raise KnotError(f"{axis.name}: a velocity does not fit the int24 of a record (velocity unit too fine?)")
    return v.astype(np.int64)


# --- EPOS2 PVT ---------------------------------------------------------------------------------------
def _switch_knots(
    switch_ms: NDArray[np.float64], jump: NDArray[np.float64], threshold: float, n_ms: int, min_gap: int
) -> NDArray[np.int64]:
    """Integer ms at the significant acceleration switches, largest jumps first, min_gap apart."""
    return kernels.switch_knots(np.ascontiguousarray(switch_ms), np.ascontiguousarray(jump), threshold, n_ms, min_gap)


def _split(knots: NDArray[np.int64], segments: NDArray[np.int64]) -> NDArray[np.int64]:
    """Halve the given knot segments (sorted, unique; those of 1 ms cannot be split and are left alone)."""
    lo, hi = knots[segments], knots[segments + 1]
    ok = hi - lo >= 2
    return np.insert(knots, segments[ok] + 1, (lo[ok] + hi[ok]) // 2)  # each inside its segment: still sorted


_COARSE = 4.0  # first cut: exact-sample cubics to this multiple of the fit target (cheap), then least squares
_MIN_SPLIT_MS = 12  # segments shorter than twice this are not split for a limit (rounding grows as 1/T^2)
_FIT_PROBES = np.arange(1, 8) / 8.0  # where a candidate segment's fit is judged
_REPAIR_REACH = 2  # knots on either side of a segment over a limit whose records the repair may move
_MAX_SHIFT_MS = 3  # how far the last try before a slow-down may move a knot


def _refine(
    knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64], target: float, max_rounds: int
) -> NDArray[np.int64]:
    """Split segments until the cubic through the exact samples stays within ``target`` of the plan.

    The fit is judged at seven whole-ms probes per segment (a cheap first cut: the exact
    reconstruction is checked at every ms afterwards and splits what this misses), by
    ``knot_kernels.refine``. Only the segments made by the last split are judged again.
    """
    return kernels.refine(knots, p, v, _FIT_PROBES, target, max_rounds, TIME_MAX_MS)


def _hermite_basis(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """(4, 4, n): for each segment, the cubic's coefficients c0..c3 (axis 1) per unit end condition
    P0, V0, P1, V1 (axis 0): the drive's cubic is linear in its end conditions."""
    eye = np.eye(4)
    return np.array([np.array(hermite_coefficients(*(np.full_like(T, e) for e in row), T)) for row in eye])


class _BasisTable:
    """The four basis cubics of every segment length 1..255 ms at its whole-ms samples, and their
    Gram matrices: the least-squares fit then gathers instead of evaluating polynomials."""

    def __init__(self, t_max: int = TIME_MAX_MS) -> None:
        T = np.arange(1, t_max + 1)
        self.offset = np.concatenate(([0, 0], np.cumsum(T)))  # offset[T]: first sample of length T
        lengths = np.repeat(T, T)
        tau = np.arange(len(lengths)) - np.repeat(self.offset[1:-1], T)
        c = _hermite_basis(lengths.astype(float))
        self.values = c[:, 0] + tau * (c[:, 1] + tau * (c[:, 2] + tau * c[:, 3]))  # (4, samples)
        gram = np.einsum("as,cs->sac", self.values, self.values)
        self.gram = np.concatenate((np.zeros((1, 4, 4)), np.add.reduceat(gram, self.offset[1:-1], axis=0)))


_BASIS: _BasisTable | None = None


def _basis_table() -> _BasisTable:
    global _BASIS
    if _BASIS is None:
        _BASIS = _BasisTable()
    return _BASIS


@functools.lru_cache(maxsize=64)
def _axis_constants(axes: tuple[DriveAxis, ...]) -> tuple[NDArray[np.float64], ...]:
    """The per-axis constants of ``_Flat`` (f, amax, vmax, v_units, pos_lo, pos_hi, rv_per, ra_per),
    once per set of axes."""
    sc = [a.scaling for a in axes]
    lim = [a.limits for a in axes]
    pairs = list(zip(sc, lim, strict=True))
    return _read_only(
        np.array([s.qc_per_ms_per_velocity_unit for s in sc]),
        np.array([float(s.rpm_s_to_qc_per_ms2(m.max_acceleration_rpm_s)) for s, m in pairs]),
        np.array([float(s.rpm_to_qc_per_ms(m.max_profile_velocity_rpm)) for s, m in pairs]),
        np.array([math.floor(m.max_profile_velocity_rpm / s.velocity_unit_rpm + 1e-9) for s, m in pairs], dtype=float),
        np.array([float(m.min_position_qc) for m in lim]),
        np.array([float(m.max_position_qc) for m in lim]),
        np.array([float(s.qc_per_ms_to_rpm(1.0)) / m.max_profile_velocity_rpm for s, m in pairs]),
        np.array([float(s.qc_per_ms2_to_rpm_s(1.0)) / m.max_acceleration_rpm_s for s, m in pairs]),
    )


@dataclass(frozen=True)
class _Flat:
    """Several EPOS2 axes placed as one: their plan samples end to end (axis a's ms j at flat index
    a * stride + j) and their knots in that index, so that every step below is one set of array
    operations for all axes (the axes are independent: numpy's fixed cost per call is paid once,
    not once per axis). Consecutive knots of one axis bound a segment; the step from an axis's last
    knot to the next axis's first is none (``_real`` is False there, it is never split, fitted,
    checked or repaired). Per-axis constants are arrays indexed by the axis number."""

    axes: tuple[DriveAxis, ...]
    stride: int  # samples per axis: n_ms + 1
    p: NDArray[np.float64]  # plan positions (qc), flat
    v: NDArray[np.float64]  # plan velocities (qc/ms), flat
    f: NDArray[np.float64]  # qc/ms per velocity unit
    amax: NDArray[np.float64]  # 0x60C5 in qc/ms^2
    vmax: NDArray[np.float64]  # 0x607F in qc/ms
    v_units: NDArray[np.float64]  # 0x607F in whole velocity units
    pos_lo: NDArray[np.float64]  # 0x607D
    pos_hi: NDArray[np.float64]
    rv_per: NDArray[np.float64]  # |v| / 0x607F per qc/ms
    ra_per: NDArray[np.float64]  # |a| / 0x60C5 per qc/ms^2
    ids: NDArray[np.int64]  # each axis's place in the first _Flat (stays when others leave: ``subset``)

    @classmethod
    def of(cls, axes: Sequence[DriveAxis], cols: Sequence[int], smp: _Samples) -> _Flat:
        return cls(
            tuple(axes),
            smp.n_ms + 1,
            smp.position[list(cols)].ravel(),
            smp.velocity[list(cols)].ravel(),
            *_axis_constants(tuple(axes)),
            np.arange(len(axes)),
        )

    def subset(self, keep: NDArray[np.int64]) -> _Flat:
        """The axes ``keep`` (positions in this one) alone; ``moved_knots`` maps knots across."""
        m = len(self.axes)
        return _Flat(
            tuple(self.axes[a] for a in keep),
            self.stride,
            self.p.reshape(m, self.stride)[keep].ravel(),
            self.v.reshape(m, self.stride)[keep].ravel(),
            self.f[keep],
            self.amax[keep],
            self.vmax[keep],
            self.v_units[keep],
            self.pos_lo[keep],
            self.pos_hi[keep],
            self.rv_per[keep],
            self.ra_per[keep],
            self.ids[keep],
        )

    def moved_knots(
        self, keep: NDArray[np.int64], knots: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """For knots of this one: (the indices of those on the axes ``keep``, where they are in
        ``subset(keep)``)."""
        new_pos = np.full(len(self.axes), -1)
        new_pos[keep] = np.arange(len(keep))
        ax = self.axis_of(knots)
        sel = np.flatnonzero(new_pos[ax] >= 0)
        return sel, knots[sel] + (new_pos[ax[sel]] - ax[sel]) * self.stride

    def axis_of(self, idx: NDArray[np.int64]) -> NDArray[np.int64]:
        return idx // self.stride

    def is_end(self, knots: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Knots at an axis's start or goal: at rest, at the plan's position, never moved."""
        r = knots % self.stride
        return (r == 0) | (r == self.stride - 1)

    def flat_knots(self, per_axis: Sequence[NDArray[np.int64]]) -> NDArray[np.int64]:
        """Each axis's knots (sorted, unique; both ends added, no segment over 255 ms) laid end to end."""
        n = self.stride - 1
        parts = []
        for a, k in enumerate(per_axis):
            base = a * self.stride
            parts += [[base], k[(k > 0) & (k < n)] + base, [base + n]]
        # the step from an axis's end to the next one's start is 1: only real segments are split
        return _within_record_time(np.concatenate(parts).astype(np.int64))


def _within_record_time(knots: NDArray[np.int64]) -> NDArray[np.int64]:
    """Sorted knots with every gap longer than a record's 255 ms split evenly."""
    gaps = np.diff(knots)
    long = np.flatnonzero(gaps > TIME_MAX_MS)
    if not len(long):
        return knots
    pieces = -(-gaps[long] // TIME_MAX_MS)
    at = np.repeat(long, pieces - 1)  # the gap each new knot splits
    n = np.repeat(pieces, pieces - 1)
    j = np.arange(len(at)) - np.repeat(np.cumsum(pieces - 1) - (pieces - 1), pieces - 1) + 1  # 1 .. n - 1
    return np.union1d(knots, knots[at] + (gaps[at] * j) // n)


def _real(fl: _Flat, knots: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per knot segment: both ends on the same axis (a segment, not the step between two axes)."""
    return fl.axis_of(knots[:-1]) == fl.axis_of(knots[1:])


@dataclass(frozen=True)
class _Fitted:
    """A least-squares fit with what the next one can reuse: each segment's right-hand side (its
    basis cubics against the plan) and its worst deviation."""

    knots: NDArray[np.int64]
    rhs: NDArray[np.float64]  # (4, segments)
    P: NDArray[np.float64]
    V: NDArray[np.float64]
    worst: NDArray[np.float64] | None  # per segment, None when not asked for


_NO_INT = np.zeros(0, dtype=np.int64)
_NO_FLOAT = np.zeros(0)
_NO_RHS = np.zeros((4, 0))


def _lsq_fit(fl: _Flat, knots: NDArray[np.int64], prev: _Fitted | None = None, target: float | None = None) -> _Fitted:
    """Knot positions and velocities (qc, qc/ms) whose cubics fit the plan best at every ms.

    Least squares over all drive samples: a banded (block-tridiagonal) system, solved in one go
    for all axes (the step between two axes contributes nothing, so the blocks are independent).
    Each axis's ends stay at the plan's start and goal at rest; a faint pull towards the exact
    samples keeps the system regular. The right-hand side of every segment unchanged since
    ``prev`` is reused.

    With ``target``, the worst |fit - plan| per segment is returned as well, as far as the
    comparison with ``target`` needs it (``knot_kernels.lsq_worst``).
    """
    table = _basis_table()
    prev_knots = _NO_INT if prev is None else prev.knots
    r, same, where = kernels.lsq_rhs(
        knots, fl.stride, fl.p, table.values, table.offset, prev_knots, _NO_RHS if prev is None else prev.rhs
    )
    P, V, ok = kernels.lsq_solve(knots, fl.stride, r, table.gram, fl.p, fl.v, fl.is_end(knots))
    if not ok:
        raise np.linalg.LinAlgError("least-squares knot fit: the banded normal equations are not positive definite")
    if target is None:
        return _Fitted(knots, r, P, V, None)
    keep = prev is not None and prev.worst is not None
    worst = kernels.lsq_worst(
        knots,
        fl.stride,
        fl.p,
        table.values,
        table.offset,
        P,
        V,
        target,
        same,
        where,
        prev.P if keep else _NO_FLOAT,
        prev.V if keep else _NO_FLOAT,
        prev.worst if keep else _NO_FLOAT,
    )
    return _Fitted(knots, r, P, V, worst)


def _fitted_subset(fl: _Flat, keep: NDArray[np.int64], fitted: _Fitted | None) -> _Fitted | None:
    if fitted is None:
        return None
    sel, knots = fl.moved_knots(keep, fitted.knots)
    seg = sel[:-1]  # the segment after each kept knot (the step to the next kept axis: none, as before)
    worst = None if fitted.worst is None else fitted.worst[seg]
    return _Fitted(knots, np.ascontiguousarray(fitted.rhs[:, seg]), fitted.P[sel], fitted.V[sel], worst)


def _fit_knots(
    fl: _Flat, knots: NDArray[np.int64], target: float, max_rounds: int
) -> tuple[NDArray[np.int64], _Fitted]:
    """Split segments until the least-squares cubics stay within ``target`` of the plan."""
    fitted: _Fitted | None = None
    for _ in range(max_rounds):
        fitted = _lsq_fit(fl, knots, fitted, target)
        assert fitted.worst is not None
        T = np.diff(knots)
        bad = np.flatnonzero(((fitted.worst > target) & (T >= 2)) | (T > TIME_MAX_MS))
        if not len(bad):
            break
        knots = _split(knots, bad)
    assert fitted is not None
    return knots, fitted


def _round_knots(
    fl: _Flat, knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Knot positions to counts (inside 0x607D), velocities to the drive's unit (inside 0x607F)."""
    ax = fl.axis_of(knots)
    r = np.rint(p)
    out = (r < INT32_MIN) | (r > INT32_MAX)
    if out.any():
        raise KnotError(f"{fl.axes[ax[np.argmax(out)]].name}: the motion leaves the int32 position range of a record")
    P = np.clip(r, fl.pos_lo[ax], fl.pos_hi[ax]).astype(np.int64)
    V = np.clip(np.rint(v / fl.f[ax]), -fl.v_units[ax], fl.v_units[ax])
    out = (V < INT24_MIN) | (V > INT24_MAX)
    if out.any():
        raise KnotError(
            f"{fl.axes[ax[np.argmax(out)]].name}: a velocity does not fit the int24 of a record "
            "(velocity unit too fine?)"
        )
    V[fl.is_end(knots)] = 0
    return P, V.astype(np.int64)


@dataclass(frozen=True)
class _Checked:
    """A check with the quantized knots it judged: the next check reuses the deviation of every
    segment whose two knots (times, positions, velocities) did not change."""

    knots: NDArray[np.int64]
    P: NDArray[np.int64]
    V: NDArray[np.int64]
    chk: _Check


def _checked_subset(fl: _Flat, keep: NDArray[np.int64], checked: _Checked | None) -> _Checked | None:
    if checked is None:
        return None
    sel, knots = fl.moved_knots(keep, checked.knots)
    seg = sel[:-1]
    c = checked.chk
    return _Checked(
        knots,
        checked.P[sel],
        checked.V[sel],
        _Check(c.seg_deviation[seg], c.velocity_ratio[seg], c.acceleration_ratio[seg], c.position_out[seg]),
    )


def _check_knots(
    fl: _Flat, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], prev: _Checked | None = None
) -> _Checked:
    """``_check`` of the quantized knots of all axes at once, per knot segment.

    The drive's segment between two records is THE Hermite cubic through their integer positions
    and velocities (``hermite``, as ``epos2_pvt`` builds it), judged by its exact extrema and at
    every ms against the plan (``knot_kernels.check_segments``). Only the segments that differ
    from ``prev`` are judged (the same two records make the same cubic, with the same extrema and
    deviation).
    """
    if prev is None:
        old = (_NO_INT, _NO_INT, _NO_INT, _NO_FLOAT, _NO_FLOAT, _NO_FLOAT, np.zeros(0, dtype=bool))
    else:
        c = prev.chk
        old = (prev.knots, prev.P, prev.V, c.seg_deviation, c.velocity_ratio, c.acceleration_ratio, c.position_out)
    dev, rv, ra, out = kernels.check_segments(
        knots, P, V, fl.stride, fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.p, *old
    )
    return _Checked(knots, P, V, _Check(dev, rv, ra, out))


def _place_epos2(
    fl: _Flat,
    smp: _Samples,
    cols: Sequence[int],
    opts: KnotOptions,
    mode: str,
    initial: Sequence[NDArray[np.int64]] | None = None,
) -> list[tuple[AxisKnots, float]]:
    """Records of the axes of ``fl`` (columns ``cols`` of ``smp``), and the slow-down each still
    calls for. ``mode``: "hint" (start from ``initial``, then least squares), "lsq" (switch knots,
    a coarse cut, least squares) or "exact" (cubics through the exact samples).

    Steps 2-4 of the module docstring, for all axes at once. An axis without a segment to split
    is done (as it would be on its own) and leaves: the next rounds work on the others only.
    """
    n = smp.n_ms
    tol = opts.tolerance_qc
    fitted: _Fitted | None = None
    target = opts.fit_fraction * tol
    if mode == "hint":
        assert initial is not None
        knots, fitted = _fit_knots(fl, fl.flat_knots(initial), target, opts.max_splits)
        p_fit, v_fit = fitted.P, fitted.V
    else:
        switch = [
            _switch_knots(
                smp.switch_ms, smp.jump[:, c], abs(fl.amax[a]) * opts.switch_fraction, n, opts.min_switch_gap_ms
            )
            for a, c in enumerate(cols)
        ]
        knots = fl.flat_knots(switch)
        if mode == "lsq":  # a coarse first cut with the cheap exact-sample cubics, then least-squares fits
            knots = _refine(knots, fl.p, fl.v, _COARSE * target, opts.max_splits)
            knots, fitted = _fit_knots(fl, knots, target, opts.max_splits)
            p_fit, v_fit = fitted.P, fitted.V
        else:
            knots = _refine(knots, fl.p, fl.v, target, opts.max_splits)
            p_fit, v_fit = fl.p[knots], fl.v[knots]
    checked: _Checked | None = None
    last_stuck = np.full(len(fl.axes), np.iinfo(np.int64).max)  # per axis (by ``ids``): segments over a limit
    out: dict[int, tuple[AxisKnots, float]] = {}
    best: dict[int, tuple[AxisKnots, float]] = {}  # per axis (by ``ids``): its least slow-down so far
    for _ in range(opts.max_splits):
        if len(p_fit) != len(knots):
            if mode == "exact":
                p_fit, v_fit = fl.p[knots], fl.v[knots]
            else:
                fitted = _lsq_fit(fl, knots, fitted)
                p_fit, v_fit = fitted.P, fitted.V
        P_round, V = _round_knots(fl, knots, p_fit, v_fit)
        rounded = _check_knots(fl, knots, P_round, V, checked)
        _, P, V, checked = _repair_rounds(fl, knots, P_round, V, rounded, tol)
        chk = checked.chk
        T = np.diff(knots)
        bad = np.flatnonzero((chk.seg_deviation > tol) | chk.position_out)
        bad = bad[T[bad] >= 2]
        # a segment still over a limit with a long span: another knot gives the repair room to fix it
        stuck = np.flatnonzero(_over(chk))
        # splits are worth it while they help: an axis whose segments over a limit did not get
        # fewer (and that strays nowhere) stops here, as it is
        ax_stuck = fl.axis_of(knots[stuck])
        n_stuck = np.bincount(ax_stuck, minlength=len(fl.axes))
        strays = np.zeros(len(fl.axes), dtype=bool)
        strays[fl.axis_of(knots[bad])] = True
        give_up = (n_stuck > 0) & ~strays & (n_stuck >= last_stuck[fl.ids])
        last_stuck[fl.ids] = n_stuck
        stuck = stuck[~give_up[ax_stuck]]
        # an axis that strays nowhere has a usable program now: keep it if it is the best so far
        # (splitting for a limit can also make it worse: shorter segments feel rounding more)
        for a in np.flatnonzero(~strays & (n_stuck > 0)):
            cand = _axis_knots(fl, int(a), knots, P, V, chk, opts.dwell_ms)
            kept = best.get(int(fl.ids[a]))
            if kept is None or cand[1] < kept[1]:
                best[int(fl.ids[a])] = cand
        bad = np.union1d(bad, stuck[T[stuck] >= 2 * _MIN_SPLIT_MS])
        if not len(bad):
            break
        # the axes without a bad segment are done (as each would be on its own): they leave
        busy = np.unique(fl.axis_of(knots[bad]))
        if len(busy) < len(fl.axes):
            for a in np.setdiff1d(np.arange(len(fl.axes)), busy):
                out[int(fl.ids[a])] = _axis_knots(fl, a, knots, P, V, chk, opts.dwell_ms)
            sel, moved_knots = fl.moved_knots(busy, knots)
            bad = np.searchsorted(sel, bad)  # every bad segment starts at a knot of a busy axis
            p_fit, v_fit = p_fit[sel], v_fit[sel]
            fitted = _fitted_subset(fl, busy, fitted)
            checked = _checked_subset(fl, busy, checked)
            fl, knots = fl.subset(busy), moved_knots
        knots = _split(knots, bad)
    assert checked is not None
    for a in range(len(fl.axes)):
        out[int(fl.ids[a])] = _axis_knots(fl, a, knots, P, V, checked.chk, opts.dwell_ms)
    for i, kept in best.items():
        if kept[1] < out[i][1]:
            out[i] = kept
    return [out[i] for i in range(len(out))]


def _repair_rounds(
    fl: _Flat,
    knots: NDArray[np.int64],
    P: NDArray[np.int64],
    V: NDArray[np.int64],
    checked: _Checked,
    tol: float,
    shift: int = 0,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], _Checked]:
    """Re-round the records around the segments over a limit, check, again (at most three rounds:
    the repair judges deviations at probes, the check at every ms). Returns the knots (moved
    only with ``shift``), the records and their check.

    Rounding each number to its nearest integer ignores that a cubic's end accelerations move by
    6/T^2 per count and 4 f/T per velocity unit: on a segment at the limit that alone can cross
    it, and on a run of segments at the limit (a time-optimal acceleration phase) fixing one end
    pushes the next segment over. So the records within ``_REPAIR_REACH`` knots of every segment
    over a limit are re-rounded together, each by up to a count and two velocity units: the
    combination with the least worst limit ratio over the segments they touch, and among those
    that stay under max(that, 1), the least summed excess, then the closest to the plan, all
    within the tolerance (``knot_kernels.repair_chains``: a shortest path over the nudges, exact,
    not greedy). With
    ``shift`` the knots may also move by up to that many ms (the integers of a cubic of another
    length make other accelerations).
    """
    per_axis = (fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.v_units)
    for _ in range(3):
        over = _over(checked.chk)
        if not over.any():
            break
        # repaired in place; ``checked`` keeps the records it judged
        knots, P, V = (knots.copy() if shift else knots), P.copy(), V.copy()
        segments = np.flatnonzero(over)
        if not kernels.repair_chains(
            knots, P, V, segments, _REPAIR_REACH, shift, fl.stride, *per_axis, fl.p, fl.v, tol
        ):
            break
        checked = _check_knots(fl, knots, P, V, checked)
    return knots, P, V, checked


def _shifted(fl: _Flat, placed: tuple[AxisKnots, float], opts: KnotOptions) -> tuple[AxisKnots, float]:
    """The records of ``fl``'s one axis with the knots around its segments over a limit moved by up
    to ``_MAX_SHIFT_MS`` where that brings them inside (and within the tolerance): the last try
    before the whole motion is slowed down. A ms first, further only where that is not enough
    (the search grows with the square of the candidates). ``placed`` if it does not help."""
    records = placed[0].records
    knots0 = _record_knots(records)
    P0, V0 = records[:-1, 0].copy(), records[:-1, 1].copy()
    checked0 = _check_knots(fl, knots0, P0, V0)
    for shift in range(1, _MAX_SHIFT_MS + 1):  # each from the placed records: the search of that reach
        knots, P, V, checked = _repair_rounds(fl, knots0, P0, V0, checked0, opts.tolerance_qc, shift)
        if not _over(checked.chk).any():
            break
    chk = checked.chk
    if chk.position_out.any() or exceeds(chk.seg_deviation, opts.tolerance_qc).any():
        return placed
    moved = _axis_knots(fl, 0, knots, P, V, chk, opts.dwell_ms)
    return moved if moved[1] < placed[1] else placed


def _record_knots(records: NDArray[np.int64]) -> NDArray[np.int64]:
    """The knots (ms from the first record) of an axis's records: ``_axis_knots`` backwards."""
    return np.concatenate(([0], np.cumsum(records[1:-1, 2]))).astype(np.int64)


def _axis_knots(
    fl: _Flat, a: int, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], chk: _Check, dwell_ms: int
) -> tuple[AxisKnots, float]:
    """The records of axis ``a`` of ``fl``, what their reconstruction does, the slow-down it needs."""
    k0, k1 = np.searchsorted(knots, [a * fl.stride, (a + 1) * fl.stride])  # knots k0 .. k1 - 1
    records = np.zeros((k1 - k0 + 1, 3), dtype=np.int64)  # the last: the end record (P, 0, 0)
    records[:-1, 0], records[:-1, 1] = P[k0:k1], V[k0:k1]
    records[-1, 0] = P[k1 - 1]
    records[0, 2] = dwell_ms
    records[1:-1, 2] = np.diff(knots[k0:k1])
    dev = float(chk.seg_deviation[k0 : k1 - 1].max())
    rv = float(chk.velocity_ratio[k0 : k1 - 1].max())
    ra = float(chk.acceleration_ratio[k0 : k1 - 1].max())
    return AxisKnots(fl.axes[a].name, records, dev, rv, ra), _needed_scale(rv, ra)


def _epos2_axes(
    axes: Sequence[DriveAxis],
    cols: Sequence[int],
    smp: _Samples,
    opts: KnotOptions,
    hints: Sequence[NDArray[np.int64]] | None,
) -> list[tuple[AxisKnots, float]]:
    """Records of the EPOS2 ``axes`` (columns ``cols`` of the samples), all placed together.

    Least-squares cubics need the fewest records for the tolerance, but spend most of it: where
    the quantized result still exceeds a limit, cubics through the exact samples (more records,
    more room for the repair) are tried as well, and the one that needs less slow-down wins.
    ``hints``: the knots of a previous, faster round, scaled to this one (tried first: cheap).
    """
    results: dict[int, tuple[AxisKnots, float]] = {}
    todo = list(range(len(axes)))

    def place(
        which: list[int], mode: str, initial: Sequence[NDArray[np.int64]] | None = None
    ) -> list[tuple[AxisKnots, float]]:
        fl = _Flat.of([axes[i] for i in which], [cols[i] for i in which], smp)
        return _place_epos2(fl, smp, [cols[i] for i in which], opts, mode, initial)

    def shifted(i: int, placed: tuple[AxisKnots, float]) -> tuple[AxisKnots, float]:
        return _shifted(_Flat.of([axes[i]], [cols[i]], smp), placed, opts)

    if hints is not None:
        for i, res in zip(todo, place(todo, "hint", list(hints)), strict=True):
            if res[1] <= 1.0:
                results[i] = res
        todo = [i for i in todo if i not in results]
    if todo:
        fit = place(todo, "lsq")
        redo = []
        for i, res in zip(todo, fit, strict=True):
            if res[1] > 1.0:  # knots a ms earlier or later first (cheap), then the exact samples
                res = shifted(i, res)
            results[i] = res
            if res[1] > 1.0:
                redo.append(i)
        if redo:
            for i, res in zip(redo, place(redo, "exact"), strict=True):
                if res[1] > 1.0:
                    res = shifted(i, res)
                if res[1] < results[i][1]:
                    results[i] = res
    return [results[i] for i in range(len(axes))]


def _over(chk: _Check) -> NDArray[np.bool_]:
    return exceeds(chk.acceleration_ratio, 1.0) | exceeds(chk.velocity_ratio, 1.0)


def _needed_scale(rv: float, ra: float) -> float:
    """Slowing down by k divides velocities by k and accelerations by k^2."""
    k = max(rv, math.sqrt(max(ra, 0.0)))
    return k * (1.0 + 1e-4) if exceeds(k, 1.0) else 1.0


# --- fixed-period profiles -------------------------------------------------------------------------------
_FP_REACH = 3  # counts (and records) a cubic's setpoint may move off the plan around a segment over a limit


def _reconstruction_kind(axis: DriveAxis) -> int:
    """Which reconstruction the axis's drive makes of its setpoints (``knot_kernels.LINEAR``,
    ``CUBIC_PV``, ``CUBIC_P``), as ``AxisProgram.reconstruction`` picks it: Parker interpolates its
    cubic submodes only from a 2.5 ms cycle on; below, and for every other fixed-period drive, the
    setpoints are joined linearly."""
    parker_interpolates = (
        axis.profile == "parker_slvdn" and int(axis.period_ms or 0) * 1000.0 >= PARKER_CUBIC_THRESHOLD_US
    )
    if parker_interpolates and axis.interpolation_submode == -1:
        return kernels.CUBIC_PV
    if parker_interpolates and axis.interpolation_submode == -2:
        return kernels.CUBIC_P
    return kernels.LINEAR


def _record_times(axis: DriveAxis, smp: _Samples) -> NDArray[np.int64]:
    """The plan's ms of each record of a fixed-period axis: one per period, the last at the goal."""
    period = int(axis.period_ms or 1)
    return np.minimum(np.arange(math.ceil(smp.n_ms / period) + 1) * period, smp.n_ms)


def _lattice(axis: DriveAxis, counts: float, what: str, obj: str) -> float:
    """A limit of ``counts`` (per period, or per period squared) over the largest whole number of
    counts within it; KnotError where there is none (no motion at all stays inside)."""
    whole = math.floor(counts * (1.0 + LIMIT_RTOL))
    if not whole:
        raise KnotError(
            f"{axis.name}: the drive's reconstruction still exceeds its limits whatever the slow-down: at a "
            f"{axis.period_ms} ms period a setpoint one count off moves its {what} by more than {obj} allows "
            f"({counts:.3g} counts)"
        )
    return counts / whole


def _drive_slowdown(axis: DriveAxis, i: int, smp: _Samples) -> tuple[float, float]:
    """What a fixed-period axis's drive alone calls for on this plan, before any integer is chosen:
    (the least slow-down, the slow-down of the plan's exact samples).

    Whole counts put a linear reconstruction's velocities on multiples of 1/T qc/ms and its
    accelerations (and cubic_p's) on multiples of 1/T^2 qc/ms^2: the largest of them within
    0x607F / 0x60C5 can lie well below (at 1 ms on a 4096-count encoder, 2 qc/ms^2 is the most
    below a 0x60C5 of 40,000 rpm/s = 2.73 qc/ms^2). A plan that keeps its acceleration for more
    than a period or two cannot be followed faster than that: the least slow-down is the plan's own
    (its samples joined linearly) on that lattice. On top, a cubic through the plan's exact samples
    overshoots where the plan's acceleration jumps between two records (up to 1.5 times with the
    plan's velocities, 2 times with central ones): the second figure is the drive's reconstruction
    of the exact samples on the lattice, which the integer search usually beats.
    """
    kind = _reconstruction_kind(axis)
    period = float(axis.period_ms or 1)
    f, amax, vmax, *_ = (float(x[0]) for x in _axis_constants((axis,)))
    lattice_v = lattice_a = 1.0
    if kind != kernels.CUBIC_PV:
        lattice_a = _lattice(axis, amax * period * period, "acceleration", "0x60C5")
    if kind == kernels.LINEAR:
        lattice_v = _lattice(axis, vmax * period, "velocity", "0x607F")
    t_ms = _record_times(axis, smp)
    p = smp.position[i, t_ms]
    v = smp.velocity[i, t_ms] / f
    args = (smp.position[i], int(period), f, *(float(x[0]) for x in _axis_constants((axis,))[6:8]), -math.inf, math.inf)
    out = []
    for k in (kernels.LINEAR, kind):
        rv, ra = kernels.fixed_period_ratios(k, p, v, *args)
        out.append(max(float(rv.max()) * lattice_v, math.sqrt(float(ra.max()) * lattice_a), 1.0))
    return out[0], max(out)


def _fixed_period_axis(axis: DriveAxis, i: int, smp: _Samples, opts: KnotOptions) -> tuple[AxisKnots, float]:
    """One record per period: the plan's samples rounded, then re-chosen among the integers around
    them where the drive's reconstruction of the rounding exceeds a limit
    (``knot_kernels.track_fixed_period``: exact, over the whole motion)."""
    period = int(axis.period_ms or 1)
    t_ms = _record_times(axis, smp)
    P = _round_positions(smp.position[i, t_ms], axis)
    if axis.profile == "parker_slvdn" and axis.interpolation_submode == -1:
        V = _round_velocities(smp.velocity[i, t_ms], axis)
    else:
        V = np.zeros(len(P), dtype=np.int64)
    V[0] = V[-1] = 0
    f, _, _, v_units, pos_lo, pos_hi, rv_per, ra_per = (float(x[0]) for x in _axis_constants((axis,)))
    kind = _reconstruction_kind(axis)
    reach = _FP_REACH if kind == kernels.CUBIC_P else 1
    P, V, _ = kernels.track_fixed_period(
        kind, P, V, smp.position[i], period, f, rv_per, ra_per, pos_lo, pos_hi, v_units, reach
    )
    records = np.column_stack((np.append(P, P[-1]), np.append(V, 0), np.full(len(P) + 1, period))).astype(np.int64)
    chk, _ = _check(axis, records, smp.position[i])
    ra = float(chk.acceleration_ratio.max())
    rv = float(chk.velocity_ratio.max())
    return AxisKnots(axis.name, records, chk.deviation, rv, ra), _needed_scale(rv, ra)


# --- the front door -----------------------------------------------------------------------------------------
def place_knots(traj: TimedTrajectory, axes: Sequence[DriveAxis], options: KnotOptions | None = None) -> KnotResult:
    """Records for every axis whose quantized reconstruction stays inside the drive limits.

    ``axes`` are in the trajectory's joint order. Raises KnotError when no program within
    ``options.max_time_scale`` meets the limits.
    """
    opts = options or KnotOptions()
    if traj.duration <= 0:
        raise KnotError("the trajectory has no duration")
    # end on a whole ms: a stop between two drive samples would put the final deceleration switch
    # inside the last segment, where no cubic follows it
    duration_ms = traj.duration * 1000.0
    scale = math.ceil(duration_ms - 1e-6) / duration_ms
    last: tuple[AxisKnots, ...] = ()
    last_n = 0
    least = drives = 1.0  # the slow-downs the fixed-period drives alone call for (``_drive_slowdown``)
    if any(a.profile != "epos2_pvt" for a in axes):
        smp = _sample(traj, axes, scale)
        for i, axis in enumerate(axes):
            if axis.profile != "epos2_pvt":
                k_least, k_drive = _drive_slowdown(axis, i, smp)
                least, drives = max(least, scale * k_least), max(drives, scale * k_drive)
        if least > scale:  # no integers make less: no round below it
            scale = math.ceil(duration_ms * least - 1e-6) / duration_ms
    for rounds in range(1, opts.max_rounds + 1):
        smp = _sample(traj, axes, scale)
        placed: dict[int, tuple[AxisKnots, float]] = {}
        epos2 = [i for i, a in enumerate(axes) if a.profile == "epos2_pvt"]
        if epos2:
            hints = None
            if last:  # the previous round's knots, stretched with the motion
                hints = []
                for i in epos2:
                    prev = _record_knots(last[i].records)
                    hints.append(np.unique(np.rint(prev * smp.n_ms / last_n).astype(np.int64)))
            placed.update(zip(epos2, _epos2_axes([axes[i] for i in epos2], epos2, smp, opts, hints), strict=True))
        for i, axis in enumerate(axes):
            if axis.profile != "epos2_pvt":
                placed[i] = _fixed_period_axis(axis, i, smp, opts)
        results = [placed[i][0] for i in range(len(axes))]
        need = max([1.0] + [placed[i][1] for i in range(len(axes))])
        last = tuple(results)
        last_n = smp.n_ms
        if need <= 1.0:
            return KnotResult(last, scale, smp.n_ms, rounds)
        # A new scale re-places the knots, whose rounding differs: the residual excess is no
        # measure of what the next round needs. Rounding moves a segment's acceleration by a few
        # tenths of a percent, so ask at least for that much room, a little more each round.
        # The excess of a quantized program overstates what a slower one needs (its integers
        # can be placed better with a little room): grow by at most 1, 2, 4 ... % per round.
        scale *= min(max(need, 1.0 + 1e-3 * rounds), 1.0 + 0.01 * 2 ** (rounds - 1))
        if least > scale:  # no integers make less: no round below it
            scale = least
        scale = math.ceil(duration_ms * scale - 1e-6) / duration_ms  # and end on a whole ms again
        # the limit on the slow-down is on what the integers cost, on top of what the drives' own
        # interpolation of this plan calls for (a plan that asks more than they can take)
        if scale > opts.max_time_scale * drives and duration_ms * (scale - drives) > opts.max_extra_ms:
            break
    worst = max(last, key=lambda a: max(a.velocity_ratio, a.acceleration_ratio))
    beyond = f" beyond the {drives:.4f} the drives' interpolation of this plan calls for" if drives > 1.0 else ""
    raise KnotError(
        f"{worst.name}: the drive's reconstruction still exceeds its limits (|v| {100 * worst.velocity_ratio:.2f}% "
        f"of 0x607F, |a| {100 * worst.acceleration_ratio:.2f}% of 0x60C5) after slowing down by "
        f"{scale:.4f} (max {opts.max_time_scale}{beyond}, or {opts.max_extra_ms} ms)"
    )
