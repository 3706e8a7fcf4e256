"""How a process that serves a bus treats CPython's cyclic garbage collector: the one policy.

A full (generation 2) collection walks every tracked object of the process and stops every thread
while it does: with Pinocchio, numba, zenoh and the simulated drives loaded that took 90-180 ms here,
longer than any drive rides out a silent master (a fixed-period drive: two periods; an EPOS2: its FIFO
reserve, tens of ms). Nothing of a motion needs the collector (reference counting frees almost
everything at once). So, in every process of pvtflow:

- what start-up built lives as long as the process and is frozen out of the collector's reach once
  start-up is over (``freeze_startup_objects``: ``pvtflow serve`` and ``demo`` once their service is
  open, the planning child after its warm-up, the benchmarks that stand in for ``serve``); a full
  collection over hundreds of thousands of start-up objects is a pause any request could land in
  (the tail of ``bench/service_latency.py``, bench/RESULTS.md);
- the master pauses the collector from the first SYNC of a motion on the wall clock to its last, and
  from a quick stop's requests to their confirmations (``hold`` / ``release``; process-wide, counted:
  several buses of one process pause it together);
- the drives' process keeps the young collections (about 1 ms each: most cyclic garbage dies young)
  and runs the full one once the bus has been without SYNC for ``QUIET_S``: between motions
  (``FullCollectionBetweenMotions``). There a full collection on the wall clock took 14-65 ms, and
  meanwhile the simulated wire, every drive's clock and heartbeat stood still, the master's transmit
  FIFO filled waiting for the reports of frames gone (ENOBUFS) and a drive's records ran late.
"""

from __future__ import annotations

import gc
import threading
import time

import canopen

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.objects import SYNC_COB_ID

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


QUIET_S = 1.0  # no SYNC for this long: no motion runs, a full collection stalls nothing that counts
NO_AUTOMATIC_FULL = 2**31 - 1  # generation 2's threshold: never by allocation count


def full_collections_by_hand() -> tuple[int, int, int]:
    """Freeze what lives now, keep the young collections, and run full ones only when asked
    (``gc.collect()``), never by allocation count; the thresholds before, to restore."""
    thresholds = gc.get_threshold()
    freeze_startup_objects()
    gc.set_threshold(thresholds[0], thresholds[1], NO_AUTOMATIC_FULL)
    return thresholds


class FullCollectionBetweenMotions:
    """``tick()`` from a thread that wakes now and then (the process's main loop); ``close()`` restores."""

    def __init__(self, network: canopen.Network) -> None:
        self.network = network
        self.last_sync = time.monotonic()
        self._collected_for: float | None = None  # the last SYNC before the latest full collection
        self._thresholds = full_collections_by_hand()
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


def freeze_startup_objects() -> None:
    """Collect start-up's garbage once, then keep every object alive now out of later collections."""
    gc.collect()
    gc.freeze()
