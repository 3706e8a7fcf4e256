"""Step 3: knot positions and velocities to the drive's integers, and the exact integer repair of
the records around a segment whose rounding crossed a limit."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import exceeds
from pvtflow.axes.drive.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN
from pvtflow.planner.knots import quantize_kernels as kernels
from pvtflow.planner.knots import records_kernels, round_kernels
from pvtflow.planner.knots.check import (
    NO_FLOAT,
    NO_INT,
    Check,
    Checked,
    axis_records,
    check_knots,
    over_limit,
    record_knots,
)
from pvtflow.planner.knots.flat import Flat
from pvtflow.planner.knots.types import AxisKnots, DriveAxis, KnotError, KnotOptions


def round_positions(p: NDArray[np.float64], axis: DriveAxis) -> NDArray[np.int64]:
    lim = axis.limits
    r = np.rint(p)
    if np.any(r < INT32_MIN) or np.any(r > INT32_MAX):
        raise KnotError(f"{axis.joint}: the motion leaves the int32 position range of a record")
    return np.clip(r, lim.min_position_qc, lim.max_position_qc).astype(np.int64)


def round_velocities(v_qc_per_ms: NDArray[np.float64], axis: DriveAxis) -> NDArray[np.int64]:
    s = axis.scaling
    v_max = math.floor(axis.limits.max_profile_velocity_rpm / s.velocity_unit_rpm + 1e-9)  # 0x607F in units
    v = np.clip(np.rint(v_qc_per_ms / s.qc_per_ms_per_velocity_unit), -v_max, v_max)
    if np.any(v < INT24_MIN) or np.any(v > INT24_MAX):
        raise KnotError(f"{axis.joint}: a velocity does not fit the int24 of a record (velocity unit too fine?)")
    return v.astype(np.int64)


def round_knots(
    fl: Flat, knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Knot positions to counts (inside 0x607D), velocities to the drive's unit (inside 0x607F)."""
    ax = fl.axis_of(knots)
    r = np.rint(p)
    out = (r < INT32_MIN) | (r > INT32_MAX)
    if out.any():
        raise KnotError(f"{fl.axes[ax[np.argmax(out)]].joint}: the motion leaves the int32 position range of a record")
    P = np.clip(r, fl.pos_lo[ax], fl.pos_hi[ax]).astype(np.int64)
    V = np.clip(np.rint(v / fl.f[ax]), -fl.v_units[ax], fl.v_units[ax])
    out = (V < INT24_MIN) | (V > INT24_MAX)
    if out.any():
        raise KnotError(
            f"{fl.axes[ax[np.argmax(out)]].joint}: a velocity does not fit the int24 of a record "
            "(velocity unit too fine?)"
        )
    V[fl.is_end(knots)] = 0
    return P, V.astype(np.int64)


_REPAIR_REACH = 2  # knots on either side of a segment over a limit whose records the repair may move


_MAX_SHIFT_MS = 3  # how far the last try before a slow-down may move a knot


def repair_rounds(
    fl: Flat,
    knots: NDArray[np.int64],
    P: NDArray[np.int64],
    V: NDArray[np.int64],
    checked: Checked,
    tol: float,
    shift: int = 0,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], Checked]:
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
    within the tolerance (``quantize_kernels.repair_chains``: a shortest path over the nudges, exact,
    not greedy). With
    ``shift`` the knots may also move by up to that many ms (the integers of a cubic of another
    length make other accelerations).
    """
    per_axis = (fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.v_units)
    for _ in range(_REPAIRS):
        over = over_limit(checked.chk)
        if not over.any():
            break
        # repaired in place; ``checked`` keeps the records it judged
        knots, P, V = (knots.copy() if shift else knots), P.copy(), V.copy()
        segments = np.flatnonzero(over)
        if not kernels.repair_chains(
            knots, P, V, segments, _REPAIR_REACH, shift, fl.stride, *per_axis, fl.p, fl.v, tol
        ):
            break
        checked = check_knots(fl, knots, P, V, checked)
    return knots, P, V, checked


_REPAIRS = 3  # repair rounds of ``repair_rounds``: the repair judges deviations at probes, the check at every ms


def quantize_checked(
    fl: Flat,
    knots: NDArray[np.int64],
    p: NDArray[np.float64],
    v: NDArray[np.float64],
    prev: Checked | None,
    tol: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], Checked]:
    """``round_knots``, ``check_knots`` (reusing ``prev``) and ``repair_rounds`` of the knots in one
    compiled call (``round_kernels.round_check_repair``): the records and their check. A chain
    whose records are those of a chain ``prev``'s round repaired gets that repair's records
    without the search (``quantize_kernels.repair_chains_memo``: the same inputs, the same answer)."""
    if prev is None:
        old = (NO_INT, NO_INT, NO_INT, NO_FLOAT, NO_FLOAT, NO_FLOAT, np.zeros(0, dtype=bool))
        memo = (kernels.NO_MEMO_AT, kernels.NO_MEMO_ROWS)
    else:
        c = prev.chk
        old = (prev.knots, prev.P, prev.V, c.seg_deviation, c.velocity_ratio, c.acceleration_ratio, c.position_out)
        memo = prev.memo
    err, at, P, V, cP, cV, dev, rv, ra, out, *kept = round_kernels.round_check_repair(
        knots, p, v, fl.stride, fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.v_units, fl.p, fl.v, tol,
        _REPAIR_REACH, _REPAIRS, *old, *memo,
    )  # fmt: skip
    if err == round_kernels.POSITION_RANGE:
        joint = fl.axes[fl.axis_of(knots[at])].joint
        raise KnotError(f"{joint}: the motion leaves the int32 position range of a record")
    if err == round_kernels.VELOCITY_RANGE:
        raise KnotError(
            f"{fl.axes[fl.axis_of(knots[at])].joint}: a velocity does not fit the int24 of a record "
            "(velocity unit too fine?)"
        )
    return P, V, Checked(knots, cP, cV, Check(dev, rv, ra, out), (kept[0], kept[1]))


def shifted_records(fl: Flat, placed: tuple[AxisKnots, float], opts: KnotOptions) -> tuple[AxisKnots, float]:
    """The records of ``fl``'s one axis with the knots around its segments over a limit moved by up
    to ``_MAX_SHIFT_MS`` where that brings them inside (and within the tolerance): the last try
    before the whole motion is slowed down. A ms first, further only where that is not enough
    (the search grows with the square of the candidates). ``placed`` if it does not help."""
    records = placed[0].records
    knots0 = record_knots(records)
    P0, V0 = records[:-1, 0].copy(), records[:-1, 1].copy()
    checked0 = check_knots(fl, knots0, P0, V0)
    for shift in range(1, _MAX_SHIFT_MS + 1):  # each from the placed records: the search of that reach
        knots, P, V, checked = repair_rounds(fl, knots0, P0, V0, checked0, opts.tolerance_qc, shift)
        if not over_limit(checked.chk).any():
            break
    chk = checked.chk
    if chk.position_out.any() or exceeds(chk.seg_deviation, opts.tolerance_qc).any():
        return placed
    moved = axis_records(fl, 0, knots, P, V, chk, opts.dwell_ms)
    return moved if moved[1] < placed[1] else placed


def warm_up() -> None:
    """Load the repair's and the check's compiled loops with the types the placement's own calls
    pass (numba's cache), as a service does at start: a warm-up move rarely needs the repair that
    may move knots, and a first real plan would pay the load (on a new machine the compilation,
    seconds) inside its budget. tests/service/test_warm_up.py holds every kernel to this."""
    one = np.ones(1)
    plan = np.linspace(0.0, 10.0, 21)
    fl = Flat((), 21, plan, np.full(21, 0.5), one, one, one, 1e3 * one, -1e9 * one, 1e9 * one, one, one,
              np.full(1, np.inf), np.arange(1))  # fmt: skip
    knots = np.array([0, 10, 20], dtype=np.int64)
    P, V = np.array([0, 5, 10], dtype=np.int64), np.array([0, 1, 0], dtype=np.int64)
    checked = check_knots(fl, knots, P, V)
    per_axis = (fl.f, fl.rv_per, fl.ra_per, fl.pos_lo, fl.pos_hi, fl.v_units)
    for shift in (0, 1):
        segments = np.flatnonzero(np.ones(2, dtype=bool))
        kernels.repair_chains(
            knots.copy(), P.copy(), V.copy(), segments, _REPAIR_REACH, shift, fl.stride, *per_axis, fl.p, fl.v, 1.0
        )
    check_knots(fl, knots, P, V, checked)
    # one axis's records read back (a placement reads all axes in one call; the shifted and the
    # jerk-smoothed records one axis at a time)
    chk = checked.chk
    records_kernels.axis_records(
        knots, P, V, fl.stride, 0, 1, chk.seg_deviation, chk.velocity_ratio, chk.acceleration_ratio
    )
