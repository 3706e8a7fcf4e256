"""The DS402 power state machine of a simulated drive, driven by the controlword, and its statusword.

The transitions are CiA 402's (the numbers in the comments), with the EPOS2's shortcut of switch on
and enable operation in one controlword. Leaving OPERATION ENABLED stops the motion: a quick stop
brakes on 0x6085 (then SWITCH ON DISABLED), a halt (bit 8) on 0x6084, anything else at once. The
statusword is the power state's bits plus voltage enabled, warning, target reached, ip mode active
(or the homing bits in homing mode) and a manufacturer's "referenced" bit.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from canopen.profiles.p402 import State402

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Controlword, PowerState, Statusword
from pvtflow.axes.sim.cia402.segment import Segment

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
    """The power state machine as part of a ``SimulatedDrive`` (which owns the state below and gives
    it ``read_or``, the homing and fault calls and the profiles' hooks)."""

    REFERENCED_BIT: ClassVar[int]
    state: PowerState
    _controlword: int
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
                    self._stop_segment = None
                    self.velocity = self.acceleration = 0.0
            if state == QUICK_STOP_ACTIVE:
                self._stop_segment = None
                self.velocity = self.acceleration = 0.0
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

    def _begin_stop(self, deceleration: float) -> None:
        v = self.velocity
        self._abort_motion()
        if abs(v) > 1e-12:
            self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, v, deceleration)
        else:  # at rest: the demand settles on its whole count (see Segment.braking)
            self._stop_segment = None
            self.velocity = self.acceleration = 0.0
            self.demand = float(round(self.demand))

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
