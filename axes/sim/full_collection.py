"""The drives' process runs CPython's full garbage collection only while no SYNC runs.

A full (generation 2) collection stops every thread of the process: in the drives' process on the
wall clock that took 14-65 ms here, and meanwhile the simulated wire (its driver and its loopback
server), every drive's clock and heartbeat stood still, the master's transmit FIFO filled waiting
for the reports of frames gone (ENOBUFS) and a drive's records ran late. As the master holds its
collector off while SYNC runs (``axes/master/bus/collector.py``), the drives' process keeps the young
collections (about 1 ms each: most cyclic garbage dies young) and runs the full one once the bus
has been without SYNC for ``QUIET_S``: between motions. What the start built is frozen out of the
collections' reach (``gc.freeze``) so that those walk only what the running drives make.
"""

from __future__ import annotations

import gc
import time

import canopen

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.objects import SYNC_COB_ID

QUIET_S = 1.0  # no SYNC for this long: no motion runs, a full collection stalls nothing that counts
NO_AUTOMATIC_FULL = 2**31 - 1  # generation 2's threshold: never by allocation count


class FullCollectionBetweenMotions:
    """``tick()`` from a thread that wakes now and then (the process's main loop); ``close()`` restores."""

    def __init__(self, network: canopen.Network) -> None:
        self.network = network
        self.last_sync = time.monotonic()
        self._collected_for: float | None = None  # the last SYNC before the latest full collection
        self._thresholds = gc.get_threshold()
        gc.collect()
        gc.freeze()
        gc.set_threshold(self._thresholds[0], self._thresholds[1], NO_AUTOMATIC_FULL)
        subscribe(network, SYNC_COB_ID, self._on_sync)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.last_sync = time.monotonic()

    def tick(self) -> bool:
        """A full collection if the bus has been without SYNC for ``QUIET_S`` and none ran since the
        last SYNC; whether it ran."""
        last = self.last_sync
        if time.monotonic() - last < QUIET_S or self._collected_for == last:
            return False
        gc.collect()
        self._collected_for = last
        return True

    def close(self) -> None:
        unsubscribe(self.network, SYNC_COB_ID, self._on_sync)
        gc.set_threshold(*self._thresholds)
        gc.unfreeze()
