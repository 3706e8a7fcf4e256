"""Simulated CiA 402 drive with linear interpolation and one target point (seed
cia402-ip-linear-single-setpoint).

Mode 7; 0x60C2:01 is the time between two targets (ms); 0x60C4:06 = 1 must be written before
0x60C1:01 is accepted (otherwise SDO abort 0x08000022, and an RPDO value is dropped). Bit 4 of the
controlword enables interpolation from the next SYNC. A target validated by SYNC s is reached, on a
straight line from the present demand, at the end of the period that SYNC starts (one period of
delay): with the master sending record k to be validated at program time k*T the demand is
``axes.drive.interpolation.linear`` of the records.

Wall clock, an early SYNC (less than a period after the previous one): the seed gives the ramp its
time, "60C2h:01h: Time in ms between two given target positions", and its shape, "The controller
follows a path linear interpolated between the current and the given position"; it asks the master
"to deliver the target positions in time". So a SYNC latches whatever target it finds and the
drive runs from the current demand to it over 0x60C2 from that SYNC, early or not; a late one
finds the ramp ended and the drive on the given position.
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.sim.node.device import IP_LINEAR_MODES
from pvtflow.axes.sim.node.dictionary import ABORT_DEVICE_STATE, ABORT_VALUE_RANGE
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive


class IpLinearDrive(FixedPeriodDrive):
    PROFILE = DriveProfile.CIA402_IP_LINEAR
    EDS = "cia402_ip_linear.eds"
    MODES = IP_LINEAR_MODES
    delay_periods = 1

    def _reset_profile(self) -> None:
        super()._reset_profile()
        self.buffer_enabled = False

    def _check_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.INTERPOLATION_DATA_RECORD and subindex == 1 and not self.buffer_enabled:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        if index == od.INTERPOLATION_DATA_CONFIGURATION and subindex == 6 and value not in (0, 1):
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == od.INTERPOLATION_SUBMODE and value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # "only linear interpolation is supported"
        if index == od.INTERPOLATION_TIME_PERIOD and subindex == 1 and value == 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def _on_object_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.INTERPOLATION_DATA_CONFIGURATION and subindex == 6:
            self.buffer_enabled = value == 1
            if not self.buffer_enabled:
                self._forget_setpoint()
        super()._on_object_write(index, subindex, value)

    def _validated(self, now: float, target: int | None) -> None:
        if target is not None:
            self._ramp(now, target, self.period_ms)
