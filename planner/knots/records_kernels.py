"""An axis's records read back from the flat problem of all EPOS2 axes (``planner.knots.check.axis_records``),
with the worst of its segments' check, in one compiled call: every round of a placement reads an
axis's program back where the axis leaves or keeps its best, and a handful of numpy calls per axis
cost more than the copying.

Layout (as in ``planner.knots.flat.Flat``): all EPOS2 axes' plan samples end to end, axis ``a``'s
ms ``j`` at flat index ``a * stride + j``; ``knots`` are sorted flat indices.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

_F = NDArray[np.float64]
_I = NDArray[np.int64]


@njit(cache=True)
def axis_knots(knots: _I, stride: int, a: int) -> tuple[int, int]:
    """The knots of axis ``a``: ``knots[k0:k1]``."""
    return np.searchsorted(knots, a * stride), np.searchsorted(knots, (a + 1) * stride)


@njit(cache=True)
def knot_records(knots: _I, P: _I, V: _I, stride: int, a: int, dwell_ms: int) -> _I:
    """The records of axis ``a``: the dwell, one per knot (its position, velocity and the time
    to the next), the end record (P, 0, 0)."""
    k0, k1 = axis_knots(knots, stride, a)
    records = np.zeros((k1 - k0 + 1, 3), dtype=np.int64)
    for i in range(k1 - k0):
        records[i, 0], records[i, 1] = P[k0 + i], V[k0 + i]
    records[-1, 0] = P[k1 - 1]
    records[0, 2] = dwell_ms
    for i in range(1, k1 - k0):
        records[i, 2] = knots[k0 + i] - knots[k0 + i - 1]
    return records


@njit(cache=True)
def axis_records(
    knots: _I, P: _I, V: _I, stride: int, a: int, dwell_ms: int, dev: _F, rv: _F, ra: _F
) -> tuple[_I, float, float, float]:
    """``knot_records`` of axis ``a`` and the worst deviation, |v| ratio and |a| ratio of its segments."""
    k0, k1 = axis_knots(knots, stride, a)
    d, v, acc = dev[k0], rv[k0], ra[k0]
    for k in range(k0 + 1, k1 - 1):
        d, v, acc = max(d, dev[k]), max(v, rv[k]), max(acc, ra[k])
    return knot_records(knots, P, V, stride, a, dwell_ms), d, v, acc


@njit(cache=True)
def axes_records(
    knots: _I, P: _I, V: _I, stride: int, axes: _I, dwell_ms: int, dev: _F, rv: _F, ra: _F
) -> tuple[_I, _I, _F]:
    """``axis_records`` of each of ``axes`` in one call: their records one after the other (axis
    ``axes[i]``'s are rows ``first[i]:first[i + 1]``), ``first``, and per axis the worst deviation,
    |v| ratio and |a| ratio of its segments."""
    first = np.zeros(len(axes) + 1, dtype=np.int64)
    for i in range(len(axes)):
        k0, k1 = axis_knots(knots, stride, axes[i])
        first[i + 1] = first[i] + k1 - k0 + 1
    rows = np.empty((first[-1], 3), dtype=np.int64)
    worst = np.empty((len(axes), 3))
    for i in range(len(axes)):
        records, d, v, acc = axis_records(knots, P, V, stride, axes[i], dwell_ms, dev, rv, ra)
        rows[first[i] : first[i + 1]] = records
        worst[i, 0], worst[i, 1], worst[i, 2] = d, v, acc
    return rows, first, worst
