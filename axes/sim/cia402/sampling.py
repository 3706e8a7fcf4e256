"""The motion clock of a simulated drive: what advances its motion time, and the samples taken on it.

``clock="lockstep"`` (the default): each SYNC advances the drive's motion time by the
cell's SYNC period; between two SYNCs the drive samples its interpolation at every whole millisecond
of that clock. Nothing waits on wall-clock time (but the reaction to a lost master,
``axes/sim/node/master_loss.py``), so a test runs a drive exactly as fast as it sends SYNCs, deterministically.

``clock="wall"``: the drive keeps its own time (``axes/sim/clock.py``: its quartz, ``drift_ppm``
fast) and samples every whole ms of it, run by the cell's ``Ticker`` (``run_to``) whatever the SYNCs
do. A SYNC is latched at its arrival on that clock (the frame's bus time stamp when plausible, else
the callback's instant), as a drive latches it in hardware, and the profiles act on it there
(``sync_time_us``) even when the simulation gets to the frame after the ticker has sampled past it
(``SyncSample.behind_us``): a late SYNC or a burst of SYNCs is what the drive sees, as a real one
would, and the simulation's own latency is not.

Every sample is bounded by 0x607D (a demand outside faults the drive and is not taken) and, on whole
milliseconds, by the profile's dynamics check (by default 0x607F); after each the drive publishes
its state in its object dictionary.
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Callable
from typing import ClassVar

import canopen
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.drive.scaling import INT32_MAX, INT32_MIN
from pvtflow.axes.sim.cia402.homing_mode import Homing
from pvtflow.axes.sim.cia402.power_states import (
    OPERATION_ENABLED,
)
from pvtflow.axes.sim.cia402.records import SyncSample
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.clock import MotionClock, arrival
from pvtflow.axes.sim.node.master_loss import MasterLossReaction
from pvtflow.axes.sim.node.pdo import PdoEngine


class Sampling:
    """The motion clock as part of a ``SimulatedDrive`` (which owns the state below and gives it the
    object dictionary access, the faults, the homing and the profiles' hooks)."""

    EMCY_POSITION_LIMIT: ClassVar[int]
    EMCY_VELOCITY: ClassVar[int]
    node: canopen.LocalNode
    pdo: PdoEngine
    motion_clock: MotionClock | None
    state: PowerState
    history: deque[SyncSample]
    master_loss: MasterLossReaction
    sync_count: int
    sync_period_us: int
    time_us: int
    sync_time_us: int
    sample_ms: float
    demand: float
    velocity: float
    acceleration: float
    ip_active: bool
    mode_display: int
    homing: Homing
    _stop_segment: Segment | None
    _internal_position: bool
    _units_per_qc_ms: float
    _in_own_thread: Callable[[Callable[[], None]], None]
    _guard: Callable[[Callable[[], None]], None]

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        def act() -> None:
            self.sync_count += 1
            clock = self.motion_clock
            behind = 0
            if clock is None:  # lockstep: one SYNC period per SYNC
                new_time = self.time_us + self.sync_period_us
            else:  # the SYNC instant on the drive's own clock, in order
                mono = arrival(timestamp)
                latched = clock.at(mono)
                new_time = max(self.sync_time_us, math.floor(self._sync_instant(latched, mono)))
                behind = max(self.time_us - new_time, 0)
            if not behind:
                self._run_clock_to(new_time)
            self.sync_time_us = new_time
            if self.operational:
                self.pdo.apply_synchronous()
            self._on_sync_validated()
            if clock is not None:
                self._on_sync_clock(latched, mono)
            self._refresh(events=False)
            self.history.append(
                SyncSample(
                    self.sync_count, new_time / 1000.0, self.demand, self.actual, self.ip_active, self.state, behind
                )
            )
            if self.operational:
                self.pdo.transmit_on_sync()
                self.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def run_to(self, mono: float) -> None:
        """Wall clock (the cell's ``Ticker``): sample every whole ms of the drive's own time up to
        ``mono`` (a ``time.monotonic()``), whatever the SYNCs do; send event TPDOs on change."""

        def act() -> None:
            clock = self.motion_clock
            if clock is None or not self.node.has_network():
                return
            now_us = clock.at(mono)
            new_time = self._sample_horizon(math.floor(now_us / 1000.0) * 1000, now_us)
            if new_time <= self.time_us:
                return
            self._run_clock_to(new_time)
            if self._stop_segment is None:
                self.master_loss.at_rest()
            self._refresh()

        self._in_own_thread(act)

    def _sync_instant(self, latched_us: float, mono: float) -> float:
        """Wall clock: the motion time at which a SYNC latched at ``latched_us`` takes effect (the
        fixed-period drives: their locked cycle, axes/sim/profiles/sync_lock.py)."""
        return latched_us

    def _sample_horizon(self, new_time_us: int, now_us: float) -> int:
        """Wall clock: the sample time the ticker may advance to at motion time ``now_us``."""
        return new_time_us

    # --- the motion: this module alone writes the demand, its velocity and acceleration, the braking
    # segment and the motion time; the power state machine, the homing and the profiles ask it to ---------
    def _power_on_motion(self, history_length: int) -> None:
        """At construction: motion time 0, no SYNC yet, the demand at 0 at rest."""
        self.history: deque[SyncSample] = deque(maxlen=history_length)
        self.sync_count = 0
        self.time_us = 0
        # the SYNC being processed, on the motion clock: time_us in lockstep; on the wall clock its
        # arrival, which the drive's samples may have passed already when the simulation is late
        self.sync_time_us = 0
        self.sample_ms = 0.0  # motion time of the sample being computed (or of the last SYNC)
        self._reset_motion()

    def _reset_motion(self) -> None:
        """Power-on (and every reset): the demand at 0 (the encoder counts from where the axis stands), at rest."""
        self._stop_segment: Segment | None = None
        self.demand = 0.0
        self.velocity = 0.0
        self.acceleration = 0.0

    @property
    def braking(self) -> bool:
        """The drive brakes on its own (a halt, a quick stop, a fault reaction): until the demand is at rest."""
        return self._stop_segment is not None

    def _rest(self) -> None:
        """At rest where the demand is: no braking segment, no velocity."""
        self._stop_segment = None
        self.velocity = self.acceleration = 0.0

    def _stop_at_once(self) -> None:
        """The power stage went off: at rest, the demand on the actual position."""
        self._rest()
        self.demand = float(self.actual)

    def _hold_actual(self) -> None:
        """Hold the present position: the demand takes the actual position (a whole count), at rest."""
        self.demand = float(self.actual)
        self.velocity = self.acceleration = 0.0

    def _stand_at(self, demand: float) -> None:
        self.demand = demand
        self.velocity = self.acceleration = 0.0

    def _jump_to(self, demand: float) -> None:
        """The demand takes ``demand`` at once (a drive without a ramp, below its cubic threshold)."""
        self.demand = demand

    def _zero_rates(self) -> None:
        self.velocity = self.acceleration = 0.0

    def _brake(self, velocity: float, deceleration: float) -> None:
        """Brake from ``velocity`` at ``deceleration`` (qc/ms^2) from now on (``Segment.braking``)."""
        self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, velocity, deceleration)

    def _begin_stop(self, deceleration: float) -> None:
        v = self.velocity
        self._abort_motion()
        if abs(v) > 1e-12:
            self._brake(v, deceleration)
        else:  # at rest: the demand settles on its whole count (see Segment.braking)
            self._rest()
            self.demand = float(round(self.demand))

    def _run_clock_to(self, new_time_us: int) -> None:
        """The motion time is ``new_time_us`` now (a SYNC, the ticker, a drive braking without SYNC)."""
        self._advance(new_time_us)
        self.time_us = new_time_us
        self.sample_ms = new_time_us / 1000.0

    def _advance(self, new_time_us: int) -> None:
        """Run the interpolation from the last SYNC to this one: every whole ms, then the SYNC instant."""
        t = (self.time_us // 1000 + 1) * 1000
        while t <= new_time_us:
            self._sample(t / 1000.0, True)
            t += 1000
        if new_time_us % 1000:
            self._sample(new_time_us / 1000.0, False)

    def _sample(self, t: float, full: bool) -> None:
        self.sample_ms = t
        if self._stop_segment is not None:
            seg = self._stop_segment
            p, v, a = seg.at(t)
            if not self._check_position(p):
                return
            self.demand, self.velocity, self.acceleration = p, v, a
            if t >= seg.end:
                self._rest()
                self.power.braked()
            return
        if self.state == OPERATION_ENABLED and self.mode_display == od.HOMING_MODE and self.homing.moves():
            self.demand, self.velocity, self.acceleration = self.homing.sample(t)
            return
        pva = self._motion_at(t) if self.state == OPERATION_ENABLED else None
        if pva is None or self.state != OPERATION_ENABLED:
            self.velocity = self.acceleration = 0.0
            return
        if not self._check_position(pva[0]) or not self._check_machine(pva[0]):
            return
        self.demand, self.velocity, self.acceleration = pva
        if full:
            self._check_dynamics(self.velocity, self.acceleration)

    def _check_position(self, p: float) -> bool:
        """0x607D bounds every position demand: one outside faults the drive and is not taken."""
        lo = self.read_or(od.SOFTWARE_POSITION_LIMIT, 1, INT32_MIN)
        hi = self.read_or(od.SOFTWARE_POSITION_LIMIT, 2, INT32_MAX)
        if lo <= round(p) <= hi:
            return True
        self.fault(self.EMCY_POSITION_LIMIT, "software position limit 0x607D")
        return False

    def _check_machine(self, p: float) -> bool:
        """The simulated machine bounds every motion outside homing (``Homing.machine_stop``): what it
        meets stops the axis there and faults the drive."""
        met = self.homing.machine_stop(self.demand, p)
        if met is None:
            return True
        self.demand, code, why = met
        self.fault(code, why)
        return False

    def _check_dynamics(self, v: float, a: float) -> None:
        """Default sanity check: 0x607F bounds the demand velocity (fault)."""
        if abs(v) * self._units_per_qc_ms > self.read_or(od.MAX_PROFILE_VELOCITY, 0, 2**32 - 1):
            self.fault(self.EMCY_VELOCITY, "max profile velocity 0x607F")

    @property
    def actual(self) -> int:
        """Position actual value: the simulated axis follows its demand exactly (rounded to qc)."""
        return round(self.demand)

    def _refresh(self, events: bool = True) -> None:
        """Publish the drive's state in its object dictionary (and send event TPDOs on change)."""
        self.publish(od.STATUSWORD, 0, self.statusword())
        demand = min(max(round(self.demand), INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_DEMAND_VALUE, 0, demand)
        actual = min(max(self.actual, INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_ACTUAL_VALUE, 0, actual)
        if self._internal_position:  # no factor group: the same increments
            self.publish(od.POSITION_ACTUAL_INTERNAL_VALUE, 0, actual)
        self._publish()
        if events and self.operational:
            self.pdo.transmit_events()
