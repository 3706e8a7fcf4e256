"""Faults of a simulated drive: the fault reaction (the error objects and the EMCY: ``axes/sim/node/emcy.py``).

A fault stops the axis at once (the power stage off, the demand on the actual position), or, where
its reaction brakes first as 0x605E says, in FAULT REACTION ACTIVE until the demand is at rest. It
sets 0x603F, 0x1001 and 0x1003 and sends its EMCY (the drive's ``emcy`` part); a fault reset
(controlword bit 7) clears them and sends EMCY 0x0000. Tests inject errors as the drive would raise
them (``inject_emcy``).
"""

from __future__ import annotations

import threading

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.sim.cia402.homing_mode import Homing
from pvtflow.axes.sim.cia402.power_states import (
    FAULT,
    FAULT_REACTION_ACTIVE,
    OPERATION_ENABLED,
    QUICK_STOP_ACTIVE,
    SWITCH_ON_DISABLED,
)
from pvtflow.axes.sim.cia402.records import FaultRecord
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.node.emcy import REGISTER_GENERIC, Emcy


class FaultHandling:
    """The fault reaction as part of a ``SimulatedDrive`` (which owns the state below and gives it the
    object dictionary access, its EMCY, ``_deceleration``, the homing and the profiles' hooks)."""

    lock: threading.RLock
    state: PowerState
    faults: list[FaultRecord]
    emcy: Emcy
    sync_count: int
    sample_ms: float
    time_us: int
    demand: float
    velocity: float
    acceleration: float
    _stop_segment: Segment | None
    homing: Homing

    def fault(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """Fault reaction: the drive stops its interpolation, sends EMCY and waits in FAULT for a reset."""
        if self.state == FAULT:
            return
        self.faults.append(FaultRecord(self.sync_count, self.sample_ms, code, check))
        self._abort_motion()
        self.homing.interrupt()
        self._stop_segment = None
        self.velocity = self.acceleration = 0.0
        self.demand = float(self.actual)  # the power stage is off: the demand follows the actual position
        self.state = FAULT
        self.emcy.signal_fault(code, data, register)

    def fault_braking(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """A fault whose reaction brakes first, as 0x605E says (1: profile deceleration, 2: quick stop
        ramp; 0, or at rest: at once, as ``fault``): FAULT REACTION ACTIVE while braking, then FAULT."""
        if self.state in (FAULT, FAULT_REACTION_ACTIVE):
            return
        reaction = self.read_or(od.FAULT_REACTION_OPTION_CODE, 0, od.FaultReaction.QUICK_STOP)
        v = self.velocity
        moving = self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and abs(v) > 1e-12
        if reaction not in (od.FaultReaction.SLOW_DOWN, od.FaultReaction.QUICK_STOP) or not moving:
            self.fault(code, check, data, register)
            return
        self.faults.append(FaultRecord(self.sync_count, self.sample_ms, code, check))
        deceleration = self._deceleration(quick=reaction == od.FaultReaction.QUICK_STOP)
        self.state = FAULT_REACTION_ACTIVE  # before the abort: an EPOS2 empties its FIFO (app note 3.8)
        self._abort_motion()
        self.homing.interrupt()
        self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, v, deceleration)
        self.emcy.signal_fault(code, data, register)

    def _fault_reset(self) -> None:
        self.state = SWITCH_ON_DISABLED
        self.emcy.clear_errors()
        self._on_fault_reset()
        self.emcy.send(od.EMCY_NO_ERROR, 0)

    def inject_emcy(self, code: int, *, fault: bool = True, data: bytes = b"") -> None:
        """Raise an error as the drive would: EMCY with ``code`` and, by default, the fault state."""
        with self.lock:
            if fault:
                self.fault(code, "injected", data)
            else:
                self.emcy.send(code, data=data)
            self._refresh()
