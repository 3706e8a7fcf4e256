"""The simulated wire's own threads run at real-time priority where the OS allows it.

They stand in for what a real bus does outside any process: the controller that puts a queued
frame on the wire when the bus is free, and the kernel that hands a received frame to its socket.
Neither waits for a busy host's scheduler on a machine, so the wall driver (``wall.WallDriver``),
the loopback server's selector thread and a remote bus's reader thread ask for SCHED_FIFO at
``WIRE_PRIORITY``, above the master's SYNC thread (``BusConfig.sync_priority``, 50): the wire
carries what that thread sends. Each of them blocks between frames, so it takes no CPU from anyone
while the bus is quiet. Not permitted (no CAP_SYS_NICE or rtprio limit): the thread stays at normal
priority, silently (the master warns for its own SYNC thread; ``bench/wire_sync.py`` shows what the
priority buys).
"""

from __future__ import annotations

import os

WIRE_PRIORITY = 60


def ask_wire_priority() -> bool:
    """SCHED_FIFO at ``WIRE_PRIORITY`` for the calling thread; False where not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(WIRE_PRIORITY))
    except (AttributeError, OSError):
        return False
    return True
