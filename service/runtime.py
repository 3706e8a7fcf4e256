"""What a latency-bound service process does once it has started.

A full collection of CPython's cyclic garbage collector walks every tracked object, and a service's
start-up (numpy, scipy, Pinocchio, toppra, numba's kernels, zenoh, the cell's drives and planner)
leaves hundreds of thousands of them: a full collection over them is a pause that any plan request
or execute could land in (the tail of ``bench/service_latency.py``, bench/RESULTS.md). Start-up
objects live as long as the process, so they are moved out of the collector's reach once start-up is
over; collections then walk only what came after.

A process-wide policy, so the processes call it, not the library: ``pvtflow serve`` and ``demo``
once their service is open, the planning child after its warm-up, and the benchmarks that stand
in for ``serve``.
"""

from __future__ import annotations

import gc


def freeze_startup_objects() -> None:
    """Collect start-up's garbage once, then keep every object alive now out of later collections."""
    gc.collect()
    gc.freeze()
