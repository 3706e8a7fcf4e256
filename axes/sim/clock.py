"""A simulated drive's own time on the wall clock (``clock="wall"``), and the one thread that runs it.

In lockstep (the default) a drive's motion time advances by one SYNC period per SYNC: deterministic,
as fast as the test sends SYNC, and blind to when SYNCs come. On the wall clock each drive keeps
time as a real one does, by its quartz:

* ``Quartz``: the process's ``time.monotonic`` scaled by a drift in ppm (a drive parameter, for
  tests: real crystals are within about +-100 ppm).
* ``MotionClock``: the drive's motion time (us), its quartz times a rate, continuous when the rate
  changes (the EPOS2 slews it for a period after each SYNC to follow SYNC; the fixed-period drives
  leave it at 1).
* ``Ticker``: one thread for a whole cell that wakes every ms and advances every drive to now,
  sample by sample when it was held back (the samples are drive time; the thread is only how the
  simulation gets the CPU). SYNC and the other frames still arrive through the bus callbacks.
* ``arrival``: the instant a frame arrived, the bus's time stamp when it is a plausible one
  (python-can stamps frames in Unix time: ``virtual`` at send, a real interface at reception),
  else the instant the callback runs.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Protocol

from pvtflow.axes.canbus.clock import Clock

TICK_S = 0.001  # the drives sample their interpolation every ms of their own time
MAX_STAMP_AGE_S = 1.0  # a frame time stamp older than this (or in the future) is not this frame's arrival
MAX_DRIFT_PPM = 100_000.0


def check_clock(clock: Clock | str, drift_ppm: float = 0.0) -> Clock:
    """The ``Clock`` a drive or a cell is asked to run on (its value, ``"wall"``, will do); ValueError (one
    line) for a clock that is neither lockstep nor wall, or a drift out of range."""
    if clock not in list(Clock):
        raise ValueError(f"clock must be one of {', '.join(Clock)}, got {clock!r}")
    if not (math.isfinite(drift_ppm) and abs(drift_ppm) <= MAX_DRIFT_PPM):
        raise ValueError(f"drift_ppm must be within +-{MAX_DRIFT_PPM:g}, got {drift_ppm!r}")
    return Clock(clock)


def arrival(timestamp: float) -> float:
    """``time.monotonic()`` of a frame's arrival: its bus time stamp (Unix time) when plausible, else now."""
    mono, wall = _now_pair()
    age = wall - timestamp
    if -0.001 <= age <= MAX_STAMP_AGE_S:  # a stamp just ahead of this process's reading is still its own
        return mono - age
    return mono


def _now_pair() -> tuple[float, float]:
    """(time.monotonic(), time.time()) of one instant: another thread may run between two reads, so
    the pair read closest together of a few tries (it maps a Unix time stamp to the monotonic clock)."""
    best = (math.inf, 0.0, 0.0)
    for _ in range(3):
        w1 = time.time()
        mono = time.monotonic()
        w2 = time.time()
        if w2 - w1 < best[0]:
            best = (w2 - w1, mono, (w1 + w2) / 2.0)
        if best[0] < 20e-6:
            break
    return best[1], best[2]


class Quartz:
    """A drive's oscillator: microseconds since ``origin`` (a ``time.monotonic()``), ``drift_ppm`` fast."""

    def __init__(self, drift_ppm: float = 0.0, origin: float | None = None) -> None:
        self.drift_ppm = drift_ppm
        self.origin = time.monotonic() if origin is None else origin
        self._scale = 1e6 * (1.0 + drift_ppm * 1e-6)

    def us(self, mono: float) -> float:
        return (mono - self.origin) * self._scale


class MotionClock:
    """Motion time (us) = a reference time + the quartz time since the reference x ``rate`` for
    ``duration`` quartz us, then x 1."""

    def __init__(self, quartz: Quartz, motion_us: float, mono: float) -> None:
        self.quartz = quartz
        self.rate = 1.0
        self._t0 = motion_us
        self._q0 = quartz.us(mono)
        self._duration = math.inf

    def at(self, mono: float) -> float:
        """The motion time at ``mono`` (a ``time.monotonic()``)."""
        dq = self.quartz.us(mono) - self._q0
        if dq <= self._duration:
            return self._t0 + dq * self.rate
        return self._t0 + self._duration * self.rate + (dq - self._duration)

    def slew(self, rate: float, mono: float, duration_us: float = math.inf) -> None:
        """Run at ``rate`` from ``mono`` on for ``duration_us`` of the quartz, then at 1 (the motion
        time itself does not jump)."""
        self._t0 = self.at(mono)
        self._q0 = self.quartz.us(mono)
        self.rate = rate
        self._duration = duration_us


class Ticking(Protocol):
    def run_to(self, mono: float) -> None: ...


class Ticker:
    """One thread that advances every drive it holds to the present, every ``TICK_S``.

    ``horizon``: the ``time.monotonic()`` up to which the drives have taken in every frame the wire
    delivered (``SimulatedCell.heard_until``): they sample no further. A real drive latches a frame in
    hardware as its last bit leaves the wire; a simulated one learns of it when its process gets to
    it, and a sample taken past a SYNC it has not yet seen would show the axis holding at the last
    setpoint, then jumping: the simulation's own latency judged as the master's."""

    def __init__(
        self, drives: Iterable[Ticking] = (), name: str = "sim-ticker", horizon: Callable[[], float] | None = None
    ) -> None:
        self.drives: list[Ticking] = list(drives)
        self.name = name
        self.horizon = horizon
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.late_ticks = 0  # wakes more than a tick late (the drives then caught up sample by sample)

    def start(self) -> Ticker:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        thread, self._thread = self._thread, None
        self._stop.set()
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def _run(self) -> None:
        due = time.monotonic()
        while not self._stop.wait(max(due - time.monotonic(), 0.0)):
            now = time.monotonic()
            upto = now if self.horizon is None else min(now, self.horizon())
            for drive in self.drives:
                drive.run_to(upto)
            due += TICK_S
            if due < now:  # held back: the next wake is one tick from now, not a burst of wakes
                self.late_ticks += 1
                due = now + TICK_S
