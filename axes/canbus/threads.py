"""How the threads that serve a bus run: how often they hand the GIL on, and at which priority.

A bus is served by threads (SYNC answers, feeders, heartbeat consumers; in the drives' process the
drives' clocks and the wire's driver) that must get the GIL within a fraction of a SYNC period, not
after CPython's 5 ms switch interval. The master and the drives' process both keep it here.

The simulated wire's own threads stand in for what a real bus does outside any process: the
controller that puts a queued frame on the wire when the bus is free, and the kernel that hands a
received frame to its socket. Neither waits for a busy host's scheduler on a machine, so the wall
driver (``axes.sim.wire.wall.WallDriver``), the loopback server's selector thread and a remote bus's
reader thread ask for SCHED_FIFO at ``WIRE_PRIORITY``, above the master's SYNC thread
(``BusConfig.sync_priority``, 50): the wire carries what that thread sends. Each of them blocks
between frames, so it takes no CPU from anyone while the bus is quiet. Not permitted (no
CAP_SYS_NICE or rtprio limit): the thread stays at normal priority, silently (the master warns for
its own SYNC thread; ``bench/wire_sync.py`` shows what the priority buys). Only on the wall clock: in
lockstep no one waits on the wire's threads, and at SCHED_FIFO they would only take the CPU from a wall
clock's SYNC elsewhere on the host. The simulated drives on the wall clock run just below the master's
cyclic path (``DRIVES_PRIORITY``).
"""

from __future__ import annotations

import os
import sys

SWITCH_INTERVAL_S = 0.0001  # the interpreter hands the GIL on at least this often while a bus is open


def hand_the_gil_on_often() -> None:
    """Shorten the process's switch interval to SWITCH_INTERVAL_S (never lengthen it; not restored:
    other buses of the process may still be open)."""
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))


WIRE_PRIORITY = 60
# the simulated drives' threads (``axes.sim.process``, wall clock): hardware with a CPU of its own, so above
# every thread of normal priority; below the master's cyclic path (SYNC and the setpoints after it,
# ``BusConfig.sync_priority`` 50, its other bus threads one below), which must never wait for a drive's
# thread, and below the wire's threads
DRIVES_PRIORITY = 40


def ask_wire_priority() -> bool:
    """SCHED_FIFO at ``WIRE_PRIORITY`` for the calling thread; False where not permitted."""
    return _ask_fifo(WIRE_PRIORITY)


def ask_drives_priority() -> bool:
    """SCHED_FIFO at ``DRIVES_PRIORITY`` for the calling thread; False where not permitted."""
    return _ask_fifo(DRIVES_PRIORITY)


def _ask_fifo(priority: int) -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError):
        return False
    return True
