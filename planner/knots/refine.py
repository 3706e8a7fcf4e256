"""Steps 1-2 for EPOS2 axes: knots at the acceleration switches, then segments split until their
cubics (through the exact samples, or least-squares fits of the plan at every ms) stay close to it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import hermite_coefficients
from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.knots import refine_kernels as kernels
from pvtflow.planner.knots.check import NO_FLOAT, NO_INT
from pvtflow.planner.knots.flat import Flat, Moved


def switch_knots(
    switch_ms: NDArray[np.float64], jump: NDArray[np.float64], threshold: float, n_ms: int, min_gap: int
) -> NDArray[np.int64]:
    """Integer ms at the significant acceleration switches, largest jumps first, min_gap apart."""
    return kernels.switch_knots(np.ascontiguousarray(switch_ms), np.ascontiguousarray(jump), threshold, n_ms, min_gap)


def split_segments(knots: NDArray[np.int64], segments: NDArray[np.int64]) -> NDArray[np.int64]:
    """Halve the given knot segments (sorted, unique; those of 1 ms cannot be split and are left alone)."""
    return kernels.split_at(knots, segments)


_FIT_PROBES = np.arange(1, 8) / 8.0  # where a candidate segment's fit is judged


def refine(
    knots: NDArray[np.int64], p: NDArray[np.float64], v: NDArray[np.float64], target: float, max_rounds: int
) -> NDArray[np.int64]:
    """Split segments until the cubic through the exact samples stays within ``target`` of the plan.

    The fit is judged at seven whole-ms probes per segment (a cheap first cut: the exact
    reconstruction is checked at every ms afterwards and splits what this misses), by
    ``refine_kernels.refine``. Only the segments made by the last split are judged again.
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


@dataclass(frozen=True)
class Fitted:
    """A least-squares fit with what the next one can reuse: each segment's right-hand side (its
    basis cubics against the plan) and its worst deviation."""

    knots: NDArray[np.int64]
    rhs: NDArray[np.float64]  # (4, segments)
    P: NDArray[np.float64]
    V: NDArray[np.float64]
    worst: NDArray[np.float64] | None  # per segment, None when not asked for


NO_RHS = np.zeros((4, 0))


def lsq_fit(fl: Flat, knots: NDArray[np.int64], prev: Fitted | None = None, target: float | None = None) -> Fitted:
    """Knot positions and velocities (qc, qc/ms) whose cubics fit the plan best at every ms.

    Least squares over all drive samples: a banded (block-tridiagonal) system, solved in one go
    for all axes (the step between two axes contributes nothing, so the blocks are independent).
    Each axis's ends stay at the plan's start and goal at rest; a faint pull towards the exact
    samples keeps the system regular. The right-hand side of every segment unchanged since
    ``prev`` is reused.

    With ``target``, the worst |fit - plan| per segment is returned as well, as far as the
    comparison with ``target`` needs it (``refine_kernels.lsq_worst``).
    """
    table = _basis_table()
    prev_knots = NO_INT if prev is None else prev.knots
    r, same, where = kernels.lsq_rhs(
        knots, fl.stride, fl.p, table.values, table.offset, prev_knots, NO_RHS if prev is None else prev.rhs
    )
    P, V, ok = kernels.lsq_solve(knots, fl.stride, r, table.gram, fl.p, fl.v, fl.is_end(knots))
    if not ok:
        raise np.linalg.LinAlgError("least-squares knot fit: the banded normal equations are not positive definite")
    if target is None:
        return Fitted(knots, r, P, V, None)
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
        prev.P if keep else NO_FLOAT,
        prev.V if keep else NO_FLOAT,
        prev.worst if keep else NO_FLOAT,
    )
    return Fitted(knots, r, P, V, worst)


def fitted_subset(
    fl: Flat, keep: NDArray[np.int64], fitted: Fitted | None, moved: Moved | None = None
) -> Fitted | None:
    """``fitted`` for the axes ``keep`` alone (``moved``: ``fl.moved_knots`` of them, if already
    taken for ``fitted``'s knots)."""
    if fitted is None:
        return None
    sel, knots = moved[1:] if moved is not None and moved[0] is fitted.knots else fl.moved_knots(keep, fitted.knots)
    seg = sel[:-1]  # the segment after each kept knot (the step to the next kept axis: none, as before)
    worst = None if fitted.worst is None else fitted.worst[seg]
    return Fitted(knots, fitted.rhs.take(seg, axis=1), fitted.P[sel], fitted.V[sel], worst)


def fit_knots(fl: Flat, knots: NDArray[np.int64], target: float, max_rounds: int) -> tuple[NDArray[np.int64], Fitted]:
    """Split segments until the least-squares cubics stay within ``target`` of the plan: every
    round (``lsq_fit`` with ``target``, then the splits) in one compiled call,
    ``refine_kernels.fit_rounds``."""
    table = _basis_table()
    ok, knots, fit_knots, r, P, V, worst = kernels.fit_rounds(
        knots, fl.stride, fl.p, fl.v, table.values, table.offset, table.gram, target, max_rounds, TIME_MAX_MS
    )
    if not ok:
        raise np.linalg.LinAlgError("least-squares knot fit: the banded normal equations are not positive definite")
    return knots, Fitted(fit_knots, r, P, V, worst)
