"""PVT knot placement: from a timed trajectory to integer records the drive executes as they are.

The drive does not execute the planner's curve: it rebuilds the motion from the records with its
own interpolation (planner.interpolation), from integer ms, integer velocity units and integer
counts, and faults where that rebuild exceeds 0x607F or 0x60C5. So every candidate program is
judged here by that very reconstruction of its *quantized* records, exactly (closed-form extrema
per segment), never by the planned curve.

EPOS2 PVT (``epos2_pvt``), per axis (the axes share only the start SYNC and the end time):

1. knots at whole ms where the axis's acceleration jumps (the time-optimal profile switches
   there; a cubic across a switch overshoots), at least ``min_switch_gap_ms`` apart;
2. adaptive refinement: segments are halved while the least-squares cubics (a banded linear
   system over the knot positions and velocities, fitted to the plan at every drive ms) stray
   more than ``fit_fraction * tolerance_qc`` from the plan, or are longer than 255 ms;
3. quantization: positions to counts (inside 0x607D); where that pushes a cubic over a limit, a
   QP (casadi, daqp) moves the knot velocities by the least amount that keeps every cubic's end
   accelerations inside 0x60C5 (they are linear in the velocities once the positions are fixed),
   within the tolerance; velocities are rounded to the drive's unit, and any segment still over a
   limit is re-rounded (its end records nudged by a count or a few velocity units);
4. the exact reconstruction of the quantized records is checked: a segment that strays more than
   the tolerance, or stays over a limit, is split and steps 3-4 are redone. Where the
   least-squares knots cannot be made to fit the limits, cubics through the exact samples (more
   records, more room) are tried and the better of the two is kept;
5. where the quantized reconstruction still exceeds 0x607F/0x60C5 (rounding at the limit costs a
   few tenths of a percent), the whole motion is slowed down by the smallest factor the excess
   calls for and the knots are placed again (from the previous ones, stretched). No blanket
   margin: a motion that fits is not slowed at all.

Fixed-period profiles take one record per period and are checked by their own reconstruction
(linear, or Parker's cubic submodes) the same way. All numbers here are in drive units: qc,
velocity units (qc/ms inside the interpolation), ms.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from axes.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from planner.interpolation import PiecewiseCubic, hermite_coefficients
from planner.program import FIXED_PERIOD_PROFILES, PROFILES, TIME_MAX_MS, AxisProgram

# relative slack for float noise when comparing a reconstruction with a limit (as the validator)
_REL_EPS = 1e-9


class TimedTrajectory(Protocol):
    """What knot placement needs of a trajectory (planner.timing.Trajectory): seconds, joint units."""

    @property
    def duration(self) -> float: ...

    @property
    def breakpoints(self) -> NDArray[np.float64]: ...

    def position(self, t: Any) -> NDArray[np.float64]: ...

    def velocity(self, t: Any) -> NDArray[np.float64]: ...

    def acceleration(self, t: Any) -> NDArray[np.float64]: ...


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
        return cls(axis.joint, axis.node_id, axis.profile, axis.scaling, axis.limits, axis.period_ms,
                   axis.interpolation_submode)

    def program(self, records: NDArray[np.int64]) -> AxisProgram:
        return AxisProgram(self.name, self.node_id, self.profile, self.scaling, self.limits, records,
                           self.interpolation_submode)


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
    position: NDArray[np.float64]  # (n_ms + 1, dof) qc
    velocity: NDArray[np.float64]  # (n_ms + 1, dof) qc/ms
    switch_ms: NDArray[np.float64]  # breakpoint times (ms)
    jump: NDArray[np.float64]  # (len(switch_ms), dof) |acceleration jump| qc/ms^2


def _sample(traj: TimedTrajectory, axes: Sequence[DriveAxis], scale: float) -> _Samples:
    duration_ms = traj.duration * 1000.0 * scale
    n = max(1, math.ceil(duration_ms - 1e-6))
    t = np.arange(n + 1) / (1000.0 * scale)  # trajectory time of each drive ms
    q = np.atleast_2d(traj.position(t))
    qd = np.atleast_2d(traj.velocity(t)) / scale
    bp = np.asarray(traj.breakpoints, dtype=float)[1:-1]
    eps = 1e-9 * max(traj.duration, 1.0)
    if len(bp):
        jump_joint = (np.atleast_2d(traj.acceleration(bp + eps)) - np.atleast_2d(traj.acceleration(bp - eps)))
        jump_joint = np.abs(jump_joint) / (scale * scale)
    else:
        jump_joint = np.zeros((0, len(axes)))
    pos = np.empty((n + 1, len(axes)))
    vel = np.empty((n + 1, len(axes)))
    jump = np.empty((len(bp), len(axes)))
    for i, a in enumerate(axes):
        s = a.scaling
        pos[:, i] = s.position_to_qc(q[:, i])
        vel[:, i] = s.drive_velocity_to_qc_per_ms(s.velocity_to_drive(qd[:, i]))
        jump[:, i] = np.abs(s.rpm_s_to_qc_per_ms2(s.acceleration_to_rpm_s(jump_joint[:, i])))
    vel[0] = 0.0
    vel[-1] = 0.0
    return _Samples(scale, n, pos, vel, bp * 1000.0 * scale, jump)


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
    j plus the time at which records[0] is reached (the dwell, or the fixed-period delay).
    """
    recon = axis.program(records).reconstruction()
    s = axis.scaling
    lim = axis.limits
    v = np.asarray(s.qc_per_ms_to_rpm(recon.max_abs_velocity())) / lim.max_profile_velocity_rpm
    a = np.asarray(s.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration())) / lim.max_acceleration_rpm_s
    lo, hi = recon.position_range()
    out = (lo < lim.min_position_qc) | (hi > lim.max_position_qc)
    shift = float(recon.start[0] + recon.duration[0])
    t = np.arange(len(plan_qc)) + shift
    err = np.abs(recon.position(t) - plan_qc)
    # worst error per segment (samples are in time order: contiguous groups)
    first = np.minimum(np.searchsorted(t, recon.start), len(t) - 1)
    seg_dev = np.maximum.reduceat(err, first)
    empty = np.append(first[1:] <= first[:-1], False) | (recon.start > t[-1])
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
def _switch_knots(switch_ms: NDArray[np.float64], jump: NDArray[np.float64], threshold: float, n_ms: int,
                  min_gap: int) -> NDArray[np.int64]:
    """Integer ms at the significant acceleration switches, largest jumps first, min_gap apart."""
    big = np.flatnonzero(jump > threshold)
    if not len(big):
        return np.zeros(0, dtype=np.int64)
    order = big[np.argsort(-jump[big])]
    blocked = np.zeros(n_ms + 1, dtype=bool)
    blocked[:min_gap] = blocked[n_ms - min_gap + 1:] = True  # too close to the start or the end
    taken: list[int] = []
    for t in np.rint(switch_ms[order]).astype(np.int64):
        if not blocked[t]:
            taken.append(int(t))
            blocked[max(t - min_gap + 1, 0):t + min_gap] = True
    return np.array(sorted(taken), dtype=np.int64)


def _split(knots: NDArray[np.int64], segments: NDArray[np.int64]) -> NDArray[np.int64]:
    """Halve the given knot segments (those of 1 ms cannot be split and are left alone)."""
    lo, hi = knots[segments], knots[segments + 1]
    ok = hi - lo >= 2
    return np.union1d(knots, (lo[ok] + hi[ok]) // 2)


_COARSE = 4.0  # first cut: exact-sample cubics to this multiple of the fit target (cheap), then least squares
_QP_WINDOW = 4  # knots on either side of a segment over a limit whose velocities the QP may move
_MIN_SPLIT_MS = 12  # segments shorter than twice this are not split for a limit (rounding grows as 1/T^2)
_FIT_PROBES = np.arange(1, 8) / 8.0  # where a candidate segment's fit is judged


def _refine(knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64], target: float,
            max_rounds: int) -> NDArray[np.int64]:
    """Split segments until the cubic through the exact samples stays within ``target`` of the plan.

    The fit is judged at seven whole-ms probes per segment (a cheap first cut: the exact
    reconstruction is checked at every ms afterwards and splits what this misses). Only the
    segments made by the last split are judged again.
    """
    pending = knots[:-1]  # start times of the segments still to judge
    for _ in range(max_rounds):
        idx = np.searchsorted(knots, pending)
        lo, hi = knots[idx], knots[idx + 1]
        T = (hi - lo).astype(float)
        c = hermite_coefficients(p[lo], v[lo], p[hi], v[hi], T)
        tau = np.floor(T[:, None] * _FIT_PROBES[None, :])
        fit = c[0][:, None] + tau * (c[1][:, None] + tau * (c[2][:, None] + tau * c[3][:, None]))
        worst = np.abs(fit - p[lo[:, None] + tau.astype(np.int64)]).max(axis=1)
        bad = ((worst > target) & (T >= 2)) | (T > TIME_MAX_MS)
        if not bad.any():
            break
        mid = (lo[bad] + hi[bad]) // 2
        knots = np.union1d(knots, mid)
        pending = np.concatenate((lo[bad], mid))
    return knots


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


def _lsq_fit(knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Knot positions and velocities (qc, qc/ms) whose cubics fit the plan best at every ms.

    Least squares over all drive samples: a banded (block-tridiagonal) system, solved in one go.
    The ends stay at the plan's start and goal at rest; a faint pull towards the exact samples
    keeps the system regular. Returns (P, V, worst |fit - plan| per segment).
    """
    from scipy.linalg import solveh_banded

    table = _basis_table()
    n = np.diff(knots)
    T = n.astype(float)
    nk = len(knots)
    seg = np.repeat(np.arange(nk - 1), n)
    j = np.arange(knots[0], knots[-1])
    starts = np.cumsum(n) - n
    b = table.values[:, table.offset[n][seg] + (j - knots[seg])]  # (4, N): basis cubics at the samples
    G = table.gram[n].transpose(1, 2, 0)  # (4, 4, segments)
    r = np.array([np.add.reduceat(b[a] * p[j], starts) for a in range(4)])  # (4, segments)
    # unknowns z = (P0, V0, P1, V1, ...): segment k touches 2k .. 2k + 3; upper banded form, u = 3
    m = 2 * nk
    ab = np.zeros((4, m))
    rhs = np.zeros(m)
    span = 2 * (nk - 1)
    for a in range(4):  # segment k's entries (a, c) sit at 2k + a, 2k + c: one strided slice per pair
        rhs[a:a + span:2] += r[a]
        for c in range(a, 4):
            ab[3 - (c - a), c:c + span:2] += G[a, c]
    tw = np.concatenate(([T[0]], 0.5 * (T[:-1] + T[1:]), [T[-1]]))
    reg_p, reg_v = 1e-3, 1e-3 * tw * tw
    ab[3, 0::2] += reg_p
    ab[3, 1::2] += reg_v
    rhs[0::2] += reg_p * p[knots]
    rhs[1::2] += reg_v * v[knots]
    big = 1e9 * (1.0 + np.abs(ab[3]).max())
    for idx, target in ((0, p[knots[0]]), (1, 0.0), (m - 2, p[knots[-1]]), (m - 1, 0.0)):
        ab[3, idx] += big
        rhs[idx] += big * target
    z = solveh_banded(ab, rhs, check_finite=False)
    P, V = z[0::2], z[1::2]
    P[0], P[-1], V[0], V[-1] = p[knots[0]], p[knots[-1]], 0.0, 0.0
    local = np.array([P[seg], V[seg], P[seg + 1], V[seg + 1]])
    fit = (local * b).sum(axis=0)
    worst = np.maximum.reduceat(np.abs(fit - p[j]), starts)
    return P, V, worst


def _fit_knots(knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64], target: float,
               max_rounds: int) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Split segments until the least-squares cubics stay within ``target`` of the plan."""
    for _ in range(max_rounds):
        P, V, worst = _lsq_fit(knots, p, v)
        T = np.diff(knots)
        bad = np.flatnonzero(((worst > target) & (T >= 2)) | (T > TIME_MAX_MS))
        if not len(bad):
            break
        knots = _split(knots, bad)
    return knots, P, V


def _epos2_records(axis: DriveAxis, knots: NDArray[np.int64], P: NDArray[np.int64], v: NDArray[np.float64],
                   dwell: int) -> NDArray[np.int64]:
    """Records from integer knot positions and knot velocities in qc/ms (rounded to the drive's unit)."""
    V = _round_velocities(v, axis)
    V[0] = V[-1] = 0
    times = np.concatenate(([dwell], np.diff(knots)))
    rec = np.column_stack((P, V, times))
    end = np.array([[P[-1], 0, 0]], dtype=np.int64)
    return np.vstack((rec, end)).astype(np.int64)


def _velocity_qp(axis: DriveAxis, knots: NDArray[np.int64], P: NDArray[np.int64], v: NDArray[np.float64],
                 room: NDArray[np.float64], over: NDArray[np.int64]) -> NDArray[np.float64] | None:
    """Knot velocities (qc/ms) closest to ``v`` that keep every cubic inside 0x607F/0x60C5.

    With the positions fixed at their counts, a cubic's end accelerations are linear in its end
    velocities, (6 dP - (4 V0 + 2 V1) T) / T^2 and (-6 dP + (2 V0 + 4 V1) T) / T^2, and so is its
    position at any fixed time inside. So "as close to the plan as possible, exactly inside the
    acceleration limit" is a QP (casadi, daqp) over the velocities: it moves them just enough to
    absorb what rounding the positions did to the accelerations, each segment's interior moving
    by at most its ``room`` (counts) at a third and two thirds of it. Only the velocities within
    ``_QP_WINDOW`` knots of the segments ``over`` a limit move (the rest are fixed), which keeps the
    QP small. None when infeasible.
    """
    import casadi

    s = axis.scaling
    amax = float(s.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s))
    vmax = float(s.rpm_to_qc_per_ms(axis.limits.max_profile_velocity_rpm))
    n = len(knots)
    # the window: free velocities near the segments over a limit, and the segments they touch
    free = np.zeros(n, dtype=bool)
    for d in range(-_QP_WINDOW + 1, _QP_WINDOW + 1):
        free[np.clip(over + d, 0, n - 1)] = True
    free[0] = free[-1] = False  # at rest at both ends
    if not free.any():
        return None
    cols = np.flatnonzero(free)
    col_of = np.full(n, -1)
    col_of[cols] = np.arange(len(cols))
    segs = np.flatnonzero(free[:-1] | free[1:])
    T = (knots[segs + 1] - knots[segs]).astype(float)
    dp = (P[segs + 1] - P[segs]).astype(float)
    v0, v1 = v[segs], v[segs + 1]
    a0 = (6.0 * dp - (4.0 * v0 + 2.0 * v1) * T) / (T * T)
    a1 = (-6.0 * dp + (2.0 * v0 + 4.0 * v1) * T) / (T * T)
    # rows per segment: start acceleration, end acceleration, position at T/3 and at 2T/3
    coef = np.stack((np.stack((-4.0 / T, -2.0 / T), 1), np.stack((2.0 / T, 4.0 / T), 1),
                     np.stack((4.0 * T / 27, -2.0 * T / 27), 1), np.stack((2.0 * T / 27, -4.0 * T / 27), 1)), 1)
    A = np.zeros((4 * len(segs), len(cols)))
    for end, knot in enumerate((segs, segs + 1)):
        c = col_of[knot]
        ok = c >= 0
        rows = 4 * np.flatnonzero(ok)
        for r in range(4):
            A[rows + r, c[ok]] = coef[ok, r, end]
    r_seg = room[segs]
    lo = np.stack((-amax - a0, -amax - a1, -r_seg, -r_seg), 1).ravel()
    hi = np.stack((amax - a0, amax - a1, r_seg, r_seg), 1).ravel()
    lbx = np.clip(-vmax - v[cols], None, 0.0)
    ubx = np.clip(vmax - v[cols], 0.0, None)
    # weight: the position effect of a velocity change grows with the adjacent segment times
    w = 0.5 * (knots[cols + 1] - knots[cols - 1]).astype(float)
    m = len(cols)
    h_sp = casadi.Sparsity.diag(m)
    a_sp = casadi.Sparsity.dense(A.shape[0], m)
    solver = casadi.conic("knot_velocities", "daqp", {"h": h_sp, "a": a_sp}, {"error_on_fail": False})
    res = solver(h=casadi.DM(h_sp, 2.0 * w * w), g=np.zeros(m), a=casadi.DM(A), lba=lo, uba=hi, lbx=lbx, ubx=ubx)
    if not solver.stats().get("success", False):
        return None
    out = v.copy()
    out[cols] += np.asarray(res["x"]).ravel()
    return out


def _epos2_axis(axis: DriveAxis, i: int, smp: _Samples, opts: KnotOptions,
                hint: NDArray[np.int64] | None = None) -> tuple[AxisKnots, float]:
    """Records of one EPOS2 axis, and the slow-down its limits still call for (1.0: none).

    Least-squares cubics need the fewest records for the tolerance, but spend most of it: where
    the quantized result still exceeds a limit, cubics through the exact samples (more records,
    more room for the velocity QP) are tried as well, and the one that needs less slow-down wins.
    ``hint``: the knots of a previous, faster round, scaled to this one (tried first: cheap).
    """
    if hint is not None:
        fit, need = _epos2_axis_with(axis, i, smp, opts, least_squares=True, initial=hint)
        if need <= 1.0:
            return fit, need
    fit, need = _epos2_axis_with(axis, i, smp, opts, least_squares=True)
    if need > 1.0:
        exact, need_exact = _epos2_axis_with(axis, i, smp, opts, least_squares=False)
        if need_exact < need:
            return exact, need_exact
    return fit, need


def _epos2_axis_with(axis: DriveAxis, i: int, smp: _Samples, opts: KnotOptions, least_squares: bool,
                     initial: NDArray[np.int64] | None = None) -> tuple[AxisKnots, float]:
    p, v, n = smp.position[:, i], smp.velocity[:, i], smp.n_ms
    amax = float(axis.scaling.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s))
    threshold = abs(amax) * opts.switch_fraction
    if initial is not None:
        knots = np.union1d([0, n], initial[(initial > 0) & (initial < n)])
        knots, p_fit, v_fit = _fit_knots(knots, p, v, opts.fit_fraction * opts.tolerance_qc, opts.max_splits)
    elif least_squares:
        knots = np.union1d([0, n], _switch_knots(smp.switch_ms, smp.jump[:, i], threshold, n, opts.min_switch_gap_ms))
        # a coarse first cut with the cheap exact-sample cubics, then least-squares fits
        knots = _refine(knots, p, v, _COARSE * opts.fit_fraction * opts.tolerance_qc, opts.max_splits)
        knots, p_fit, v_fit = _fit_knots(knots, p, v, opts.fit_fraction * opts.tolerance_qc, opts.max_splits)
    else:
        knots = np.union1d([0, n], _switch_knots(smp.switch_ms, smp.jump[:, i], threshold, n, opts.min_switch_gap_ms))
        knots = _refine(knots, p, v, opts.fit_fraction * opts.tolerance_qc, opts.max_splits)
        p_fit, v_fit = p[knots], v[knots]
    for _ in range(opts.max_splits):
        if len(p_fit) != len(knots):
            p_fit, v_fit = (_lsq_fit(knots, p, v)[:2]) if least_squares else (p[knots], v[knots])
        P = _round_positions(p_fit, axis)
        records = _epos2_records(axis, knots, P, v_fit, opts.dwell_ms)
        chk, _ = _check(axis, records, p)
        if _over(chk).any():
            room = np.maximum(opts.tolerance_qc - chk.seg_deviation[1:], 0.0)
            v_qp = _velocity_qp(axis, knots, P, v_fit, room, np.flatnonzero(_over(chk)[1:]))
            if v_qp is not None:
                records = _epos2_records(axis, knots, P, v_qp, opts.dwell_ms)
                chk, _ = _check(axis, records, p)
        for _ in range(3):  # rounding the velocities, or fixing one segment, can push another over
            over = np.flatnonzero(_over(chk))
            if not len(over):
                break
            records = _repair(axis, records, over, knots, p, opts.tolerance_qc)
            chk, _ = _check(axis, records, p)
        # reconstruction segment k >= 1 is knot segment k - 1 (segment 0 is the dwell)
        T = np.diff(knots)
        bad = np.flatnonzero((chk.seg_deviation[1:] > opts.tolerance_qc) | chk.position_out[1:])
        bad = bad[T[bad] >= 2]
        # a segment still over a limit with a long span: another knot gives the QP room to fix it
        stuck = np.flatnonzero(_over(chk)[1:])
        bad = np.union1d(bad, stuck[T[stuck] >= 2 * _MIN_SPLIT_MS])
        if not len(bad):
            break
        knots = _split(knots, bad)
    ra = float(chk.acceleration_ratio.max())
    rv = float(chk.velocity_ratio.max())
    result = AxisKnots(axis.name, records, chk.deviation, rv, ra)
    return result, _needed_scale(rv, ra)


# every combination of these count / velocity-unit nudges of a segment's two end records is tried
_NUDGE_P = np.arange(-1, 2)
_NUDGE_V = np.arange(-2, 3)
_COMBOS = np.stack(np.meshgrid(_NUDGE_P, _NUDGE_V, _NUDGE_P, _NUDGE_V, indexing="ij"), axis=-1).reshape(-1, 4)
_PROBES = np.array([0.25, 0.5, 0.75])  # where inside a segment the deviation of a nudge is judged


def _repair(axis: DriveAxis, records: NDArray[np.int64], segments: NDArray[np.int64], knots: NDArray[np.int64],
            p: NDArray[np.float64], tolerance: float) -> NDArray[np.int64]:
    """Re-round the end records of segments whose quantized reconstruction exceeds a limit.

    Rounding each number to its nearest integer ignores that a cubic's end accelerations move
    by 6/T^2 per count: on a segment at the limit that alone can cross it. Here the two end
    records of such a segment are nudged by up to 1 count and 2 velocity units (all 225
    combinations at once); among those that keep the knots and the segments' interiors within
    the tolerance of the plan, the one with the lowest worst limit ratio over the three segments
    they touch wins.
    """
    r = records.copy()
    f = axis.scaling.qc_per_ms_per_velocity_unit
    s = axis.scaling
    lim = axis.limits
    last_motion = len(r) - 2  # its velocity is 0 and its position the goal: fixed
    for b in segments:
        if b < 1 or b > last_motion:
            continue
        ends = (b - 1, b)
        free = np.array([[k >= 1 and k < last_motion] * 2 for k in ends]).reshape(-1)  # P, V of each end
        combos = _COMBOS[np.all((_COMBOS == 0) | free, axis=1)]
        first, last = max(b - 1, 1), min(b + 1, last_motion)  # reconstruction segments touched
        idx = np.arange(first - 1, last + 1)  # records spanning them (record k sits at knot k)
        P = np.repeat(r[idx, 0][None, :].astype(float), len(combos), axis=0)
        V = np.repeat(r[idx, 1][None, :].astype(float), len(combos), axis=0)
        for j, k in enumerate(ends):
            col = k - (first - 1)
            P[:, col] += combos[:, 2 * j]
            V[:, col] += combos[:, 2 * j + 1]
        T = np.repeat(r[idx[1:], 2][None, :].astype(float), len(combos), axis=0)
        c = hermite_coefficients(P[:, :-1], V[:, :-1] * f, P[:, 1:], V[:, 1:] * f, T)
        # deviation at the knots and at probes inside each segment
        dev = np.abs(P - p[knots[idx]][None, :]).max(axis=1)
        for q in _PROBES:
            tau = np.floor(q * T[0])
            h = c[0] + tau * (c[1] + tau * (c[2] + tau * c[3]))
            dev = np.maximum(dev, np.abs(h - p[knots[idx[:-1]] + tau.astype(np.int64)][None, :]).max(axis=1))
        cub = PiecewiseCubic(np.zeros(T.size), T.ravel(), *(x.ravel() for x in c))
        rv = np.asarray(s.qc_per_ms_to_rpm(cub.max_abs_velocity())).reshape(T.shape) / lim.max_profile_velocity_rpm
        ra = np.asarray(s.qc_per_ms2_to_rpm_s(cub.max_abs_acceleration())).reshape(T.shape) / lim.max_acceleration_rpm_s
        worst = np.maximum(rv, ra).max(axis=1)
        worst = np.where(dev <= tolerance, worst + 1e-6 * dev, np.inf)
        best = int(np.argmin(worst))
        if np.isfinite(worst[best]):
            r[idx, 0] = P[best].astype(np.int64)
            r[idx, 1] = V[best].astype(np.int64)
    r[-1, 0] = r[-2, 0]
    return r


def _over(chk: _Check) -> NDArray[np.bool_]:
    return (chk.acceleration_ratio > 1.0 + _REL_EPS) | (chk.velocity_ratio > 1.0 + _REL_EPS)


def _needed_scale(rv: float, ra: float) -> float:
    """Slowing down by k divides velocities by k and accelerations by k^2."""
    k = max(rv, math.sqrt(max(ra, 0.0)))
    return k * (1.0 + 1e-4) if k > 1.0 + _REL_EPS else 1.0


# --- fixed-period profiles -------------------------------------------------------------------------------
def _fixed_period_axis(axis: DriveAxis, i: int, smp: _Samples, opts: KnotOptions) -> tuple[AxisKnots, float]:
    period = int(axis.period_ms or 1)
    n_rec = math.ceil(smp.n_ms / period)
    t_ms = np.minimum(np.arange(n_rec + 1) * period, smp.n_ms)
    p = smp.position[t_ms, i]
    P = _round_positions(p, axis)
    if axis.profile == "parker_slvdn" and axis.interpolation_submode == -1:
        V = _round_velocities(smp.velocity[t_ms, i], axis)
    else:
        V = np.zeros(len(P), dtype=np.int64)
    V[0] = V[-1] = 0
    if axis.profile != "parker_slvdn" or axis.interpolation_submode == 0:
        P = _track_linear(P, p, axis, period)
    records = np.column_stack((np.append(P, P[-1]), np.append(V, 0), np.full(len(P) + 1, period))).astype(np.int64)
    chk, _ = _check(axis, records, smp.position[:, i])
    ra = float(chk.acceleration_ratio.max())
    rv = float(chk.velocity_ratio.max())
    return AxisKnots(axis.name, records, chk.deviation, rv, ra), _needed_scale(rv, ra)


_OFFSETS = np.array([-1, 0, 1])  # counts a setpoint may move off its nearest integer


def _track_linear(P: NDArray[np.int64], p: NDArray[np.float64], axis: DriveAxis, period: int) -> NDArray[np.int64]:
    """Integer setpoints whose steps respect 0x607F/0x60C5 for a linear interpolator.

    Rounding each setpoint alone adds up to 2 counts to a second difference (a velocity step),
    which at a short period can be more than 0x60C5 allows. A Viterbi pass over the choices
    round(p) - 1, round(p), round(p) + 1 per setpoint (state: the last two choices) finds the
    sequence closest to the plan whose steps and step changes all stay inside the limits, from
    rest to rest. Where there is none, the plain rounding is kept (and the check slows down).
    """
    s = axis.scaling
    a_max = float(s.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s)) * period * period * (1 + _REL_EPS)
    v_max = float(s.rpm_to_qc_per_ms(axis.limits.max_profile_velocity_rpm)) * period * (1 + _REL_EPS)
    steps = np.diff(np.concatenate(([P[0]], P, [P[-1]])))  # from rest, to rest
    if np.all(np.abs(np.diff(steps)) <= a_max) and np.all(np.abs(steps) <= v_max):
        return P
    n = len(P)
    err = (P[:, None] + _OFFSETS[None, :] - p[:, None]) ** 2  # (n, 3)
    inf = np.inf
    # cost[i, j]: best cost with offset i at k-1 and j at k; start: k = 0 fixed at offset 0, at rest
    cost = np.full((3, 3), inf)
    cost[1, 1] = 0.0
    back = np.zeros((n, 3, 3), dtype=np.int8)
    o = _OFFSETS
    for k in range(1, n):
        x_prev2 = (P[k - 2] if k >= 2 else P[0]) + o[:, None, None]  # offsets i (k-2)
        x_prev = P[k - 1] + o[None, :, None]  # j (k-1)
        x = P[k] + o[None, None, :]  # l (k)
        step = x - x_prev
        ok = (np.abs(step) <= v_max) & (np.abs(step - (x_prev - x_prev2)) <= a_max)
        total = np.where(ok, cost[:, :, None], inf)  # (i, j, l)
        best_i = np.argmin(total, axis=0)  # (j, l)
        cost = np.take_along_axis(total, best_i[None], axis=0)[0] + err[k][None, :]
        back[k] = best_i
        if k == n - 1:  # the goal: offset 0, and the stop after it (a repeated setpoint) within 0x60C5
            stop = np.abs(P[k] + o[None, :] - (P[k - 1] + o[:, None])) <= a_max
            cost = np.where(stop & (o[None, :] == 0), cost, inf)
    if not np.isfinite(cost).any():
        return P
    last2, last = np.unravel_index(int(np.argmin(cost)), cost.shape)
    choice = np.zeros(n, dtype=np.int64)
    choice[n - 1], choice[n - 2] = last, last2
    for k in range(n - 1, 1, -1):
        choice[k - 2] = back[k, choice[k - 1], choice[k]]
    return P + o[choice]


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
    for rounds in range(1, opts.max_rounds + 1):
        smp = _sample(traj, axes, scale)
        results = []
        need = 1.0
        for i, axis in enumerate(axes):
            if axis.profile == "epos2_pvt":
                hint = None
                if last:  # the previous round's knots, stretched with the motion
                    prev = np.concatenate(([0], np.cumsum(last[i].records[1:-1, 2])))
                    hint = np.unique(np.rint(prev * smp.n_ms / last_n).astype(np.int64))
                res, k = _epos2_axis(axis, i, smp, opts, hint)
            else:
                res, k = _fixed_period_axis(axis, i, smp, opts)
            results.append(res)
            need = max(need, k)
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
        scale = math.ceil(duration_ms * scale - 1e-6) / duration_ms  # and end on a whole ms again
        if scale > opts.max_time_scale and duration_ms * (scale - 1.0) > opts.max_extra_ms:
            break
    worst = max(last, key=lambda a: max(a.velocity_ratio, a.acceleration_ratio))
    raise KnotError(
        f"{worst.name}: the drive's reconstruction still exceeds its limits (|v| {100 * worst.velocity_ratio:.2f}% "
        f"of 0x607F, |a| {100 * worst.acceleration_ratio:.2f}% of 0x60C5) after slowing down by "
        f"{scale:.4f} (max {opts.max_time_scale}, or {opts.max_extra_ms} ms)"
    )
