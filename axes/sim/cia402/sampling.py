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
from typing import Protocol

import canopen
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.scaling import INT32_MAX, INT32_MIN
from pvtflow.axes.sim.cia402.homing_mode import Homing
from pvtflow.axes.sim.cia402.power_states import OPERATION_ENABLED, PowerStateMachine
from pvtflow.axes.sim.cia402.records import SyncSample
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.clock import MotionClock, arrival
from pvtflow.axes.sim.node.dictionary import DriveDictionary
from pvtflow.axes.sim.node.master_loss import MasterLossReaction
from pvtflow.axes.sim.node.pdo import PdoEngine


class MotionHost(Protocol):
    """What the motion needs of its drive (a ``SimulatedDrive``): its node, PDOs, dictionary, clock, power
    state, homing and lost-master reaction, its guard (an action under its lock) and its profile's hooks
    (where the interpolation is at a time, what a SYNC validates, its own dynamics check)."""

    EMCY_POSITION_LIMIT: int
    node: canopen.LocalNode
    pdo: PdoEngine
    dictionary: DriveDictionary
    motion_clock: MotionClock | None
    power: PowerStateMachine
    homing: Homing
    master_loss: MasterLossReaction
    mode_display: int
    ip_active: bool

    @property
    def operational(self) -> bool: ...

    def _guard(self, action: Callable[[], None]) -> None: ...

    def _in_own_thread(self, action: Callable[[], None]) -> None: ...

    def _refresh(self, events: bool = True) -> None: ...

    def _abort_motion(self) -> None: ...

    def _motion_at(self, t: float) -> tuple[float, float, float] | None: ...

    def _on_sync_validated(self) -> None: ...

    def _on_sync_clock(self, instant_us: float, mono: float) -> None: ...

    def _sync_instant(self, latched_us: float, mono: float) -> float: ...

    def _sample_horizon(self, new_time_us: int, now_us: float) -> int: ...

    def _check_dynamics(self, v: float, a: float) -> None: ...


class Motion:
    """The motion of a drive, a part of its ``SimulatedDrive`` (given as ``drive``; called under the
    drive's lock): the only writer of the demand, its velocity and acceleration, the braking segment
    and the motion time; the SYNC and the ticker run it, the power state machine, the homing and the
    profiles ask it to stop, brake or hold."""

    def __init__(self, drive: MotionHost, *, sync_period_us: int, history_length: int) -> None:
        self._drive = drive
        self.sync_period_us = sync_period_us
        self.history: deque[SyncSample] = deque(maxlen=history_length)
        self.sync_count = 0
        self.time_us = 0
        # the SYNC being processed, on the motion clock: time_us in lockstep; on the wall clock its
        # arrival, which the drive's samples may have passed already when the simulation is late
        self.sync_time_us = 0
        self.sample_ms = 0.0  # motion time of the sample being computed (or of the last SYNC)
        self.reset()

    # --- what runs it ------------------------------------------------------------------------------
    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        d = self._drive

        def act() -> None:
            self.sync_count += 1
            clock = d.motion_clock
            behind = 0
            if clock is None:  # lockstep: one SYNC period per SYNC
                new_time = self.time_us + self.sync_period_us
            else:  # the SYNC instant on the drive's own clock, in order
                mono = arrival(timestamp)
                latched = clock.at(mono)
                new_time = max(self.sync_time_us, math.floor(d._sync_instant(latched, mono)))
                behind = max(self.time_us - new_time, 0)
            if not behind:
                self.run_clock_to(new_time)
            self.sync_time_us = new_time
            if d.operational:
                d.pdo.apply_synchronous()
            d._on_sync_validated()
            if clock is not None:
                d._on_sync_clock(latched, mono)
            d._refresh(events=False)
            self.history.append(
                SyncSample(
                    self.sync_count, new_time / 1000.0, self.demand, self.actual, d.ip_active, d.power.state, behind
                )
            )
            if d.operational:
                d.pdo.transmit_on_sync()
                d.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            d._guard(act)

    def run_to(self, mono: float) -> None:
        """Wall clock (the cell's ``Ticker``): sample every whole ms of the drive's own time up to
        ``mono`` (a ``time.monotonic()``), whatever the SYNCs do; send event TPDOs on change."""
        d = self._drive

        def act() -> None:
            clock = d.motion_clock
            if clock is None or not d.node.has_network():
                return
            now_us = clock.at(mono)
            new_time = d._sample_horizon(math.floor(now_us / 1000.0) * 1000, now_us)
            if new_time <= self.time_us:
                return
            self.run_clock_to(new_time)
            if self._stop_segment is None:
                d.master_loss.at_rest()
            d._refresh()

        d._in_own_thread(act)

    def run_clock_to(self, new_time_us: int) -> None:
        """The motion time is ``new_time_us`` now (a SYNC, the ticker, a drive braking without SYNC)."""
        self._advance(new_time_us)
        self.time_us = new_time_us
        self.sample_ms = new_time_us / 1000.0

    # --- what the others ask of it ------------------------------------------------------------------
    def reset(self) -> None:
        """Power-on (and every reset): the demand at 0 (the encoder counts from where the axis stands), at rest."""
        self._stop_segment: Segment | None = None
        self.demand = 0.0
        self.velocity = 0.0
        self.acceleration = 0.0

    @property
    def actual(self) -> int:
        """Position actual value: the simulated axis follows its demand exactly (rounded to qc)."""
        return round(self.demand)

    @property
    def braking(self) -> bool:
        """The drive brakes on its own (a halt, a quick stop, a fault reaction): until the demand is at rest."""
        return self._stop_segment is not None

    def rest(self) -> None:
        """At rest where the demand is: no braking segment, no velocity."""
        self._stop_segment = None
        self.velocity = self.acceleration = 0.0

    def stop_at_once(self) -> None:
        """The power stage went off: at rest, the demand on the actual position."""
        self.rest()
        self.demand = float(self.actual)

    def hold_actual(self) -> None:
        """Hold the present position: the demand takes the actual position (a whole count), at rest."""
        self.demand = float(self.actual)
        self.velocity = self.acceleration = 0.0

    def stand_at(self, demand: float) -> None:
        self.demand = demand
        self.velocity = self.acceleration = 0.0

    def jump_to(self, demand: float) -> None:
        """The demand takes ``demand`` at once (a drive without a ramp, below its cubic threshold)."""
        self.demand = demand

    def zero_rates(self) -> None:
        self.velocity = self.acceleration = 0.0

    def brake(self, velocity: float, deceleration: float) -> None:
        """Brake from ``velocity`` at ``deceleration`` (qc/ms^2) from now on (``Segment.braking``)."""
        self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, velocity, deceleration)

    def begin_stop(self, deceleration: float) -> None:
        v = self.velocity
        self._drive._abort_motion()
        if abs(v) > 1e-12:
            self.brake(v, deceleration)
        else:  # at rest: the demand settles on its whole count (see Segment.braking)
            self.rest()
            self.demand = float(round(self.demand))

    def check_position(self, p: float) -> bool:
        """0x607D bounds every position demand: one outside faults the drive and is not taken."""
        d = self._drive
        lo = d.dictionary.read_or(od.SOFTWARE_POSITION_LIMIT, 1, INT32_MIN)
        hi = d.dictionary.read_or(od.SOFTWARE_POSITION_LIMIT, 2, INT32_MAX)
        if lo <= round(p) <= hi:
            return True
        d.power.fault(d.EMCY_POSITION_LIMIT, "software position limit 0x607D")
        return False

    # --- the samples -----------------------------------------------------------------------------------
    def _advance(self, new_time_us: int) -> None:
        """Run the interpolation from the last SYNC to this one: every whole ms, then the SYNC instant."""
        t = (self.time_us // 1000 + 1) * 1000
        while t <= new_time_us:
            self.sample(t / 1000.0, True)
            t += 1000
        if new_time_us % 1000:
            self.sample(new_time_us / 1000.0, False)

    def sample(self, t: float, full: bool) -> None:
        d = self._drive
        self.sample_ms = t
        if self._stop_segment is not None:
            seg = self._stop_segment
            p, v, a = seg.at(t)
            if not self.check_position(p):
                return
            self.demand, self.velocity, self.acceleration = p, v, a
            if t >= seg.end:
                self.rest()
                d.power.braked()
            return
        enabled = d.power.state == OPERATION_ENABLED
        if enabled and d.mode_display == od.HOMING_MODE and d.homing.moves():
            self.demand, self.velocity, self.acceleration = d.homing.sample(t)
            return
        pva = d._motion_at(t) if enabled else None
        if pva is None or d.power.state != OPERATION_ENABLED:
            self.velocity = self.acceleration = 0.0
            return
        if not self.check_position(pva[0]) or not self._check_machine(pva[0]):
            return
        self.demand, self.velocity, self.acceleration = pva
        if full:
            d._check_dynamics(self.velocity, self.acceleration)

    def _check_machine(self, p: float) -> bool:
        """The simulated machine bounds every motion outside homing (``Homing.machine_stop``): what it
        meets stops the axis there and faults the drive."""
        met = self._drive.homing.machine_stop(self.demand, p)
        if met is None:
            return True
        self.demand, code, why = met
        self._drive.power.fault(code, why)
        return False
