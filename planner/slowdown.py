"""The slow-down rule: how much slower a timing must run to meet its velocity and acceleration limits.

Running a motion k times slower (every time multiplied by k) divides its velocities by k and its
accelerations by k^2 (its jerks by k^3), so the least k that brings the worst ratios value / limit
``rv`` and ``ra`` within 1 is max(rv, sqrt(ra)): :func:`slowdown`. Every slow-down of the planner
asks it: TOPP-RA's dense check (``planner.timing``), the jerk-limited timing's (``planner.jerk``, with
cbrt of the jerk ratio beside it), knot placement's step 5 (``planner.knots.check.needed_scale``) and
its per-segment searches (``planner.knots.fixed_period_kernels``, which is why it is compiled).

Where a slow-down is applied, it is a little more than the rule, for two different reasons:

- ``SLOWDOWN_MARGIN``: a continuous timing slowed by exactly k lands on its limit, and the round-off
  of multiplying every time by k can leave it a hair above: 1e-9 is far beyond that round-off and far
  below anything a drive can tell.
- ``KNOT_SLOWDOWN_MARGIN``: knots placed again on a slowed motion are rounded again, and their
  integers do not scale with it: asking for 1e-4 more than the excess measured keeps the next round
  from landing on the limit once more. (Both figures are what the records digest,
  ``bench/records_digest.py``, was taken with: another value places other records.)
"""

from __future__ import annotations

import numpy as np
from numba import njit

SLOWDOWN_MARGIN = 1e-9
KNOT_SLOWDOWN_MARGIN = 1e-4


@njit(cache=True)
def slowdown(rv: float, ra: float) -> float:
    """The least slow-down that brings the worst velocity ratio ``rv`` and acceleration ratio ``ra``
    within 1 (below 1 where both already are: the room there is)."""
    return max(rv, np.sqrt(ra))
