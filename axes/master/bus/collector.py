"""CPython's cyclic garbage collector held off while SYNC runs on the wall clock.

A full (generation 2) collection walks every object of the process: with Pinocchio, numba, zenoh
and the simulated drives loaded that took 90-180 ms here, longer than any drive rides out a silent
master (a fixed-period drive: two periods; an EPOS2: its FIFO reserve, tens of ms). Nothing of the
motion needs the collector (reference counting frees almost everything at once), so it is paused
from the first SYNC of a motion on the wall clock to its last and runs when the motion is over.
Process-wide, counted: several buses of one process pause it together.
"""

from __future__ import annotations

import gc
import threading

_lock = threading.Lock()
_holders = 0
_was_enabled = True


def hold() -> None:
    """Pause the cyclic collector (until as many ``release`` calls)."""
    global _holders, _was_enabled
    with _lock:
        if _holders == 0:
            _was_enabled = gc.isenabled()
            gc.disable()
        _holders += 1


def release() -> None:
    """Let the collector run again once nobody holds it (as it was before the first ``hold``)."""
    global _holders
    with _lock:
        if _holders == 0:
            return
        _holders -= 1
        if _holders == 0 and _was_enabled:
            gc.enable()
