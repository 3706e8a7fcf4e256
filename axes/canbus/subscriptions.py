"""Subscribing to a CAN-ID of a canopen ``Network`` without disturbing a dispatch in progress.

canopen's ``Network.notify`` walks the list ``network.subscribers[can_id]`` in the bus's receive
thread, and ``Network.subscribe`` / ``unsubscribe`` append to and remove from that very list. A
callback that unsubscribes (itself or another) while that frame is being dispatched, or another
thread doing so at that moment, shifts the list under the walk: the subscriber after the removed one
misses the frame (a drive's SYNC, the master's count of a SYNC answer). Here the list is never
changed in place: a new list replaces it, so a dispatch already under way walks the list it started
with, and every subscriber it held gets the frame. One lock orders the replacements of all threads.
Both the master (``axes.master.bus.sync``, ``axes.master.bus.sync_follower``, ``axes.master.link``)
and the simulated drives (``axes.sim``) use these.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import canopen

Callback = Callable[[int, bytearray, float], None]

_lock = threading.Lock()


def subscribe(network: canopen.Network, can_id: int, callback: Callable[..., None]) -> None:
    """``network.subscribe`` by replacing the subscriber list (a callback already there stays once)."""
    with _lock:
        current = network.subscribers.get(can_id, [])
        if callback not in current:
            network.subscribers[can_id] = [*current, callback]


def unsubscribe(network: canopen.Network, can_id: int, callback: Callable[..., None]) -> None:
    """``network.unsubscribe(can_id, callback)`` by replacing the subscriber list (nothing to do when
    the callback is not subscribed)."""
    with _lock:
        remaining = [cb for cb in network.subscribers.get(can_id, []) if cb != callback]
        if remaining:
            network.subscribers[can_id] = remaining
        else:
            network.subscribers.pop(can_id, None)
