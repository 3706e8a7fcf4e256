"""Shared part of the fixed-period simulated drives: one setpoint per period, validated by SYNC.

A setpoint written to 0x60C1 (by the synchronous RPDO, or by SDO) is *validated* by the next SYNC;
each profile then says when, and along what curve, the demand reaches it (``delay_periods`` after
the validating SYNC). A SYNC that validates no new setpoint starts nothing: the drive finishes the
segment under way and holds its end point (for the Parker cubic without velocity: see parker.py).

The SYNC that activates interpolation with no new setpoint written since the last SYNC latches
0x60C1:01 as the object holds it, as a real drive's position loop does (0 after power-up, the last
run's end after a run: a master primes it with the actual position first, ``FixedPeriodProfile``);
the Parker below 2.5 ms takes it as its target at once (parker.py).

The fixed-period drives have no interpolation limits of their own (the master limits the motion);
as sanity checks 0x607D bounds every demand sample and 0x607F every demand velocity (fault). The two
without a ramp of their own (bufferless, Parker direct) also judge the setpoint stream itself, in a
motion and in a stop alike (``_judge``, axes/sim/profiles/setpoint_judge.py): a stream that stops too
abruptly faults them.

On the wall clock (``clock="wall"``, axes/sim/clock.py) the drive's cycle is locked to the SYNCs it
hears (axes/sim/profiles/sync_lock.py): a SYNC inside the lock's window (the 135 us a SYNC can wait for a
frame already on the wire at 1 Mbit/s) starts its cycle on the locked period, at the instant the
lock predicted, so the segment it starts runs over the configured period (0x60C2; the Parker's
0x1006) from there and the demand is the one a perfectly timed SYNC gives; the drive samples no
further than that instant while the SYNC may still come inside its window. A SYNC outside the
window starts its cycle at its arrival on the drive's own clock, and the lock restarts from it:

* a late SYNC (a missing one among them): the segment ends on time and the drive holds its end
  point (velocity 0) until a SYNC latches the next setpoint; a segment that then starts, starts at
  rest.
* an early SYNC (before the window), and so each SYNC of a burst, latches whatever setpoint it
  finds; the segment it starts runs from where the demand is, so the demand heads for the later
  setpoint in less time than planned. What that does to the velocity is judged by the same checks
  as any program (0x607D every sample, 0x607F every whole-ms sample, each with the EMCY and fault
  it has today); no tolerance of its own. Each profile module quotes its seed.
"""

from __future__ import annotations

import math
from collections import deque

from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.cia402.power_states import OPERATION_ENABLED
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.drive import SimulatedDrive
from pvtflow.axes.sim.profiles.setpoint_judge import SetpointStream, too_fast
from pvtflow.axes.sim.profiles.sync_lock import SyncLock, sync_window_us


class FixedPeriodDrive(SimulatedDrive):
    """Interpolated position mode with one setpoint per period (subclasses: how it is reached)."""

    delay_periods: int = 1

    def _reset_profile(self) -> None:
        self.ip_active = False
        self._ip_requested = False
        self._segment: Segment | None = None
        self._new_setpoint: int | None = None  # written since the last SYNC
        self.setpoints: deque[tuple[int, int]] = deque(maxlen=self.history.maxlen)  # (validating SYNC, target)
        self.first_setpoint_sync: int | None = None  # SYNC that validated the first setpoint of a run
        self._stream = SetpointStream()  # the setpoints as judged by a drive without a ramp (_judge)
        self.sync_lock = SyncLock(sync_window_us(self.bitrate))  # wall clock: the cycle locked to SYNC

    # --- activation -------------------------------------------------------------------------------
    def _on_mode_change(self, old: int, new: int) -> None:
        if new != od.INTERPOLATED_POSITION_MODE and (self.ip_active or self._ip_requested):
            self._abort_motion()

    def _abort_motion(self) -> None:
        self._stream.reset()
        self.ip_active = False
        self._ip_requested = False
        self._segment = None
        self._new_setpoint = None
        self._reset_stream()

    def _request_ip(self) -> None:
        self._ip_requested = True

    def _activate(self) -> bool:
        """Interpolation becomes active at this SYNC (False: the configuration is refused)."""
        self.ip_active = True
        self.ip_active_sync = self.sync_count
        self.first_setpoint_sync = None
        self._segment = None
        self._stream.reset()
        self._reset_stream()
        return True

    def _on_sync_validated(self) -> None:
        if self.state != OPERATION_ENABLED:
            self._new_setpoint = None
            return
        activated = self._ip_requested
        if self._ip_requested:
            self._ip_requested = False
            if not self._activate():
                return
        if not self.ip_active:
            self._new_setpoint = None
            return
        target, self._new_setpoint = self._new_setpoint, None
        if target is None and activated:  # the position loop takes 0x60C1:01 as it stands, written or not
            self._validated(self.sync_time_us / 1000.0, self.read(od.INTERPOLATION_DATA_RECORD, 1))
            return
        if target is not None:
            self.setpoints.append((self.sync_count, target))
            if self.first_setpoint_sync is None:
                self.first_setpoint_sync = self.sync_count
        self._validated(self.sync_time_us / 1000.0, target)

    # --- the cycle locked to SYNC (wall clock) ---------------------------------------------------------
    @property
    def _cycle_us(self) -> float:
        """The period the lock expects SYNC at: the drive's interpolation period (0x60C2; 0x1006)."""
        return float(round(self.period_ms * 1000.0))

    def _sync_instant(self, latched_us: float, mono: float) -> float:
        instant, rate = self.sync_lock.place(latched_us, self._cycle_us)
        if rate is not None and self.motion_clock is not None:
            self.motion_clock.slew(rate, mono)
        return instant

    def _sample_horizon(self, new_time_us: int, now_us: float) -> int:
        held = self.sync_lock.holds_at(now_us, self._cycle_us)
        if held is None or new_time_us <= held:
            return new_time_us
        return math.floor(held / 1000.0) * 1000

    # --- writes -----------------------------------------------------------------------------------
    def _on_object_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.INTERPOLATION_DATA_RECORD and subindex == 1:
            self._new_setpoint = value

    # --- motion -----------------------------------------------------------------------------------
    @property
    def period_ms(self) -> float:
        """The interpolation period 0x60C2 (value x 10^index s), in ms."""
        value = self.read(od.INTERPOLATION_TIME_PERIOD, 1)
        index = self.read(od.INTERPOLATION_TIME_PERIOD, 2)
        return value * 10.0 ** (index + 3)

    def _motion_at(self, t: float) -> tuple[float, float, float] | None:
        if not self.ip_active or self._segment is None:
            return None
        p, v, a = self._segment.at(t)
        if t > self._segment.end + 1e-9:
            return p, 0.0, 0.0  # reached: holds there until the next validated setpoint moves it
        return p, v, a  # up to and including the end sample, the segment's own velocity

    def _target_reached(self) -> bool:
        return self._segment is None or self.time_us / 1000.0 >= self._segment.end - 1e-9

    def _start_point(self) -> tuple[float, float]:
        """Where a new segment starts: the running segment's present point (position, velocity);
        at rest on its end point once it has ended before now (a late SYNC: the drive held there)."""
        if self._segment is None:
            return self.demand, 0.0
        t = self.sync_time_us / 1000.0
        if t > self._segment.end + 1e-9:
            return self._segment.p1, 0.0
        if t >= self._segment.end - 1e-9:
            return self._segment.p1, self._segment.v1
        p, v, _ = self._segment.at(t)
        return p, v

    def _ramp(self, start: float, target: float, period: float) -> None:
        """A linear ramp from the present demand to ``target`` over ``period`` ms from ``start``."""
        p0, _ = self._start_point()
        self._segment = Segment.linear(start, p0, float(target), period)

    def _follow(self, segment: Segment) -> None:
        """The demand follows ``segment`` from its start (a profile's own curve to a setpoint)."""
        self._segment = segment

    def _forget_setpoint(self) -> None:
        """A setpoint written since the last SYNC is dropped (the drive no longer takes one)."""
        self._new_setpoint = None

    def _judge(self, target: int | None) -> bool:
        """A drive without a ramp takes this SYNC's setpoint (None: holds the last): the change of its
        step against 0x60C5 (axes/sim/profiles/setpoint_judge.py; the velocity is judged where the demand
        runs, 0x607F). False: it faulted."""
        _, acceleration = self._stream.take(target, self.demand, self.period_ms)
        if too_fast(acceleration, self._rpm_s_per_qc_ms2, self.read_or(od.MAX_ACCELERATION, 0, 2**32 - 1)):
            self.fault(self.EMCY_VELOCITY, "max acceleration 0x60C5")
            return False
        return True

    # --- subclass hooks ---------------------------------------------------------------------------
    def _reset_stream(self) -> None:
        """Forget the points of the previous run."""

    def _validated(self, now: float, target: int | None) -> None:
        """A SYNC validated ``target`` (None: no new setpoint since the last SYNC)."""
        raise NotImplementedError
