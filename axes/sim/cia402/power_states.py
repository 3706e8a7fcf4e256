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

from typing import TYPE_CHECKING, Protocol

from canopen.profiles.p402 import State402

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Controlword, PowerState, Statusword
from pvtflow.axes.sim.cia402.records import FaultRecord
from pvtflow.axes.sim.node.dictionary import DriveDictionary
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


class MotionControl(Protocol):
    """What the power state machine asks of the drive's motion (``sampling.Motion``)."""

    velocity: float
    sync_count: int
    sample_ms: float

    @property
    def braking(self) -> bool: ...

    def rest(self) -> None: ...

    def stop_at_once(self) -> None: ...

    def brake(self, velocity: float, deceleration: float) -> None: ...

    def begin_stop(self, deceleration: float) -> None: ...


class PowerHost(Protocol):
    """What the power state machine needs of its drive (a ``SimulatedDrive``): its dictionary, EMCY,
    homing and lost-master reaction, what its statusword shows, and its motion and profile hooks,
    which it asks to stop, brake or hold (the motion is ``sampling.py``'s)."""

    REFERENCED_BIT: int
    dictionary: DriveDictionary
    emcy: Emcy
    homing: Homing
    master_loss: MasterLossReaction
    motion: MotionControl
    mode_display: int
    ip_active: bool

    def _abort_motion(self) -> None: ...

    def _enter_operation(self) -> None: ...

    def _on_mode_bits(self, previous: int, controlword: int) -> None: ...

    def _on_fault_reset(self) -> None: ...

    def _warning(self) -> bool: ...

    def _target_reached(self) -> bool: ...


class PowerStateMachine:
    """The power state machine, its statusword and the fault reaction, a part of a ``SimulatedDrive``
    (given as ``drive``; called under the drive's lock). It owns the power state, the controlword it
    was last given, the halts and the faults."""

    def __init__(self, drive: PowerHost, *, rpm_s_per_qc_ms2: float) -> None:
        self._drive = drive
        self._rpm_s_per_qc_ms2 = rpm_s_per_qc_ms2
        self.state = SWITCH_ON_DISABLED
        self.controlword = 0
        self.halts: list[int] = []  # the SYNC count at every halt (controlword bit 8) taken in OPERATION ENABLED
        self.faults: list[FaultRecord] = []

    def power_on(self) -> None:
        """Power-on: switch on disabled (transition 1 is automatic), no controlword yet."""
        self.state = SWITCH_ON_DISABLED
        self.controlword = 0

    def braked(self) -> None:
        """The braking segment ended at rest: a quick stop disables, a fault reaction ends in FAULT."""
        if self.state == QUICK_STOP_ACTIVE:
            self.state = SWITCH_ON_DISABLED
        elif self.state == FAULT_REACTION_ACTIVE:
            self.state = FAULT  # braked to rest: the power stage goes off

    def on_controlword(self, cw: int) -> None:
        d = self._drive
        previous, self.controlword = self.controlword, cw
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
                d.homing.interrupt()
                if new == QUICK_STOP_ACTIVE:
                    d.motion.begin_stop(self.deceleration(quick=True))
                else:
                    d._abort_motion()
                    d.motion.rest()
            if state == QUICK_STOP_ACTIVE:
                d.motion.rest()
            self.state = new
            if new == QUICK_STOP_ACTIVE and not d.motion.braking:
                self.state = SWITCH_ON_DISABLED  # already at rest: quick stop option code 2
            elif new == QUICK_STOP_ACTIVE:
                d.master_loss.brake_on_own_clock()
            if new == OPERATION_ENABLED:
                d._enter_operation()
        if self.state == OPERATION_ENABLED:
            if cw & Controlword.HALT and not previous & Controlword.HALT:
                self.halts.append(d.motion.sync_count)
                d.motion.begin_stop(self.deceleration(quick=False))
            d._on_mode_bits(previous, cw)

    def deceleration(self, quick: bool) -> float:
        """Halt: profile deceleration 0x6084; quick stop: 0x6085 where the drive has it. In qc/ms^2."""
        dictionary = self._drive.dictionary
        quick_stop = od.QUICK_STOP_DECELERATION
        index = quick_stop if quick and dictionary.has(quick_stop) else od.PROFILE_DECELERATION
        rpm_s = max(dictionary.read_or(index, 0, 10000), 1)
        return rpm_s / self._rpm_s_per_qc_ms2

    @property
    def halted(self) -> bool:
        """Halt is set now (the master clears it again when it readies the drive for the next run:
        ``halts`` tells whether a run was halted)."""
        return bool(self.controlword & Controlword.HALT)

    def statusword(self) -> int:
        d = self._drive
        _mask, value = State402.SW_MASK[self.state]
        word = value
        if self.state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            word |= VOLTAGE_ENABLED
        if d._warning():
            word |= WARNING
        if d.mode_display == od.HOMING_MODE:
            rest = self.state == OPERATION_ENABLED and not d.motion.braking and abs(d.motion.velocity) <= 1e-12
            word |= d.homing.status(rest)
        else:
            if self.state == OPERATION_ENABLED and not d.motion.braking and d._target_reached():
                word |= TARGET_REACHED
            if d.ip_active:
                word |= IP_MODE_ACTIVE
        if d.homing.referenced:
            word |= d.REFERENCED_BIT
        return word

    # --- the fault reaction --------------------------------------------------------------------------
    def fault(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """Fault reaction: the drive stops its interpolation, sends EMCY and waits in FAULT for a reset."""
        if self.state == FAULT:
            return
        d = self._drive
        self.faults.append(FaultRecord(d.motion.sync_count, d.motion.sample_ms, code, check))
        d._abort_motion()
        d.homing.interrupt()
        d.motion.stop_at_once()  # the power stage is off: the demand follows the actual position
        self.state = FAULT
        d.emcy.signal_fault(code, data, register)

    def fault_braking(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """A fault whose reaction brakes first, as 0x605E says (1: profile deceleration, 2: quick stop
        ramp; 0, or at rest: at once, as ``fault``): FAULT REACTION ACTIVE while braking, then FAULT."""
        if self.state in (FAULT, FAULT_REACTION_ACTIVE):
            return
        d = self._drive
        reaction = d.dictionary.read_or(od.FAULT_REACTION_OPTION_CODE, 0, od.FaultReaction.QUICK_STOP)
        v = d.motion.velocity
        moving = self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and abs(v) > 1e-12
        if reaction not in (od.FaultReaction.SLOW_DOWN, od.FaultReaction.QUICK_STOP) or not moving:
            self.fault(code, check, data, register)
            return
        self.faults.append(FaultRecord(d.motion.sync_count, d.motion.sample_ms, code, check))
        deceleration = self.deceleration(quick=reaction == od.FaultReaction.QUICK_STOP)
        self.state = FAULT_REACTION_ACTIVE  # before the abort: an EPOS2 empties its FIFO (app note 3.8)
        d._abort_motion()
        d.homing.interrupt()
        d.motion.brake(v, deceleration)
        d.emcy.signal_fault(code, data, register)

    def _fault_reset(self) -> None:
        self.state = SWITCH_ON_DISABLED
        self._drive.emcy.clear_errors()
        self._drive._on_fault_reset()
        self._drive.emcy.send(od.EMCY_NO_ERROR, 0)
