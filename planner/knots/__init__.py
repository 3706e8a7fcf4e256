"""PVT knot placement: from a timed trajectory to integer records the drive executes as they are.

The drive does not execute the planner's curve: it rebuilds the motion from the records with its
own interpolation (axes.drive.interpolation), from integer ms, integer velocity units and integer
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
   shortest path over the candidates, ``quantize_kernels.repair_chains``). Integers need an integer
   search: a continuous optimum is only as good as its rounding;
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
gets the records it would get alone, and leaves as soon as it is done (its knots are dropped; the
samples stay where they are, no copy). Work that repeats is not redone: the check evaluates only
the segments whose cubic changed, the least-squares fit reuses the right-hand side of every
unchanged segment and re-evaluates a segment's fit only where its verdict could change, and the
repair takes a chain's records from the last round's search where the chain's records are the
same (``quantize_kernels.repair_chains_memo``: the search reads nothing else).

Fixed-period profiles take one record per period and are checked by their own reconstruction
(linear, or Parker's cubic submodes) the same way. All numbers here are in drive units: qc,
velocity units (qc/ms inside the interpolation), ms.

Where each step lives: ``types`` (what goes in and out), ``samples`` (the plan at every drive ms),
``refine`` (steps 1-2), ``quantize`` (step 3), ``check`` (step 4), ``flat`` (the EPOS2 axes as one
problem), ``epos2`` (steps 1-4 for the EPOS2 axes), ``fixed_period`` (the other profiles), and
step 5, ``place_knots``, here. A step's per-segment loops, compiled with numba, sit beside it as
``<step>_kernels`` (``check_kernels`` also holds the judgements of a segment the others share).
A round of steps 2-4 is a few compiled calls, not a numpy call per array operation: the
least-squares fits and their splits (``refine_kernels.fit_rounds``), rounding, check and repair
(``round_kernels.round_check_repair``), what the round splits (``round_kernels.split_verdict``),
an axis's records read back (``records_kernels``). A plan's placement makes a few tens of them;
the Python around them only decides which axes are done.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pvtflow.planner.knots.check import record_knots
from pvtflow.planner.knots.epos2 import epos2_axes
from pvtflow.planner.knots.fixed_period import drive_slowdown, fixed_period_axis
from pvtflow.planner.knots.samples import sample_trajectory
from pvtflow.planner.knots.types import AxisKnots, DriveAxis, KnotError, KnotOptions, KnotResult, TimedTrajectory

__all__ = ["AxisKnots", "DriveAxis", "KnotError", "KnotOptions", "KnotResult", "TimedTrajectory", "place_knots"]


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
    least = drives = 1.0  # the slow-downs the fixed-period drives alone call for (``drive_slowdown``)
    fixed = [i for i, a in enumerate(axes) if a.profile.fixed_period]
    epos2 = [i for i, a in enumerate(axes) if not a.profile.fixed_period]
    if fixed:
        smp = sample_trajectory(traj, axes, scale, opts.max_jerk, opts.window_jerk_ratio)
        for i in fixed:
            k_least, k_drive = drive_slowdown(axes[i], i, smp)
            least, drives = max(least, scale * k_least), max(drives, scale * k_drive)
        if least > scale:  # no integers make less: no round below it
            scale = math.ceil(duration_ms * least - 1e-6) / duration_ms
    for rounds in range(1, opts.max_rounds + 1):
        smp = sample_trajectory(traj, axes, scale, opts.max_jerk, opts.window_jerk_ratio)
        placed: dict[int, tuple[AxisKnots, float]] = {}
        if epos2:
            hints = None
            if last:  # the previous round's knots, stretched with the motion
                hints = []
                for i in epos2:
                    prev = record_knots(last[i].records)
                    hints.append(np.unique(np.rint(prev * smp.n_ms / last_n).astype(np.int64)))
            placed.update(zip(epos2, epos2_axes([axes[i] for i in epos2], epos2, smp, opts, hints), strict=True))
        for i in fixed:
            placed[i] = fixed_period_axis(axes[i], i, smp, opts)
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
        # interpolation of this plan calls for (a plan that asks more than they can take); a round
        # that would pass it tries the limit itself first (the growth per round can step over all of
        # the room left: a jerk-limited plan's window jerk fell within its allowance at 1.05, where
        # the rounds went 1.03 -> 1.07)
        if scale > opts.max_time_scale * drives and duration_ms * (scale - drives) > opts.max_extra_ms:
            most = max(opts.max_time_scale * drives, drives + opts.max_extra_ms / duration_ms)
            most = math.floor(duration_ms * most + 1e-6) / duration_ms
            if most <= smp.scale + 1e-12:
                break
            scale = most
    worst = max(last, key=lambda a: max(a.velocity_ratio, a.acceleration_ratio))
    beyond = f" beyond the {drives:.4f} the drives' interpolation of this plan calls for" if drives > 1.0 else ""
    raise KnotError(
        f"{worst.name}: the drive's reconstruction still exceeds its limits (|v| {100 * worst.velocity_ratio:.2f}% "
        f"of 0x607F, |a| {100 * worst.acceleration_ratio:.2f}% of 0x60C5) after slowing down by "
        f"{scale:.4f} (max {opts.max_time_scale}{beyond}, or {opts.max_extra_ms} ms)"
    )
