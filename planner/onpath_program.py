"""The on-path stop, pause, resume and override as records: the running program's change from ``t0`` on
(issue 37; planner side of ``axes.master.splice``).

Everything is in program time (``planner.program_motion``: s = the program's time, seconds). A change keeps
each axis's records up to the end of its last one the drive holds (``join_ms``) and appends records sampled
from the new motion from there: the knot at the join is the record the drive already has (the records join
with the same position and velocity), the next knots at ``t0`` (where the new motion leaves the old one),
where the new motion's acceleration jumps, at most ``MAX_SEGMENT_MS`` apart, and at its end. A fixed-period
axis's setpoints are the new motion's at its own period. The new motion's braking is made to end on the
records' common grid (a share of 0x60C5 a little lower, found by bisection), so that every axis is at rest
from the same SYNC and no cubic straddles the end of the braking (a cubic across an acceleration switch
overshoots it). The whole program, kept records and new, is then judged by the validator, like any program.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.axis import DriveAxis
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.planner.knots import fixed_period_kernels as fp_kernels
from pvtflow.planner.knots.fixed_period import _FP_REACH, reconstruction_kind
from pvtflow.planner.knots.samples import axis_constants
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk_profile
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.onpath_rejoin import NoRejoinError, rejoin_plan
from pvtflow.planner.onpath_stop import (
    OnPathStop,
    _s_at,
    brake_on_path,
    jerk_braking,
    jerk_braking_rates,
    jerk_change_rates,
    jerk_override,
    jerk_override_rates,
    joined,
    override,
)
from pvtflow.planner.path import PlanError
from pvtflow.planner.trajectory import Trajectory
from pvtflow.planner.validate import validate_program

# EPOS2 knots of a change: segments of 8-12 ms keep a count's rounding (6 * 0.5 qc / T^2) near 1 % of a
# typical 0x60C5 and the cubic's fit to the braking within a fraction of a count
MIN_SEGMENT_MS = 8
MAX_SEGMENT_MS = 12
# the EPOS2 knot spacings tried in turn (min, max ms) until an axis's records validate: shorter segments
# follow an acceleration switch closer, longer ones feel the rounding less
SPACINGS = ((MIN_SEGMENT_MS, MAX_SEGMENT_MS), (5, 8), (12, 24), (4, 6))
# the share of the joint accelerations the braking plans with: room for the records' rounding (the knot
# placement's repair of integers is not run on a change: it must be made within the look-ahead)
BRAKING_SHARE = 0.9
JUMP_SHARE = 0.02  # an acceleration jump of this share of 0x60C5 gets a knot of its own


class ChangeError(ValueError):
    """The change cannot be made into records that the drives take (the caller stops the quick way)."""


class NoRampError(ChangeError):
    """No jerk-limited ramp back to the planned speed holds the limits before the motion's end: none will at a
    lower share of them either (``jerk_change_rates`` tries lower rates already, down to a fifth; a lower share
    judges about the same rates harder)."""


def change_start_ms(t0_ms: float, join_ms: Sequence[float], axes: Sequence[AxisProgram]) -> float:
    """Where the new motion leaves the old one: ``t0``, or later where an EPOS2 axis's held records end
    less than ``MIN_SEGMENT_MS`` before it (the records from its join to the change would be a segment too
    short for its rounding: the change waits until the first knot after the join can be one)."""
    close = [
        j for j, a in zip(join_ms, axes, strict=True) if not a.profile.fixed_period and 0 < t0_ms - j < MIN_SEGMENT_MS
    ]
    return max([t0_ms, *(j + MIN_SEGMENT_MS for j in close)])


def scaled_limits(limits: JointLimits, share: float) -> JointLimits:
    return dataclasses.replace(limits, acceleration=np.asarray(limits.acceleration) * share)


def brake_on_grid(motion: Trajectory, t0_s: float, limits: JointLimits, grid_s: float) -> OnPathStop:
    """``brake_on_path`` from ``t0_s`` that comes to rest on the grid: at most ``BRAKING_SHARE`` of the
    joint accelerations, lowered until the rest falls on the next grid time (bisection on the share)."""
    hi = BRAKING_SHARE
    stop = brake_on_path(motion, t0_s, scaled_limits(limits, hi))
    target = math.ceil(stop.t_end / grid_s - 1e-9) * grid_s
    if abs(stop.t_end - target) < 1e-7:
        return stop
    lo = hi * 0.5
    best = None
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        trial = brake_on_path(motion, t0_s, scaled_limits(limits, mid), tries=1)
        if trial.t_end > target:
            lo = mid
        else:
            hi, best = mid, trial
        if best is not None and target - best.t_end < 2e-6:
            break
    if best is None:
        raise ChangeError("no braking on this path comes to rest on the SYNC grid")
    return best


# the drives' window jerk a change's records may reach, of the plan's jerk limit (the knot placement's
# ``KnotOptions.window_jerk_ratio``: the records' jumps in acceleration at every knot)
WINDOW_JERK_RATIO = 1.2


# the shares of the planned jerk limit a jerk-limited braking is tried with, in turn, until its records hold
# ``WINDOW_JERK_RATIO`` (the records' acceleration jumps at the knots add to the motion's own jerk)
JERK_SHARES = (0.9, 0.7, 0.5)


def brake_with_jerk_on_grid(
    motion: Trajectory,
    t0_s: float,
    limits: JointLimits,
    max_jerk: NDArray[np.float64],
    grid_s: float,
    jerk_share: float = JERK_SHARES[0],
) -> OnPathStop:
    """The jerk-limited on-path braking (``onpath_stop.jerk_braking_rates``: ``BRAKING_SHARE`` of 0x60C5,
    ``jerk_share`` of the jerk limit) that comes to rest on the grid: its deceleration and jerk lowered
    together (bisection) until the rest is a grid time."""
    decel, jerk = jerk_braking_rates(motion, t0_s, limits, max_jerk, BRAKING_SHARE, jerk_share)
    stop = jerk_braking(motion, t0_s, decel, jerk)
    target = t0_s + on_grid(stop.t_end - t0_s, grid_s)
    if target - stop.t_end < 2e-6:
        return stop
    lo, hi, best = 0.3, 1.0, None
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        trial = jerk_braking(motion, t0_s, decel * mid, jerk * mid)
        if trial.t_end > target:
            lo = mid
        else:
            hi, best = mid, trial
            if target - trial.t_end < 2e-6:
                break
    if best is None or target - best.t_end >= 2e-6:
        raise ChangeError("no jerk-limited braking on this path comes to rest on the SYNC grid")
    return best


def records_jerk_ratio(program: PvtProgram, max_jerk: NDArray[np.float64], from_ms: float) -> float:
    """The drives' 10-ms-window jerk of ``program``'s records from ``from_ms`` on, of ``max_jerk`` (joint
    units/s^3 per axis), at most: what the knot placement holds a jerk-limited plan's records to."""
    worst = 0.0
    for a, jmax in zip(program.axes, max_jerk, strict=True):
        if not np.isfinite(jmax):
            continue
        t, jerk = window_jerk_profile(a.reconstruction())
        jerk = jerk[t >= from_ms - WINDOW_MS]
        allowed = float(jmax) * abs(float(a.scaling.qc_per_joint_unit)) * 1e-9  # qc/ms^3
        if len(jerk):
            worst = max(worst, float(jerk.max()) / allowed)
    return worst


def tail_records(
    axis: AxisProgram,
    join_ms: float,
    t0_ms: float,
    motion: Trajectory,
    end_ms: float,
    jumps_ms: NDArray[np.float64],
    offset_ms: float = 0.0,
    spacing: tuple[int, int] = (MIN_SEGMENT_MS, MAX_SEGMENT_MS),
) -> NDArray[np.int64]:
    """The records of ``axis`` from ``join_ms`` (the end of its last kept record) to ``end_ms``, sampled from
    ``motion`` (its time 0 at program time ``offset_ms``), ending at rest; ``jumps_ms``: where ``motion``'s
    acceleration jumps (program time)."""
    j = next(i for i, n in enumerate(motion.joint_names) if n == axis.joint)
    sc = axis.scaling
    if axis.profile.fixed_period:
        period = float(axis.records[0, 2])
        n = round((end_ms - join_ms) / period)
        if n < 1:
            raise ChangeError(f"{axis.joint}: the change ends before its next setpoint")
        t = join_ms + period * np.arange(1, n + 1)
        q, qd = _states(motion, t - offset_ms, j)
        p = np.rint(sc.position_to_qc(q)).astype(np.int64)
        v = np.zeros(n, dtype=np.int64)
        if axis.profile.carries_velocity(axis.interpolation_submode):
            v = np.rint(sc.velocity_to_drive(qd)).astype(np.int64)
        v[-1] = 0
        p, v = _tracked(axis, join_ms, p, v, motion, offset_ms, j)
        rows = np.column_stack((p, v, np.full(n, int(period))))
        return np.vstack([rows, [[p[-1], 0, int(period)]]]).astype(np.int64)  # held at rest one more period
    knots = _knot_times(join_ms, t0_ms, end_ms, jumps_ms, spacing)
    if len(knots) < 2 or np.any(np.diff(knots) <= 0):
        raise ChangeError(f"{axis.joint}: the change ends before its next record could")
    q, qd = _states(motion, knots[1:] - offset_ms, j)
    p = np.rint(sc.position_to_qc(q)).astype(np.int64)
    v = np.rint(sc.velocity_to_drive(qd)).astype(np.int64)
    v[-1] = 0
    rows = np.column_stack((p, v, np.diff(knots).astype(np.int64)))
    return np.vstack([rows, [[p[-1], 0, 0]]]).astype(np.int64)  # the end record: interpolation ends


def _tracked(
    axis: AxisProgram,
    join_ms: float,
    p: NDArray[np.int64],
    v: NDArray[np.int64],
    motion: Trajectory,
    offset_ms: float,
    j: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """A fixed-period axis's new setpoints re-chosen among the integers around them where the drive's
    reconstruction of their rounding leaves a limit (the knot placement's ``track_fixed_period``, from the
    last kept setpoint, which stays), as a plan's are."""
    drive = DriveAxis(**{f.name: getattr(axis, f.name) for f in dataclasses.fields(DriveAxis)})
    period = int(axis.records[0, 2])
    k = round(join_ms / period) - 1  # the last kept setpoint
    if k < 0 or k >= len(axis.records):
        return p, v
    P = np.concatenate(([int(axis.records[k, 0])], p)).astype(np.int64)
    V = np.concatenate(([int(axis.records[k, 1])], v)).astype(np.int64)
    t_ms = np.arange(0.0, period * (len(P) - 1) + 1.0) + join_ms
    plan = np.ascontiguousarray(drive.scaling.position_to_qc(_states(motion, t_ms - offset_ms, j)[0]), dtype=float)
    f, _, _, v_units, pos_lo, pos_hi, rv_per, ra_per = (float(x[0]) for x in axis_constants((drive,)))
    kind = reconstruction_kind(drive)
    reach = _FP_REACH if kind == fp_kernels.CUBIC_P else 1
    P, V, _ = fp_kernels.track_fixed_period(kind, P, V, plan, period, f, rv_per, ra_per, pos_lo, pos_hi, v_units, reach)
    return P[1:], V[1:]


def _states(motion: Trajectory, t_ms: NDArray[np.float64], j: int) -> tuple[NDArray[np.float64], ...]:
    t = np.clip(np.asarray(t_ms, dtype=float) / 1000.0, 0.0, motion.duration)
    return motion.position(t)[:, j], motion.velocity(t)[:, j]


def _knot_times(
    join_ms: float,
    t0_ms: float,
    end_ms: float,
    jumps_ms: NDArray[np.float64],
    spacing: tuple[int, int] = (MIN_SEGMENT_MS, MAX_SEGMENT_MS),
) -> NDArray[np.int64]:
    """Whole-ms knots from the join to the end: t0, the acceleration jumps, at most MAX_SEGMENT_MS apart,
    none closer than MIN_SEGMENT_MS (the end kept, the knot before it dropped where they would be)."""
    join, end = round(join_ms), round(end_ms)
    wanted = sorted({round(t0_ms), *(round(t) for t in jumps_ms if join_ms < t < end_ms)})
    knots = [join]
    for t in [*wanted, end]:
        while t - knots[-1] > spacing[1]:
            gap = t - knots[-1]
            knots.append(knots[-1] + math.ceil(gap / math.ceil(gap / spacing[1])))
        if t - knots[-1] >= spacing[0]:
            knots.append(t)
    if knots[-1] != end:
        if len(knots) > 1 and end - knots[-2] <= 255:
            knots[-1] = end
        else:
            knots.append(end)
    return np.asarray(knots, dtype=np.int64)


def _fits(cell: str, axis: AxisProgram, max_jerk: NDArray[np.float64] | None, i: int, from_ms: float) -> bool | None:
    """None: the axis's records do not validate; True: they do and hold ``WINDOW_JERK_RATIO`` of its planned jerk
    limit from ``from_ms`` on (or it has none); False: they validate only."""
    one = PvtProgram(cell, (axis,))
    if not validate_program(one, sample_period_ms=None).ok:
        return None
    return max_jerk is None or records_jerk_ratio(one, max_jerk[i : i + 1], from_ms) <= WINDOW_JERK_RATIO


def changed_program(
    program: PvtProgram,
    first: Sequence[int],
    join_ms: Sequence[float],
    t0_ms: float,
    motion: Trajectory,
    end_ms: float,
    limits: JointLimits,
    offset_ms: float = 0.0,
    max_jerk: NDArray[np.float64] | None = None,
) -> tuple[PvtProgram, list[NDArray[np.int64]]]:
    """``program`` with each axis's records from ``first[i]`` on replaced by ``motion``'s (its time 0 at
    program time ``offset_ms``) from ``join_ms[i]`` to ``end_ms``, validated; (the new program, the new
    records per axis). ChangeError where the drives would not take it. ``max_jerk``: an axis's knot spacing is
    the first whose records also hold ``WINDOW_JERK_RATIO`` of it (else the first that validates)."""
    times, jumps = motion.acceleration_jumps()
    amax = np.asarray(limits.acceleration, dtype=float)
    big = np.any(np.abs(jumps) > JUMP_SHARE * amax, axis=1) if len(jumps) else np.zeros(0, dtype=bool)
    jumps_ms = np.asarray(times, dtype=float)[big] * 1000.0 + offset_ms
    rows: list[NDArray[np.int64]] = []
    axes = []
    for i, (a, k, jm) in enumerate(zip(program.axes, first, join_ms, strict=True)):
        taken = None
        for spacing in SPACINGS if not a.profile.fixed_period else SPACINGS[:1]:
            r = tail_records(a, jm, t0_ms, motion, end_ms, jumps_ms, offset_ms, spacing)
            axis = AxisProgram.of(a, np.concatenate((a.records[:k], r)))
            fit = _fits(program.cell, axis, max_jerk, i, t0_ms)
            if fit is not None:
                taken = taken or (r, axis)
                if fit:
                    taken = (r, axis)
                    break
        r, axis = taken or (r, axis)
        rows.append(r)
        axes.append(axis)
    changed = PvtProgram(program.cell, tuple(axes), {**program.metadata, "duration_ms": round(end_ms)})
    report = validate_program(changed, sample_period_ms=None)
    if not report.ok:
        raise ChangeError("the changed records do not validate: " + "; ".join(f.format() for f in report.errors[:3]))
    return changed, rows


def on_grid(duration_s: float, grid_s: float) -> float:
    """The grid time at or after ``duration_s``."""
    return math.ceil(duration_s / grid_s - 1e-9) * grid_s


def override_on_grid(
    planned: Trajectory,
    running: Trajectory,
    t0_s: float,
    scale: float,
    limits: JointLimits,
    grid_s: float,
    max_jerk: NDArray[np.float64] | None = None,
    jerk_share: float = JERK_SHARES[0],
) -> tuple[Trajectory, float]:
    """``override`` at ``scale`` joined to ``running`` at ``t0_s``, with the scale lowered by at most 3 % so
    that the motion ends on the grid (no cubic straddles its last deceleration); (the motion, the scale).
    The ramps to it take ``BRAKING_SHARE`` of the joint accelerations: the records' rounding needs that room
    (scale 1.0 itself: ``back_to_plan_on_grid``, which joins the planned records). ``max_jerk`` (a motion
    planned with a jerk limit): the ramp is the S-curve of ``jerk_override`` at ``jerk_share`` of it."""
    if max_jerk is None:
        limits = scaled_limits(limits, BRAKING_SHARE)

        def retimed(k: float) -> Trajectory:
            return joined(running, override(planned, running, t0_s, k, limits, rest_at_end=False))
    else:
        accel, jerk = jerk_override_rates(planned, running, t0_s, scale, limits, max_jerk, BRAKING_SHARE, jerk_share)

        def retimed(k: float) -> Trajectory:
            return joined(running, jerk_override(planned, running, t0_s, k, accel, jerk))

    whole = retimed(scale)
    target = on_grid(whole.duration, grid_s)
    if target - whole.duration < 2e-6:
        return whole, scale
    lo, hi, best = max(0.05, scale * 0.97), scale, None
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        trial = retimed(mid)
        if trial.duration > target:
            lo = mid
        else:
            hi, best = mid, (trial, mid)
            if target - trial.duration < 2e-6:
                break
    if best is None:
        raise ChangeError(f"no scale near {scale:g} ends the motion on the SYNC grid")
    return best


# --- back to the planned timing (override 1.0) ------------------------------------------------------------
# the original records a change joins, tried in turn per axis: the first that ends after the ramp, and later ones
JOIN_TRIES = 4


@dataclass(frozen=True)
class BackToPlan:
    """The running motion brought back to the planned timing: ``motion`` (program time) is the planned one
    delayed by ``delay_ms`` (on the grid, plus the phase asked for) from path position ``s_ms`` (program ms of
    the plan) on."""

    motion: Trajectory
    s_ms: float
    delay_ms: float


def _delay(whole: Trajectory, planned: Trajectory, s0: float) -> tuple[float, float] | None:
    """(where the re-timed motion is on the planned timing again, its delay there), seconds; None where it
    does not reach the planned speed before the end."""
    grid, sd = whole.gridpoints, whole.sd
    off = np.abs(sd[:-1] - 1.0) > 1e-9
    after = np.nonzero(off & (grid[:-1] >= s0 - 1e-12))[0]
    i = int(after[-1]) + 1 if len(after) else int(np.searchsorted(grid, s0 - 1e-12))
    if i >= len(grid) - 2:
        return None
    s1 = float(grid[i])
    return s1, float(whole.time_at(np.array([s1]))[0]) - s1


# the shares of 0x60C5 the ramp back to the planned speed is tried with, in turn: where it reaches the plan, the
# joints' acceleration jumps by the ramp's part of it, which a record's cubic across it overshoots
RAMP_SHARES = (BRAKING_SHARE, 0.6, 0.35)
# the ramp limited by acceleration only (override 1.0 and resume of a motion planned without a jerk limit): all of
# 0x60C5 first, no share of it given away where the records take it (on every gantry cell they validate at 1.0
# wherever at 0.9, bench/RESULTS.md); a lower share where they do not, each try a few ms of the look-ahead
BACK_RAMP_SHARES = (1.0, *RAMP_SHARES)


def back_to_plan_on_grid(
    planned: Trajectory,
    running: Trajectory,
    t0_s: float,
    limits: JointLimits,
    grid_s: float,
    share: float = BRAKING_SHARE,
    phase_s: float = 0.0,
    max_jerk: NDArray[np.float64] | None = None,
    jerk_share: float = JERK_SHARES[0],
) -> BackToPlan:
    """``override`` at 1.0 from ``t0_s``: the largest path acceleration (``share`` of the joints', lowered by
    bisection) up to the planned speed, reached where the motion is late on the plan by a whole number of grid
    steps (plus ``phase_s``: a resume's rest, which need not be a grid time), so that from there the planned
    records run unchanged, that much later. ``max_jerk`` (a motion planned with a jerk limit): the ramp is the
    S-curve of ``jerk_override`` at ``jerk_share`` of it, its acceleration and jerk lowered together."""
    s0 = _s_at(running, t0_s)
    if max_jerk is None:
        return _back_on_grid(planned, running, t0_s, limits, grid_s, share, phase_s, s0, None)
    rates = jerk_change_rates(planned, running, t0_s, 1.0, limits, max_jerk, share, jerk_share)
    if not rates:
        raise NoRampError("no jerk-limited ramp back to the planned speed holds the limits before the motion's end")
    failed = ChangeError("no ramp back to the planned speed ends on the SYNC grid")
    for accel, jerk in rates[:RATE_TRIES]:
        try:
            return _back_on_grid(planned, running, t0_s, limits, grid_s, share, phase_s, s0, (accel, jerk))
        except ChangeError as exc:
            failed = exc
    raise failed


# the jerk-limited ramps back to the planned speed (``jerk_change_rates``, the soonest first) tried in turn to end
# on the SYNC grid
RATE_TRIES = 3


def _back_on_grid(
    planned: Trajectory,
    running: Trajectory,
    t0_s: float,
    limits: JointLimits,
    grid_s: float,
    share: float,
    phase_s: float,
    s0: float,
    rates: tuple[float, float] | None,
) -> BackToPlan:
    """``back_to_plan_on_grid`` with the jerk-limited ramp's ``rates`` (None: limited by acceleration only): the
    ramp's rates lowered together (bisection) until its delay is on the grid."""

    def at(f: float) -> tuple[Trajectory, tuple[float, float] | None]:
        if rates is None:
            change = override(planned, running, t0_s, 1.0, scaled_limits(limits, f), tries=1)
        else:
            try:
                change = jerk_override(planned, running, t0_s, 1.0, rates[0] * f / share, rates[1] * f / share)
            except PlanError:  # too slow to reach the planned speed before the end
                return running, None
        whole = joined(running, change)
        return whole, _delay(whole, planned, s0)

    hi = share
    whole, d = at(hi)
    if d is None:
        raise ChangeError("the motion does not reach its planned speed again before its end")
    target = on_grid(d[1] - phase_s, grid_s) + phase_s
    if target - d[1] >= 2e-6:
        lo, best = hi * 0.3, None
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            trial, dt = at(mid)
            if dt is None or dt[1] > target:
                lo = mid
            else:
                hi, best = mid, (trial, dt)
                if target - dt[1] < 2e-6:
                    break
        if best is None or target - best[1][1] >= 2e-6:
            raise ChangeError("no ramp back to the planned speed ends on the SYNC grid")
        whole, d = best
    return BackToPlan(whole, d[0] * 1000.0, float(round(target * 1000.0)) if phase_s == 0.0 else target * 1000.0)


# the shares of the jerk limit a re-timing that joins the plan later (``rejoin_on_grid``) is tried with, in turn: the
# records sampled from it add the rounding of their integers to its jerk (up to some 0.45 x the limit on gantry3's z);
# all of it last, where no lower share joins (a curved path's last deceleration, the plan itself at its jerk limit
# there: arm6's second joint at 1.15 x its limit over the drives' window; the records' window check judges)
REJOIN_JERK_SHARES = (0.7, 0.5, 1.0)


class NoJoinError(ChangeError):
    """No re-timing joins the plan within this share of the jerk limit: none will within a lower one either."""


def rejoin_on_grid(
    planned: Trajectory,
    running: Trajectory,
    t0_s: float,
    limits: JointLimits,
    max_jerk: NDArray[np.float64],
    grid_ms: int,
    jerk_share: float = REJOIN_JERK_SHARES[0],
    in_time: Callable[[], bool] | None = None,
    phase_s: float = 0.0,
) -> BackToPlan:
    """``override`` at 1.0 from ``t0_s`` for a motion planned with a jerk limit where no S-curve in path speed holds
    it (``back_to_plan_on_grid`` found none): the rest of the path re-timed to join the plan delayed by the fewest grid
    steps (``onpath_rejoin.rejoin_plan``, ``BRAKING_SHARE`` of 0x60C5, ``jerk_share`` of the jerk limit), from where
    the planned records run unchanged (``phase_s``: a resume's, as ``back_to_plan_on_grid``). ChangeError where none
    joins it before its end (or not ``in_time``)."""
    try:
        whole, s_join, delay = rejoin_plan(
            planned, running, t0_s, limits, max_jerk, grid_ms / 1000.0, BRAKING_SHARE, jerk_share, in_time, phase_s
        )
    except NoRejoinError as exc:
        raise NoJoinError(f"re-timed to join the plan: {exc}") from None
    return BackToPlan(whole, s_join * 1000.0, float(round(delay * 1000.0)) if phase_s == 0.0 else delay * 1000.0)


def rejoined_program(
    program: PvtProgram,
    first: Sequence[int],
    join_ms: Sequence[float],
    t0_ms: float,
    back: BackToPlan,
    original: PvtProgram,
    limits: JointLimits,
    offset_ms: float = 0.0,
    max_jerk: NDArray[np.float64] | None = None,
) -> tuple[PvtProgram, list[NDArray[np.int64]]]:
    """``program`` with each axis's records from ``first[i]`` on replaced by ``back.motion``'s ramp from
    ``join_ms[i]`` to the end of one of ``original``'s records after the ramp (that record's own position
    and velocity, ``back.delay_ms`` later), then ``original``'s records from there on, unchanged; validated.
    ``offset_ms``: the program time of ``back.motion``'s time 0 (a resumed motion's program begins later);
    ``max_jerk``: the first join and spacing whose records hold ``WINDOW_JERK_RATIO`` of it (else the first that
    validates)."""
    times, jumps = back.motion.acceleration_jumps()
    amax = np.asarray(limits.acceleration, dtype=float)
    big = np.any(np.abs(jumps) > JUMP_SHARE * amax, axis=1) if len(jumps) else np.zeros(0, dtype=bool)
    jumps_ms = np.asarray(times, dtype=float)[big] * 1000.0 + offset_ms
    shift = float(round(back.delay_ms + offset_ms))  # an original record's end, plan ms -> this program's ms
    rows: list[NDArray[np.int64]] = []
    axes = []
    for i, (a, k, jm, o) in enumerate(zip(program.axes, first, join_ms, original.axes, strict=True)):
        recs = o.records[:-1] if not o.profile.fixed_period and o.records[-1, 2] == 0 else o.records
        ends = np.cumsum(recs[:, 2]).astype(float)
        fixed = o.profile.fixed_period
        least = max(back.s_ms, jm - shift + (0 if fixed else MIN_SEGMENT_MS))
        start = int(np.searchsorted(ends, least - 1e-9))  # the first original record ending after the ramp
        made, held = None, False
        for m in range(start, min(start + JOIN_TRIES, len(recs))):
            end = float(ends[m]) + shift
            for spacing in SPACINGS if not fixed else SPACINGS[:1]:
                try:
                    r = tail_records(a, jm, t0_ms, back.motion, end, jumps_ms[jumps_ms < end], offset_ms, spacing)
                except ChangeError:
                    continue
                r = r[:-1].copy()  # without the rest it would end with
                r[-1, :2] = recs[m, :2]
                r = np.vstack((r, recs[m + 1 :], *([[[recs[-1, 0], 0, 0]]] if not fixed else [])))
                axis = AxisProgram.of(a, np.concatenate((a.records[:k], r)))
                fit = _fits(program.cell, axis, max_jerk, i, t0_ms)
                if fit is not None:
                    made = made or (r, axis)
                    if fit:
                        made, held = (r, axis), True
                        break
            if held:
                break
        if made is None:
            raise ChangeError(f"{a.joint}: no join to the planned records validates")
        rows.append(made[0])
        axes.append(made[1])
    duration = max(float(np.sum(x.records[:, 2])) for x in axes)
    changed = PvtProgram(program.cell, tuple(axes), {**program.metadata, "duration_ms": round(duration)})
    report = validate_program(changed, sample_period_ms=None)
    if not report.ok:
        raise ChangeError("the changed records do not validate: " + "; ".join(f.format() for f in report.errors[:3]))
    return changed, rows


def resume_from_rest(planned: Trajectory, paused: OnPathStop, limits: JointLimits) -> Trajectory:
    """The fastest motion from rest where ``paused`` ended to the end of ``planned`` along its path, within its
    timing: the largest path acceleration the joints allow (all of 0x60C5, lowered only where the dense check
    between gridpoints needs it) until the planned path speed, then the plan's own (``onpath_stop.resume`` with
    none of 0x60C5 kept back). Under the plan's speed every constraint the plan held holds, and s'' = 0 is always
    feasible there (|q''(s)| s'^2 <= what the plan held at s' = 1), so the greedy pass is the time-optimal timing
    of the rest of the path with the plan's speed as its bound. For the knot placement (``build_program``, whose
    integer repair holds 0x60C5 as for any plan) where the rest of the path is too short to reach the planned
    speed again and join its records; time 0 = the resume."""
    running = paused.trajectory
    return override(planned, running, running.duration, 1.0, limits, rest_at_end=False, share=1.0)


# the shares of the planned path speed a jerk-limited resume from rest (``jerk_resume_from_rest``) is tried at
RESUME_SCALES = (1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.05)


def jerk_resume_from_rest(
    planned: Trajectory,
    paused: OnPathStop,
    limits: JointLimits,
    max_jerk: NDArray[np.float64],
    share: float = BRAKING_SHARE,
    jerk_share: float = JERK_SHARES[0],
) -> tuple[Trajectory, float]:
    """A motion planned with a jerk limit resumed from rest where ``paused`` ended to the end of ``planned``
    where the ramp back to the planned speed cannot join its records within the limit (the rest begins near or
    in the plan's own deceleration, which the ramp's path acceleration would add jerk to): the S-curve from rest
    to a share of the planned speed whose change holds ``share`` of 0x60C5 and ``jerk_share`` of the jerk limit
    (``jerk_change_rates``, its fastest), then that speed to the end (its joint jerk is the plan's times the
    share cubed). The share is the one of ``RESUME_SCALES`` that ends soonest (a higher one needs a gentler
    change: not always sooner), looked for until two in turn end later; (the motion, time 0 = the resume; the
    share). ChangeError where none holds."""
    running, t0 = paused.trajectory, paused.trajectory.duration
    best: tuple[Trajectory, float] | None = None
    later = 0
    for scale in RESUME_SCALES:
        rates = jerk_change_rates(planned, running, t0, scale, limits, max_jerk, share, jerk_share)
        if not rates:
            continue
        motion = jerk_override(planned, running, t0, scale, *rates[0])
        if best is None or motion.duration < best[0].duration:
            best, later = (motion, scale), 0
        elif (later := later + 1) >= 2:
            break
    if best is None:
        raise ChangeError("no jerk-limited motion from rest reaches the end of the paused motion within the limits")
    return best


def resumed_program(
    paused: PvtProgram,
    back: BackToPlan,
    original: PvtProgram,
    rest_ms: float,
    limits: JointLimits,
    grid_ms: int,
    max_jerk: NDArray[np.float64] | None = None,
) -> PvtProgram:
    """The program that continues a paused motion at its planned timing: from where ``paused`` left the axes
    at rest (``back.motion``'s rest at program time ``rest_ms``), after a dwell of one grid step (every axis's
    first motion on the same SYNC), ``back``'s ramp up to the planned speed (``back_to_plan_on_grid`` from the
    rest, its delay on the grid plus the rest's phase on it), then ``original``'s own records to the motion's
    end. Its time 0 is the resume; ChangeError where it does not validate."""
    dwell = float(grid_ms)
    axes, first, joins = [], [], []
    for a in paused.axes:
        p = int(a.records[-1, 0])
        if a.profile.fixed_period:
            period = int(a.records[0, 2])
            head = np.array([[p, 0, period]] * max(1, round(dwell / period)), dtype=np.int64)
        else:
            head = np.array([[p, 0, int(dwell)]], dtype=np.int64)
        axes.append(AxisProgram.of(a, head))
        first.append(len(head))
        joins.append(float(head[:, 2].sum()))
    start = PvtProgram(paused.cell, tuple(axes), dict(paused.metadata))
    program, _ = rejoined_program(start, first, joins, dwell, back, original, limits, dwell - rest_ms, max_jerk)
    return program
