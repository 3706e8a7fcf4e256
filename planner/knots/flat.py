"""Several EPOS2 axes laid end to end as one problem, and the records of each axis read back from it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.knots.samples import Samples, axis_constants
from pvtflow.planner.knots.types import DriveAxis

# knots, the indices of those on the axes that stay, those knots (``Flat.moved_knots``)
Moved = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]


@dataclass(frozen=True)
class Flat:
    """Several EPOS2 axes placed as one: their plan samples end to end (axis a's ms j at flat index
    a * stride + j) and their knots in that index, so that every step below is one set of array
    operations for all axes (the axes are independent: numpy's fixed cost per call is paid once,
    not once per axis). Consecutive knots of one axis bound a segment; the step from an axis's last
    knot to the next placed axis's first is none (``real_segments`` is False there, it is never split,
    fitted, checked or repaired). Per-axis constants are arrays indexed by the axis number.

    An axis that is done leaves (``subset``): its knots are dropped, the samples and constants stay
    where they are (no copy), so an axis keeps its number and its knots their index."""

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
    window_jerk: NDArray[np.float64]  # the drive's allowed 10-ms-window jerk, qc/ms^3 (inf: none)
    busy: NDArray[np.int64]  # the axes still placed (their numbers, ascending): ``subset``

    @classmethod
    def of(cls, axes: Sequence[DriveAxis], cols: Sequence[int], smp: Samples) -> Flat:
        cols = list(cols)
        whole = cols == list(range(smp.position.shape[0]))  # every column in order: the samples as they are
        return cls(
            tuple(axes),
            smp.n_ms + 1,
            smp.position.ravel() if whole else smp.position[cols].ravel(),
            smp.velocity.ravel() if whole else smp.velocity[cols].ravel(),
            # own copies: the cached constants are read-only, and numba compiles a read-only array
            # as another type (a plan whose axes drop out would compile again, seconds, mid-request)
            *(c.copy() for c in axis_constants(tuple(axes))),
            smp.window_jerk[cols],
            np.arange(len(axes)),
        )

    def subset(self, keep: NDArray[np.int64]) -> Flat:
        """The axes ``keep`` (axis numbers, ascending) alone; ``moved_knots`` selects their knots."""
        return replace(self, busy=keep)

    def moved_knots(
        self, keep: NDArray[np.int64], knots: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """For knots of this one: (the indices of those on the axes ``keep``, those knots)."""
        on = np.zeros(len(self.axes), dtype=bool)
        on[keep] = True
        sel = np.flatnonzero(on[knots // self.stride])
        return sel, knots[sel]

    def axis_of(self, idx: NDArray[np.int64]) -> NDArray[np.int64]:
        return idx // self.stride

    def is_end(self, knots: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Knots at an axis's start or goal: at rest, at the plan's position, never moved."""
        r = knots % self.stride
        return (r == 0) | (r == self.stride - 1)

    def flat_knots(self, per_axis: Sequence[NDArray[np.int64]]) -> NDArray[np.int64]:
        """Each axis's knots (sorted, unique; both ends added, no segment over 255 ms) laid end to end."""
        n = self.stride - 1
        starts = np.arange(len(per_axis), dtype=np.int64) * self.stride
        k = np.concatenate([np.asarray(x, dtype=np.int64) for x in per_axis])
        base = np.repeat(starts, [len(x) for x in per_axis])
        inner = (k > 0) & (k < n)
        # each axis's knots lie between its ends, the axes one after the other: sorted, the union;
        # the step from an axis's end to the next one's start is 1: only real segments are split
        return within_record_time(np.sort(np.concatenate((starts, k[inner] + base[inner], starts + n))))


def within_record_time(knots: NDArray[np.int64]) -> NDArray[np.int64]:
    """Sorted knots with every gap longer than a record's 255 ms split evenly."""
    gaps = np.diff(knots)
    long = np.flatnonzero(gaps > TIME_MAX_MS)
    if not len(long):
        return knots
    pieces = -(-gaps[long] // TIME_MAX_MS)
    at = np.repeat(long, pieces - 1)  # the gap each new knot splits
    n = np.repeat(pieces, pieces - 1)
    j = np.arange(len(at)) - np.repeat(np.cumsum(pieces - 1) - (pieces - 1), pieces - 1) + 1  # 1 .. n - 1
    # each new knot lies strictly inside its gap (gap / n >= 128 ms apart): sorting is the union
    return np.sort(np.concatenate((knots, knots[at] + (gaps[at] * j) // n)))


def real_segments(fl: Flat, knots: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per knot segment: both ends on the same axis (a segment, not the step between two axes)."""
    return fl.axis_of(knots[:-1]) == fl.axis_of(knots[1:])
