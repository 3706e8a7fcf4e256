"""EPOS2 PVT: steps 1-4 for all the EPOS2 axes of a plan at once (see the package docstring)."""

from __future__ import annotations

from collections.abc import Sequence
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import epos2_pvt
from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.knots.check import NO_INT, Checked, axes_records, checked_subset, knot_records
from pvtflow.planner.knots.flat import Flat
from pvtflow.planner.knots.jerk_smooth import smoothed_axis
from pvtflow.planner.knots.quantize import quantize_checked, shifted_records
from pvtflow.planner.knots.refine import Fitted, fit_knots, fitted_subset, lsq_fit, refine, split_segments
from pvtflow.planner.knots.refine_kernels import switch_flat_knots
from pvtflow.planner.knots.round_kernels import split_verdict
from pvtflow.planner.knots.samples import Samples
from pvtflow.planner.knots.types import AxisKnots, DriveAxis, KnotOptions
from pvtflow.planner.knots.window_jerk import segments_over

_COARSE = 4.0  # first cut: exact-sample cubics to this multiple of the fit target (cheap), then least squares


_MIN_SPLIT_MS = 12  # segments shorter than twice this are not split for a limit (rounding grows as 1/T^2)

_NOT_YET = np.iinfo(np.int64).max  # an axis's segments over a limit before its first check


def jerk_segments(
    fl: Flat, knots: NDArray[np.int64], P: NDArray[np.int64], V: NDArray[np.int64], dwell_ms: int
) -> NDArray[np.int64]:
    """The knot segments, over every axis with a jerk limit, that a 10-ms window of the drive's
    reconstruction over the allowed jerk touches (``window_jerk.segments_over``)."""
    out = []
    for a in fl.busy[np.isfinite(fl.window_jerk[fl.busy])]:
        records = knot_records(fl, int(a), knots, P, V, dwell_ms)
        s = segments_over(epos2_pvt(records, float(fl.f[a])), float(fl.window_jerk[a]))
        s = s[(s >= 1) & (s <= len(records) - 2)]  # not the dwell: the knot segments
        out.append(np.searchsorted(knots, a * fl.stride) + s - 1)
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


class Start(Enum):
    """Where the knots of a placement come from before the splits."""

    HINT = "hint"  # the knots of a previous, faster round, then least-squares fits
    LEAST_SQUARES = "least_squares"  # switch knots, a coarse cut with exact-sample cubics, least-squares fits
    EXACT = "exact"  # switch knots, cubics through the exact samples (more records, more room for repair)


def place_epos2(
    fl: Flat,
    smp: Samples,
    cols: Sequence[int],
    opts: KnotOptions,
    start: Start,
    initial: Sequence[NDArray[np.int64]] | None = None,
) -> list[tuple[AxisKnots, float]]:
    """Records of the axes of ``fl`` (columns ``cols`` of ``smp``), and the slow-down each still
    calls for, the knots starting as ``start`` says (``Start.HINT``: from ``initial``).

    Steps 2-4 of the module docstring, for all axes at once. An axis without a segment to split
    is done (as it would be on its own) and leaves: the next rounds work on the others only.
    """
    n = smp.n_ms
    tol = opts.tolerance_qc
    fitted: Fitted | None = None
    target = opts.fit_fraction * tol
    if start is Start.HINT:
        assert initial is not None
        knots, fitted = fit_knots(fl, fl.flat_knots(initial), target, opts.max_splits)
        p_fit, v_fit = fitted.P, fitted.V
    else:
        thresholds = np.abs(fl.amax) * opts.switch_fraction
        knots = switch_flat_knots(
            smp.switch_ms, np.ascontiguousarray(smp.jump), np.asarray(cols, dtype=np.int64), thresholds, n,
            opts.min_switch_gap_ms, TIME_MAX_MS,
        )  # fmt: skip
        # a coarse first cut with the cheap exact-sample cubics, then least-squares fits
        if start is Start.LEAST_SQUARES:
            knots = refine(knots, fl.p, fl.v, _COARSE * target, opts.max_splits)
            knots, fitted = fit_knots(fl, knots, target, opts.max_splits)
            p_fit, v_fit = fitted.P, fitted.V
        else:
            knots = refine(knots, fl.p, fl.v, target, opts.max_splits)
            p_fit, v_fit = fl.p[knots], fl.v[knots]
    checked: Checked | None = None
    last_stuck = np.full(len(fl.axes), _NOT_YET)  # per axis: segments over a limit
    jerk_limited = bool(np.isfinite(fl.window_jerk).any())  # per axis, kept by ``Flat.subset``
    out: dict[int, tuple[AxisKnots, float]] = {}
    best: dict[int, tuple[AxisKnots, float]] = {}  # per axis: its least slow-down so far
    for _ in range(opts.max_splits):
        if len(p_fit) != len(knots):
            if start is Start.EXACT:
                p_fit, v_fit = fl.p[knots], fl.v[knots]
            else:
                fitted = lsq_fit(fl, knots, fitted)
                p_fit, v_fit = fitted.P, fitted.V
        P, V, checked = quantize_checked(fl, knots, p_fit, v_fit, checked, tol)
        chk = checked.chk
        # a segment still over a limit with a long span: another knot gives the repair room to fix it;
        # where the window jerk is over, shorter cubics follow the plan's acceleration closer; splits
        # are worth it while they help: an axis whose segments over a limit did not get fewer (and
        # that strays nowhere) stops here, as it is (``round_kernels.split_verdict``)
        jerk = NO_INT
        if jerk_limited:  # the drive's window jerk over what the jerk limit allows
            jerk = jerk_segments(fl, knots, P, V, opts.dwell_ms)
        bad, n_stuck, strays = split_verdict(
            knots, fl.stride, chk.seg_deviation, chk.position_out, chk.velocity_ratio, chk.acceleration_ratio,
            tol, jerk, last_stuck, 2 * _MIN_SPLIT_MS,
        )  # fmt: skip
        last_stuck = n_stuck  # the axes that left have none: they are never judged again
        # an axis that strays nowhere has a usable program now: keep it if it is the best so far
        # (splitting for a limit can also make it worse: shorter segments feel rounding more)
        usable = np.flatnonzero(~strays & (n_stuck > 0)).tolist()
        if usable:
            for a, cand in axes_records(fl, usable, knots, P, V, chk, opts.dwell_ms).items():
                kept = best.get(a)
                if kept is None or cand[1] < kept[1]:
                    best[a] = cand
        if not len(bad):
            break
        # the axes without a bad segment are done (as each would be on its own): they leave
        busy = np.unique(fl.axis_of(knots[bad]))
        if len(busy) < len(fl.busy):
            done = sorted(set(fl.busy.tolist()).difference(busy.tolist()))
            out.update(axes_records(fl, done, knots, P, V, chk, opts.dwell_ms))
            sel, moved_knots = fl.moved_knots(busy, knots)
            bad = np.searchsorted(sel, bad)  # every bad segment starts at a knot of a busy axis
            p_fit, v_fit = p_fit[sel], v_fit[sel]
            fitted = fitted_subset(fl, busy, fitted, (knots, sel, moved_knots))
            checked = checked_subset(fl, busy, checked, (knots, sel, moved_knots))
            fl, knots = fl.subset(busy), moved_knots
        knots = split_segments(knots, bad)
    assert checked is not None
    out.update(axes_records(fl, fl.busy.tolist(), knots, P, V, checked.chk, opts.dwell_ms))
    for i, kept in best.items():
        if kept[1] < out[i][1]:
            out[i] = kept
    return [out[i] for i in range(len(out))]


def epos2_axes(
    axes: Sequence[DriveAxis],
    cols: Sequence[int],
    smp: Samples,
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
        which: list[int], start: Start, initial: Sequence[NDArray[np.int64]] | None = None
    ) -> list[tuple[AxisKnots, float]]:
        fl = Flat.of([axes[i] for i in which], [cols[i] for i in which], smp)
        return place_epos2(fl, smp, [cols[i] for i in which], opts, start, initial)

    def shifted(i: int, placed: tuple[AxisKnots, float]) -> tuple[AxisKnots, float]:
        return shifted_records(Flat.of([axes[i]], [cols[i]], smp), placed, opts)

    def smoothed(i: int, placed: tuple[AxisKnots, float]) -> tuple[AxisKnots, float]:
        if placed[0].jerk_ratio <= 1.0:  # no jerk limit, or within it
            return placed
        return smoothed_axis(Flat.of([axes[i]], [cols[i]], smp), placed, opts)

    if hints is not None:
        for i, res in zip(todo, place(todo, Start.HINT, list(hints)), strict=True):
            res = smoothed(i, res)
            if res[1] <= 1.0:
                results[i] = res
        todo = [i for i in todo if i not in results]
    if todo:
        fit = place(todo, Start.LEAST_SQUARES)
        redo = []
        for i, res in zip(todo, fit, strict=True):
            res = smoothed(i, res)
            if res[1] > 1.0:  # knots a ms earlier or later first (cheap), then the exact samples
                res = shifted(i, res)
            results[i] = res
            if res[1] > 1.0:
                redo.append(i)
        if redo:
            for i, res in zip(redo, place(redo, Start.EXACT), strict=True):
                res = smoothed(i, res)
                if res[1] > 1.0:
                    res = shifted(i, res)
                if res[1] < results[i][1]:
                    results[i] = res
    return [results[i] for i in range(len(axes))]
