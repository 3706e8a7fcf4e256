"""Homing (CiA 402 mode 6) as a simulated drive runs it: the methods of ``axes.drive.objects.HomingMethod``.

The machine around the axis (``axes.drive.config.AxisSimulation``): limit switches, a home switch, an
index pulse every N counts, hard stops, all at positions of the machine (qc, as the axis reads them
once homed). The drive moves at 0x6099:01 while it searches a switch or a hard stop and at 0x6099:02
while it searches the edge or the index pulse that is home, accelerating at 0x609A, on its motion
clock (one step per interpolation sample). The home position is exact: the edge, the index pulse or
the hard stop where it lies, not where the sample fell. There the drive's position is redefined so
that it reads 0x607C, it brakes, and it goes back to stand on the home position: homing attained
(statusword bit 12) with target reached (bit 10).

A search ends in a homing error (bit 13, braking at 0x609A, no fault) when it meets what it does not
look for: a limit switch that becomes active, a hard stop it runs into (the following error a real
drive would see). A search that finds nothing goes on (the master's timeout ends it). The hard-stop
methods (maxon's -1 to -4) compare the motor current with 0x2080: ``stall_current_ma`` against a hard
stop, ``moving_current_ma`` in free motion (a threshold below it finds a "hard stop" at once, as a
real drive with too low a threshold does).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Statusword
from pvtflow.axes.drive.config import AxisSimulation
from pvtflow.axes.drive.scaling import DriveLimits
from pvtflow.axes.sim.node.dictionary import DriveDictionary

M = od.HomingMethod
RETURN_TOLERANCE_QC = 1e-6
TARGET_REACHED = int(Statusword.TARGET_REACHED)
HOMING_ATTAINED = int(Statusword.HOMING_ATTAINED)
HOMING_ERROR = int(Statusword.HOMING_ERROR)


class HomingState(Enum):
    """Where a homing run stands; the statusword bits 13, 12 and 10 follow from it (and from rest)."""

    RUNNING = "running"
    ATTAINED = "attained"
    ERROR = "error"
    INTERRUPTED = "interrupted"


class Uses(Enum):
    """What a phase looks for: any other limit switch or hard stop it meets is a homing error."""

    NEGATIVE_LIMIT = "negative limit switch"
    POSITIVE_LIMIT = "positive limit switch"
    HOME_SWITCH = "home switch"
    INDEX = "index pulse"
    HARD_STOP = "hard stop"


@dataclass
class Phase:
    """Move in ``direction`` at ``speed`` (qc/ms) until ``found(position)``; ``reference``: the home
    position this phase finds (None: the phase only brings the axis where the next one starts)."""

    direction: int
    speed: float
    uses: Uses
    found: Callable[[float], bool]
    reference: float | None = None


class Machine:
    """The switches and stops around one axis, as functions of its machine position."""

    def __init__(self, settings: AxisSimulation) -> None:
        self.s = settings

    def negative_limit(self, m: float) -> bool:
        return self.s.negative_limit_switch_qc is not None and m <= self.s.negative_limit_switch_qc

    def positive_limit(self, m: float) -> bool:
        return self.s.positive_limit_switch_qc is not None and m >= self.s.positive_limit_switch_qc

    def home_switch(self, m: float) -> bool:
        edge = self.s.home_switch_qc
        if edge is None:
            return False
        return m >= edge if self.s.home_switch_active_above else m <= edge

    def next_index(self, m: float, direction: int) -> float | None:
        """The first index pulse strictly beyond ``m`` in ``direction`` (None: the encoder has none)."""
        spacing = self.s.index_spacing_qc
        if not spacing:
            return None
        k = (m - self.s.index_offset_qc) / spacing
        k = math.floor(k) + 1 if direction > 0 else math.ceil(k) - 1
        return self.s.index_offset_qc + k * spacing

    def stop_between(self, m0: float, m1: float) -> float | None:
        """The hard stop the motion from m0 to m1 runs into (None: none)."""
        if m1 > m0 and self.s.positive_hard_stop_qc is not None and m1 >= self.s.positive_hard_stop_qc > m0 - 1e-9:
            return float(self.s.positive_hard_stop_qc)
        if m1 < m0 and self.s.negative_hard_stop_qc is not None and m1 <= self.s.negative_hard_stop_qc < m0 + 1e-9:
            return float(self.s.negative_hard_stop_qc)
        return None


class HomingRun:
    """One homing, from the start (controlword bit 4 rising in mode 6) to attained, error or interrupt.

    ``step(dt)`` advances the machine position ``m`` and velocity ``v`` (qc/ms) by one sample;
    ``on_reference(home, m)`` is called once, when the home position is found (the drive redefines its
    position there; ``m``: where the axis is then)."""

    def __init__(
        self,
        method: int,
        machine: Machine,
        position: float,
        *,
        switch_speed: float,
        zero_speed: float,
        acceleration: float,
        current_threshold_ma: float,
        on_reference: Callable[[float, float], float | None],
    ) -> None:
        self.method = method
        self.machine = machine
        self.m = position
        self.v = 0.0
        self.a = 0.0
        self.fast = max(switch_speed, 1e-9)
        self.slow = max(zero_speed, 1e-9)
        self.acceleration = max(acceleration, 1e-12)
        self.threshold = current_threshold_ma
        self.on_reference = on_reference
        self.state = HomingState.RUNNING
        self.reason = ""
        self.reference: float | None = None
        self.phases = self._plan(method, position)
        if not self.phases and self.reference is None:  # the current position: no motion
            self._referenced(position)

    # --- the methods ------------------------------------------------------------------------------
    def _plan(self, method: int, m: float) -> list[Phase]:
        mc = self.machine
        neg, pos, home = mc.negative_limit, mc.positive_limit, mc.home_switch
        fast, slow = self.fast, self.slow
        s = mc.s
        if method in (M.CURRENT_POSITION, M.CURRENT_POSITION_37):
            return []
        if method in (M.NEGATIVE_LIMIT_SWITCH, M.NEGATIVE_LIMIT_SWITCH_INDEX):
            edge = None if method == M.NEGATIVE_LIMIT_SWITCH_INDEX else s.negative_limit_switch_qc
            phases = [
                Phase(-1, fast, Uses.NEGATIVE_LIMIT, neg),
                Phase(+1, slow, Uses.NEGATIVE_LIMIT, lambda x: not neg(x), None if edge is None else float(edge)),
            ]
            return phases + ([self._index_phase(+1)] if edge is None else [])
        if method in (M.POSITIVE_LIMIT_SWITCH, M.POSITIVE_LIMIT_SWITCH_INDEX):
            edge = None if method == M.POSITIVE_LIMIT_SWITCH_INDEX else s.positive_limit_switch_qc
            phases = [
                Phase(+1, fast, Uses.POSITIVE_LIMIT, pos),
                Phase(-1, slow, Uses.POSITIVE_LIMIT, lambda x: not pos(x), None if edge is None else float(edge)),
            ]
            return phases + ([self._index_phase(-1)] if edge is None else [])
        if method in (
            M.POSITIVE_HOME_SWITCH_FROM_ABOVE,
            M.POSITIVE_HOME_SWITCH_FROM_BELOW,
            M.NEGATIVE_HOME_SWITCH_FROM_BELOW,
            M.NEGATIVE_HOME_SWITCH_FROM_ABOVE,
        ):
            return self._home_switch_phases(method, home(m))
        if method in (M.INDEX_NEGATIVE, M.INDEX_POSITIVE):
            return [self._index_phase(-1 if method == M.INDEX_NEGATIVE else +1)]
        hard_stop = (M.HARD_STOP_POSITIVE, M.HARD_STOP_NEGATIVE, M.HARD_STOP_POSITIVE_INDEX, M.HARD_STOP_NEGATIVE_INDEX)
        if method in hard_stop:
            toward = +1 if method in (M.HARD_STOP_POSITIVE, M.HARD_STOP_POSITIVE_INDEX) else -1
            phases = [Phase(toward, fast, Uses.HARD_STOP, lambda x: False)]
            if method in (M.HARD_STOP_POSITIVE_INDEX, M.HARD_STOP_NEGATIVE_INDEX):
                phases.append(self._index_phase(-toward))
            return phases
        raise ValueError(f"homing method {method} is not simulated")

    def _home_switch_phases(self, method: int, active: bool) -> list[Phase]:
        """CiA 402 methods 19-22: the initial direction from the switch's state; the home position is
        the edge, approached at zero-search speed from the side the method names."""
        home = self.machine.home_switch
        edge = self.machine.s.home_switch_qc
        ref = None if edge is None else float(edge)
        # (the switch's side: +1 active above its edge, the final approach direction)
        side, approach = {
            M.POSITIVE_HOME_SWITCH_FROM_ABOVE: (+1, -1),
            M.POSITIVE_HOME_SWITCH_FROM_BELOW: (+1, +1),
            M.NEGATIVE_HOME_SWITCH_FROM_BELOW: (-1, +1),
            M.NEGATIVE_HOME_SWITCH_FROM_ABOVE: (-1, -1),
        }[M(method)]
        ends_active = approach == side  # moving into the switch: home where it becomes active
        fast, slow = self.fast, self.slow

        def until(state: bool) -> Callable[[float], bool]:
            return lambda x: home(x) == state

        final = Phase(approach, slow, Uses.HOME_SWITCH, until(ends_active), ref)
        if active != ends_active:  # on the side the final approach starts from
            return [final]
        # on the wrong side: cross the edge (towards the switch when outside it, out of it when inside)
        return [Phase(-approach, fast if not active else slow, Uses.HOME_SWITCH, until(not ends_active)), final]

    def _index_phase(self, direction: int) -> Phase:
        phase = Phase(direction, self.slow, Uses.INDEX, lambda x: False)
        phase.reference = None  # set when the phase begins: the first pulse beyond where it begins
        return phase

    # --- motion -----------------------------------------------------------------------------------
    @property
    def at_rest(self) -> bool:
        return abs(self.v) <= 1e-12

    def interrupt(self) -> None:
        """Halt, bit 4 low, a quick stop: the run ends; the drive's own braking stops the axis."""
        if self.state is HomingState.RUNNING:
            self.state = HomingState.INTERRUPTED

    def step(self, dt: float) -> None:
        """One sample of ``dt`` ms."""
        if dt <= 0:
            return
        if self.state is HomingState.ERROR or self.state is HomingState.INTERRUPTED:
            self._move(0.0, dt)
            return
        if self.reference is not None:
            self._return(dt)
            return
        if not self.phases:
            return
        phase = self.phases[0]
        if phase.uses is Uses.INDEX and phase.reference is None:
            index = self.machine.next_index(self.m, phase.direction)
            if index is None:
                self._error("the encoder has no index pulse")
                return
            phase.reference = index
            d = phase.direction
            phase.found = lambda x, p=index: d * (x - p) >= 0
        m0 = self.m
        self._move(phase.direction * phase.speed, dt)
        stop = self.machine.stop_between(m0, self.m)
        if stop is not None:
            self.m, self.v, self.a = stop, 0.0, 0.0
            if phase.uses is Uses.HARD_STOP and self.machine.s.stall_current_ma > self.threshold:
                self._phase_done(stop)
            else:
                self._error(f"ran into the hard stop at {stop:.0f} qc (following error)")
            return
        if phase.uses is Uses.HARD_STOP and self.machine.s.moving_current_ma > self.threshold and not self.at_rest:
            self._phase_done(self.m)  # the threshold is below the current of a free motion
            return
        mc = self.machine
        limits = ((Uses.NEGATIVE_LIMIT, mc.negative_limit), (Uses.POSITIVE_LIMIT, mc.positive_limit))
        for uses, switch in limits:
            if phase.uses is not uses and switch(self.m) and not switch(m0):
                self._error(f"the {uses.value} became active")
                return
        if phase.found(self.m):
            self._phase_done(phase.reference if phase.reference is not None else self.m)

    def _phase_done(self, at: float) -> None:
        phase = self.phases.pop(0)
        if phase.reference is not None or (phase.uses is Uses.HARD_STOP and not self.phases):
            self._referenced(at)

    def _referenced(self, m_ref: float) -> None:
        self.phases = []
        moved = self.on_reference(m_ref, self.m)  # a drive may place its home past the reference
        self.reference = m_ref = m_ref if moved is None else moved
        if self.at_rest and abs(self.m - m_ref) <= RETURN_TOLERANCE_QC:
            self.m = m_ref
            self.state = HomingState.ATTAINED

    def _return(self, dt: float) -> None:
        """Brake and come back to stand on the home position (at zero-search speed)."""
        assert self.reference is not None
        rem = self.reference - self.m
        if abs(rem) <= RETURN_TOLERANCE_QC and self.at_rest:
            self.m, self.state = self.reference, HomingState.ATTAINED
            return
        target_v = math.copysign(min(self.slow, math.sqrt(2.0 * self.acceleration * abs(rem))), rem)
        m0 = self.m
        self._move(target_v, dt)
        crossed = (self.reference - m0) * (self.reference - self.m) <= 0
        if crossed and abs(self.v) <= 2.0 * self.acceleration * dt + math.sqrt(2.0 * self.acceleration):
            self.m, self.v, self.a = self.reference, 0.0, 0.0
            self.state = HomingState.ATTAINED

    def _move(self, target_v: float, dt: float) -> None:
        dv = max(-self.acceleration * dt, min(self.acceleration * dt, target_v - self.v))
        v1 = self.v + dv
        self.m += 0.5 * (self.v + v1) * dt
        self.a = dv / dt
        self.v = v1

    def _error(self, reason: str) -> None:
        self.state = HomingState.ERROR
        self.reason = reason


class Homing:
    """The simulated machine around an axis and homing mode 6 on it, a part of its ``SimulatedDrive``
    (which asks it from its controlword, sample and statusword code and moves its demand as it says;
    the drive's dictionary gives it the homing objects).

    The machine position is the drive's demand plus ``origin``: at power-on the encoder counts from 0
    wherever the axis stands; homing moves ``origin`` so that the home position reads 0x607C."""

    def __init__(
        self,
        node_id: int,
        simulation: AxisSimulation | None,
        limits: DriveLimits | None,
        dictionary: DriveDictionary,
        *,
        units_per_qc_ms: float,
        rpm_s_per_qc_ms2: float,
    ) -> None:
        self.simulation = simulation
        self.machine = Machine(simulation or AxisSimulation())
        self.origin = power_up_position(node_id, simulation, limits)
        self.referenced = False  # homed since the last power-on / reset
        self.runs: list[HomingRun] = []  # every homing started (tests, benches)
        self.run: HomingRun | None = None
        self._t = 0.0  # the motion time (ms) of the run's last step
        self._dictionary = dictionary
        self._units_per_qc_ms = units_per_qc_ms  # 0x6099 in the drive's velocity unit
        self._rpm_s_per_qc_ms2 = rpm_s_per_qc_ms2

    def power_on(self, demand: float) -> None:
        """Power-on: the encoder counts from 0 where the axis stands (``demand`` before), not homed."""
        self.origin += demand
        self.referenced = False
        self.run = None

    def machine_position(self, demand: float) -> float:
        """Where the axis really is (qc of the machine) at ``demand``: what its position reads once homed."""
        return demand + self.origin

    @property
    def running(self) -> bool:
        return self.run is not None and self.run.state is HomingState.RUNNING

    def status(self, rest: bool) -> int:
        """Statusword bits 13, 12, 10 in homing mode (CiA 402): in progress 000, interrupted or not
        started 001, attained 01x, completed 011, error 10x (bit 10: the axis is at rest, ``rest``)."""
        run = self.run
        word = TARGET_REACHED if rest else 0
        if run is None or run.state is HomingState.INTERRUPTED:
            return word
        if run.state is HomingState.RUNNING:
            return 0
        if run.state is HomingState.ATTAINED:
            return HOMING_ATTAINED | word
        return HOMING_ERROR | word

    def start(self, demand: float, t_ms: float) -> float | None:
        """Controlword bit 4 rose in mode 6 at motion time ``t_ms``: the method of 0x6098 at the speeds of
        0x6099 and 0x609A. The demand the drive then stands on when the run attained home at once (the
        current-position methods), else None."""
        self.referenced = False
        read_or = self._dictionary.read_or
        method = read_or(od.HOMING_METHOD, 0, 0)
        try:
            run = HomingRun(
                method,
                self.machine,
                self.machine_position(demand),
                switch_speed=read_or(od.HOMING_SPEEDS, 1, 0) / self._units_per_qc_ms,
                zero_speed=read_or(od.HOMING_SPEEDS, 2, 0) / self._units_per_qc_ms,
                acceleration=read_or(od.HOMING_ACCELERATION, 0, 0) / self._rpm_s_per_qc_ms2,
                current_threshold_ma=read_or(od.EPOS2_HOMING_CURRENT_THRESHOLD, 0, 500),
                on_reference=self.home_found,
            )
        except ValueError as exc:  # a method 0x6098 holds but this drive does not run
            run = HomingRun(
                od.HomingMethod.CURRENT_POSITION,
                self.machine,
                self.machine_position(demand),
                switch_speed=1.0,
                zero_speed=1.0,
                acceleration=1.0,
                current_threshold_ma=0,
                on_reference=lambda home, m: None,
            )
            run.state, run.reason = HomingState.ERROR, str(exc)
        self.run = run
        self._t = t_ms
        self.runs.append(run)
        if run.state is HomingState.ATTAINED:
            self.referenced = True
            return float(round(run.m - self.origin))
        return None

    def home_found(self, home: float, m: float) -> float | None:
        """The reference is found at ``home`` (``m``: where the axis is): the origin moves so that the
        home position reads as the drive defines it; where the axis goes to stand (None: on the reference)."""
        self.origin, stand_at = self.placement(home)
        return stand_at

    def placement(self, home: float) -> tuple[float, float | None]:
        """The origin and where the axis stands once the reference is found at ``home``: CiA 402's, the
        position reads 0x607C on the reference itself (the EPOS2 places it otherwise, epos2.py)."""
        return home - self._dictionary.read_or(od.HOME_OFFSET, 0, 0), None

    def sample(self, t: float) -> tuple[float, float, float]:
        """One step of the run at motion time ``t`` (ms): the drive's demand, velocity, acceleration."""
        run = self.run
        assert run is not None
        run.step(t - self._t)
        self._t = t
        if run.state is HomingState.ATTAINED:
            self.referenced = True
            return float(round(run.m - self.origin)), 0.0, 0.0
        return run.m - self.origin, run.v, run.a

    def moves(self) -> bool:
        """The run moves the axis (running, or braking after a homing error); the drive asks it only in
        OPERATION ENABLED and homing mode."""
        run = self.run
        return run is not None and (
            run.state is HomingState.RUNNING or (run.state is HomingState.ERROR and not run.at_rest)
        )

    def interrupt(self) -> None:
        if self.run is not None:
            self.run.interrupt()

    def machine_stop(self, demand: float, p: float) -> tuple[float, int, str] | None:
        """The simulated machine bounds every motion outside homing: a limit switch that becomes active
        faults the drive (EMCY 0x8612), a hard stop stops the axis where it stands and faults it with a
        following error (0x8611). So an axis that did not home, whose encoder's 0 is anywhere, really
        runs into them where the program thought it had room. None: the motion from ``demand`` to ``p``
        meets nothing; else the demand the axis stops at, the EMCY code and why."""
        if self.simulation is None:
            return None
        m0, m1 = demand + self.origin, p + self.origin
        stop = self.machine.stop_between(m0, m1)
        if stop is not None:
            why = f"ran into the hard stop at {stop:.0f} qc of the machine"
            return stop - self.origin, od.EMCY_FOLLOWING_ERROR, why
        for name, switch in (("negative", self.machine.negative_limit), ("positive", self.machine.positive_limit)):
            if switch(m1) and not switch(m0):
                return demand, od.EMCY_LIMIT_SWITCH, f"{name} limit switch at {m1:.0f} qc of the machine"
        return None


def power_up_position(node_id: int, sim: AxisSimulation | None, limits: DriveLimits | None) -> float:
    """Where the machine stands at power-on: nowhere in particular for an axis with a simulated
    machine (seeded: between its limit switches or hard stops, else in its 0x607D range), at its
    encoder's 0 otherwise (an absolute encoder: nothing to home)."""
    if sim is None:
        return 0.0
    if sim.power_up_qc is not None:
        return float(sim.power_up_qc)
    lows = [x for x in (sim.negative_limit_switch_qc, sim.negative_hard_stop_qc) if x is not None]
    highs = [x for x in (sim.positive_limit_switch_qc, sim.positive_hard_stop_qc) if x is not None]
    lo = max(lows) if lows else (limits.min_position_qc if limits is not None else -100_000)
    hi = min(highs) if highs else (limits.max_position_qc if limits is not None else 100_000)
    margin = 0.05 * (hi - lo)
    return float(round(random.Random(sim.seed * 1000 + node_id).uniform(lo + margin, hi - margin)))
