"""The DS402 power state machine of a simulated drive, driven by the controlword, its statusword and
its fault reaction.

The transitions are CiA 402's (the numbers in the comments), with the EPOS2's shortcut of switch on
and enable operation in one controlword. Leaving OPERATION ENABLED stops the motion: a quick stop
brakes on 0x6085 (then SWITCH ON DISABLED), a halt (bit 8) on 0x6084, anything else at once. The
statusword is the power state's bits plus voltage enabled, warning, target reached, ip mode active
(or the homing bits in homing mode) and a manufacturer's "referenced" bit.

A fault stops the axis at once (the power stage off, the demand on the actual position), or, where
its reaction brakes first as 0x605E says, in FAULT REACTION ACTIVE until the demand is at rest. It
sets 0x603F, 0x1001 and 0x1003 and sends its EMCY (the drive's ``emcy`` part); a fault reset
(controlword bit 7) clears them and sends EMCY 0x0000. Tests inject errors as the drive would raise
them (``inject_emcy``). This module is the only writer of the power state, the controlword seen, the
halts and the faults; the motion it stops is ``sampling.py``'s.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, ClassVar

from canopen.profiles.p402 import State402

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Controlword, PowerState, Statusword
from pvtflow.axes.sim.cia402.records import FaultRecord
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.node.emcy import REGISTER_GENERIC, Emcy

if TYPE_CHECKING:
    from pvtflow.axes.sim.cia402.homing_mode import Homing
    from pvtflow.axes.sim.node.master_loss import MasterLossReaction

# DS402 power states and statusword/controlword bits: the master's definitions (axes/drive/cia402.py),
# short names for the drive side
NOT_READY = PowerState.NOT_READY_TO_SWITCH_ON
SWITCH_ON_DISABLED = PowerState.SWITCH_ON_DISABLED
READY_TO_SWITCH_ON = PowerState.READY_TO_SWITCH_ON
SWITCHED_ON = PowerState.SWITCHED_ON
OPERATION_ENABLED = PowerState.OPERATION_ENABLED
QUICK_STOP_ACTIVE = PowerState.QUICK_STOP_ACTIVE
FAULT_REACTION_ACTIVE = PowerState.FAULT_REACTION_ACTIVE
FAULT = PowerState.FAULT

VOLTAGE_ENABLED = int(Statusword.VOLTAGE_ENABLED)
WARNING = int(Statusword.WARNING)
TARGET_REACHED = int(Statusword.TARGET_REACHED)
IP_MODE_ACTIVE = int(Statusword.IP_MODE_ACTIVE)


class DeviceControl:
    """The power state machine and the fault reaction as part of a ``SimulatedDrive`` (which owns the
    state below and gives it ``read_or``, its EMCY, its homing, its motion and the profiles' hooks)."""

    REFERENCED_BIT: ClassVar[int]
    lock: threading.RLock
    state: PowerState
    _controlword: int
    faults: list[FaultRecord]
    emcy: Emcy
    sample_ms: float
    _stop_segment: Segment | None
    demand: float
    velocity: float
    acceleration: float
    time_us: int
    sync_count: int
    halts: list[int]
    mode_display: int
    ip_active: bool
    homing: Homing
    master_loss: MasterLossReaction
    _rpm_s_per_qc_ms2: float

    def _power_on_state(self) -> None:
        """Power-on: switch on disabled (transition 1 is automatic), no controlword yet."""
        self.state = SWITCH_ON_DISABLED
        self._controlword = 0

    def _braked(self) -> None:
        """The braking segment ended at rest: a quick stop disables, a fault reaction ends in FAULT."""
        if self.state == QUICK_STOP_ACTIVE:
            self.state = SWITCH_ON_DISABLED
        elif self.state == FAULT_REACTION_ACTIVE:
            self.state = FAULT  # braked to rest: the power stage goes off

    def _on_controlword(self, cw: int) -> None:
        previous, self._controlword = self._controlword, cw
        state = self.state
        if state == FAULT:
            if cw & Controlword.FAULT_RESET and not previous & Controlword.FAULT_RESET:
                self._fault_reset()
            return
        if state == FAULT_REACTION_ACTIVE:
            return
        new = state
        if cw & 0x0002 == 0:  # disable voltage: 7, 9, 10, 12
            if state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
                new = SWITCH_ON_DISABLED
        elif cw & 0x0006 == 0x0002:  # quick stop: 7, 10, 11
            if state in (READY_TO_SWITCH_ON, SWITCHED_ON):
                new = SWITCH_ON_DISABLED
            elif state == OPERATION_ENABLED:
                new = QUICK_STOP_ACTIVE
        elif cw & 0x0007 == 0x0006:  # shutdown: 2, 6, 8
            if state in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                new = READY_TO_SWITCH_ON
        elif cw & 0x000F == 0x0007:  # switch on / disable operation: 3, 5
            if state in (READY_TO_SWITCH_ON, OPERATION_ENABLED):
                new = SWITCHED_ON
        elif cw & 0x000F == 0x000F and state in (READY_TO_SWITCH_ON, SWITCHED_ON, QUICK_STOP_ACTIVE):
            new = OPERATION_ENABLED  # 4, 16 (and 3 + 4 at once, as the EPOS2 accepts)
        if new != state:
            if state == OPERATION_ENABLED:
                self.homing.interrupt()
                if new == QUICK_STOP_ACTIVE:
                    self._begin_stop(self._deceleration(quick=True))
                else:
                    self._abort_motion()
                    self._rest()
            if state == QUICK_STOP_ACTIVE:
                self._rest()
            self.state = new
            if new == QUICK_STOP_ACTIVE and self._stop_segment is None:
                self.state = SWITCH_ON_DISABLED  # already at rest: quick stop option code 2
            elif new == QUICK_STOP_ACTIVE:
                self.master_loss.brake_on_own_clock()
            if new == OPERATION_ENABLED:
                self._enter_operation()
        if self.state == OPERATION_ENABLED:
            if cw & Controlword.HALT and not previous & Controlword.HALT:
                self.halts.append(self.sync_count)
                self._begin_stop(self._deceleration(quick=False))
            self._on_mode_bits(previous, cw)

    def _deceleration(self, quick: bool) -> float:
        """Halt: profile deceleration 0x6084; quick stop: 0x6085 where the drive has it. In qc/ms^2."""
        quick_stop = od.QUICK_STOP_DECELERATION
        index = quick_stop if quick and self.has(quick_stop) else od.PROFILE_DECELERATION
        rpm_s = max(self.read_or(index, 0, 10000), 1)
        return rpm_s / self._rpm_s_per_qc_ms2

    @property
    def braking(self) -> bool:
        """The drive brakes on its own (a halt, a quick stop, a fault reaction): until the demand is at rest."""
        return self._stop_segment is not None

    @property
    def halted(self) -> bool:
        """Halt is set now (the master clears it again when it readies the drive for the next run:
        ``halts`` tells whether a run was halted)."""
        return bool(self._controlword & Controlword.HALT)

    def statusword(self) -> int:
        _mask, value = State402.SW_MASK[self.state]
        word = value
        if self.state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            word |= VOLTAGE_ENABLED
        if self._warning():
            word |= WARNING
        if self.mode_display == od.HOMING_MODE:
            rest = self.state == OPERATION_ENABLED and self._stop_segment is None and abs(self.velocity) <= 1e-12
            word |= self.homing.status(rest)
        else:
            if self.state == OPERATION_ENABLED and self._stop_segment is None and self._target_reached():
                word |= TARGET_REACHED
            if self.ip_active:
                word |= IP_MODE_ACTIVE
        if self.homing.referenced:
            word |= self.REFERENCED_BIT
        return word

    # --- the fault reaction --------------------------------------------------------------------------
    def fault(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """Fault reaction: the drive stops its interpolation, sends EMCY and waits in FAULT for a reset."""
        if self.state == FAULT:
            return
        self.faults.append(FaultRecord(self.sync_count, self.sample_ms, code, check))
        self._abort_motion()
        self.homing.interrupt()
        self._stop_at_once()  # the power stage is off: the demand follows the actual position
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
        self._brake(v, deceleration)
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
