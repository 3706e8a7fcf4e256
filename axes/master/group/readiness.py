"""Which axes are ready for the next start without an enable, and the cleanup that makes them so.

After every run, however it ended (finished, stopped, faulted), every axis's interpolation is
ended and its buffer emptied in the background, so that nothing of the run is left in a drive for
the next one to start behind (a stopped EPOS2 still holds the rest of its records). An axis still
OPERATION ENABLED is also made ready for the next start (the enable a start would do: end
controlword, buffer cleared and open), so that the start needs only its checks. A start, a
recovery, a homing and ``settle`` wait for this to end; an axis that fails it is enabled at the
start as usual.

An axis counts as ready only while nothing has been said to it since (no controlword of anyone's:
a halt, a stop, a recovery's) and the bus has reported no fault meanwhile.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as wait_futures

from pvtflow.axes.drive.cia402 import PowerState, decode_state
from pvtflow.axes.master.link import AxisLink, DriveError
from pvtflow.axes.master.profiles.base import Profile

SETTLE_TIMEOUT_S = 3.0  # how long a drive is asked to empty its buffer after a run (the start enables it otherwise)


class Readiness:
    """Per axis: the link's ``controlwords_sent`` when it was last made ready (None: not ready)."""

    def __init__(
        self,
        links: Sequence[AxisLink],
        profiles: Sequence[Profile],
        pool: ThreadPoolExecutor,
        bus_faults: Callable[[], int],
    ) -> None:
        self.links = links
        self.profiles = profiles
        self._pool = pool
        self._bus_faults = bus_faults  # how many faults the bus has reported: a readiness made across one is void
        self._marks: list[int | None] = [None] * len(links)
        self._cleanup: list[Future[None]] = []

    def is_ready(self, i: int) -> bool:
        return self._marks[i] is not None and self._marks[i] == self.links[i].controlwords_sent

    def take(self) -> list[bool]:
        """Which axes are ready; a start uses the readiness up, whatever its outcome."""
        ready = [self.is_ready(i) for i in range(len(self.links))]
        self.forget()
        return ready

    def forget(self, i: int | None = None) -> None:
        """Axis i (every axis: None) is enabled afresh at the next start."""
        if i is None:
            self._marks = [None] * len(self.links)
        else:
            self._marks[i] = None

    def mark_all(self) -> None:
        """Every axis was enabled just now (a recovery)."""
        self._marks = [link.controlwords_sent for link in self.links]

    def prepare(self) -> None:
        """After a run: clean every axis up in the background (module docstring)."""
        self._cleanup = [self._pool.submit(self._make_ready, i) for i in range(len(self.links))]

    def wait(self) -> None:
        """Until the cleanup has ended (not two enables of one drive at once)."""
        for future in self._cleanup:
            future.result()

    def settle(self, timeout_s: float | None = None) -> bool:
        """Wait until the cleanup has ended; False: not within ``timeout_s``."""
        return not wait_futures(list(self._cleanup), timeout=timeout_s).not_done

    def _make_ready(self, i: int) -> None:
        """Only from OPERATION ENABLED: a drive that has left it (a fault, a reset) is not walked back
        here (that would reset a fault behind the user's back): its buffer is only cleared, and the
        start refuses it or the recovery enables it."""
        link, faults = self.links[i], self._bus_faults()
        self._marks[i] = None
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while True:  # a drive still working off the run's traffic answers late: ask again
            try:
                if decode_state(link.read_statusword()) is not PowerState.OPERATION_ENABLED:
                    self.profiles[i].clear_buffer()
                    return
                self.profiles[i].enable(fresh=True)  # reach() has nothing to do: no fault reset is ever sent
                break
            except DriveError:
                if time.monotonic() > deadline:
                    return
        if self._bus_faults() == faults:
            self._marks[i] = link.controlwords_sent
