"""How often a process that serves a bus hands the GIL from thread to thread.

A bus is served by threads (SYNC answers, feeders, heartbeat consumers; in the drives' process the
drives' clocks and the wire's driver) that must get the GIL within a fraction of a SYNC period, not
after CPython's 5 ms switch interval. The master and the drives' process both keep it here.
"""

from __future__ import annotations

import sys

SWITCH_INTERVAL_S = 0.0001  # the interpreter hands the GIL on at least this often while a bus is open


def hand_the_gil_on_often() -> None:
    """Shorten the process's switch interval to SWITCH_INTERVAL_S (never lengthen it; not restored:
    other buses of the process may still be open)."""
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
