"""The drive's window jerk at the records: integers chosen for it (EPOS2 PVT, with a jerk limit).

A record's position and velocity are integers, and the drive's cubics on both sides of it take
their end accelerations from them: a count moves them by 6/T^2 (in opposite directions where the
two segments differ in length), a velocity unit by 4 f/T each, the same way. On segments of
15-30 ms at a jerk limit of a few x 0x60C5 per second that is as much as the whole room between
the plan's jerk and what the drive may do over 10 ms. So where the drive's 10-ms-window jerk
(``planner.knots.window_jerk``) is over what the limit allows, each record there may move by a
count and two velocity units: the nudge that lowers the worst window around it most, as long as
both its segments stay within the tolerance of the plan at every ms and inside 0x607F, 0x60C5
and 0x607D (coordinate descent, a few passes; exact where it judges: every ms of the segments,
their closed-form extrema).

The loop is compiled: ``planner.smooth_kernels``.
"""

from __future__ import annotations

import numpy as np

from pvtflow.axes.drive.interpolation import exceeds
from pvtflow.planner.knots.check import check_records, jerk_scale, needed_scale
from pvtflow.planner.knots.flat import Flat
from pvtflow.planner.knots.types import AxisKnots, KnotOptions
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk
from pvtflow.planner.smooth_kernels import smooth_records


def smoothed_axis(fl: Flat, placed: tuple[AxisKnots, float], opts: KnotOptions) -> tuple[AxisKnots, float]:
    """``placed`` (the records of ``fl``'s one axis) with its records nudged for the window jerk,
    if that needs less slow-down; judged again by the drive's exact reconstruction."""
    allowed = float(fl.window_jerk[0])
    if not (np.isfinite(allowed) and placed[0].jerk_ratio > 1.0):
        return placed
    f = float(fl.f[0])
    rows = smooth_records(
        placed[0].records,
        f,
        fl.p,
        opts.tolerance_qc,
        float(fl.vmax[0]),
        float(fl.amax[0]),
        float(fl.pos_lo[0]),
        float(fl.pos_hi[0]),
        allowed,
        int(WINDOW_MS),
    )
    chk, recon = check_records(fl.axes[0], rows, fl.p)
    if chk.position_out.any() or exceeds(chk.seg_deviation, opts.tolerance_qc).any():
        return placed
    rv, ra = float(chk.velocity_ratio.max()), float(chk.acceleration_ratio.max())
    rj = window_jerk(recon) / allowed
    moved = AxisKnots(fl.axes[0].joint, rows, chk.deviation, rv, ra, rj), max(needed_scale(rv, ra), jerk_scale(rj))
    return moved if moved[1] < placed[1] else placed


def warm_up() -> None:
    """Load the compiled loop (numba's cache), as a service does at start: a warm-up move rarely
    needs a nudge, and a first real plan would pay the load inside its budget."""
    rows = np.array([[0, 0, 1], [10, 1, 10], [20, 0, 10], [20, 0, 0]], dtype=np.int64)
    smooth_records(rows, 0.03, np.linspace(0.0, 20.0, 21), 1.0, 1e9, 1e9, -1e9, 1e9, 0.0, int(WINDOW_MS))
