"""The process's simwire media, one per channel name: created by the first opener, shared by
every bus (and the loopback server) of the process on that channel, closed with the last."""

from __future__ import annotations

import threading
from dataclasses import dataclass

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.sim.wire.medium import Medium
from pvtflow.axes.sim.wire.wall import WallDriver

DEFAULT_BITRATE = 1_000_000
DEFAULT_CLOCK = Clock.WALL


@dataclass
class _Open:
    medium: Medium
    driver: WallDriver | None
    users: int


_lock = threading.Lock()
_media: dict[str, _Open] = {}


def acquire_medium(
    channel: str, *, bitrate: int | None = None, clock: str | None = None, sync_period: float | None = None
) -> Medium:
    """The medium of ``channel``, created with these parameters (defaults: 1 Mbit/s, wall clock)
    if it has no opener yet; otherwise they must agree with it (None agrees with anything)."""
    with _lock:
        entry = _media.get(channel)
        if entry is None:
            medium = Medium(
                channel,
                bitrate=DEFAULT_BITRATE if bitrate is None else bitrate,
                clock=DEFAULT_CLOCK if clock is None else clock,
                sync_period=sync_period,
            )
            entry = _media[channel] = _Open(medium, WallDriver(medium) if medium.clock is Clock.WALL else None, 0)
        else:
            entry.medium.check_agrees(bitrate=bitrate, clock=clock, sync_period=sync_period)
        entry.users += 1
        return entry.medium


def release_medium(channel: str) -> None:
    with _lock:
        entry = _media.get(channel)
        if entry is None:
            return
        entry.users -= 1
        if entry.users > 0:
            return
        del _media[channel]
    entry.medium.closed = True
    if entry.driver is not None:
        entry.driver.close()


def open_channels() -> list[str]:
    with _lock:
        return sorted(_media)
