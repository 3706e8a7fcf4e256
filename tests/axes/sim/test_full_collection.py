"""The drives' process: no full garbage collection while SYNC runs, one between motions."""

from __future__ import annotations

import gc
import time

import canopen

from pvtflow.axes.canbus.collector import QUIET_S, FullCollectionBetweenMotions
from pvtflow.axes.drive.objects import SYNC_COB_ID


def test_a_full_collection_runs_only_once_the_bus_is_without_sync() -> None:
    before = gc.get_threshold()
    network = canopen.Network()
    collection = FullCollectionBetweenMotions(network)
    try:
        assert gc.get_threshold()[2] > 10**9  # never by allocation count
        assert gc.get_freeze_count() > 0  # what the start built is out of the collections' reach
        network.notify(SYNC_COB_ID, bytearray(), time.time())  # a SYNC: a motion runs
        assert not collection.tick()
        collection.last_sync = time.monotonic() - QUIET_S - 0.1  # the bus has been quiet since
        assert collection.tick()
        assert not collection.tick()  # once per quiet spell
        network.notify(SYNC_COB_ID, bytearray(), time.time())
        assert not collection.tick()
    finally:
        collection.close()
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0
    assert SYNC_COB_ID not in network.subscribers
