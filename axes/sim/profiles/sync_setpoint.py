"""Simulated bufferless servodrive in interpolated position mode (seed servodrive-ip-no-buffer).

No data buffer (no 0x60C4): one setpoint per SYNC period, 0x60C2 between 1.0 and 100.0 ms
(checked when interpolation starts: EMCY 0x6320 and fault otherwise). Setpoint(K), validated by
SYNC K, is reached by the end of the NEXT period: the drive starts a straight ramp to it at SYNC K+1
and gets there at SYNC K+2 (two periods of delay). Profile parameters do not limit it; only
0x607D and the 0x607F sanity check fault it. With the master sending record k to be validated at
program time (k - 1)*T the demand is ``axes.drive.interpolation.linear`` of the records.

Wall clock, an early SYNC: the seed says "one value needs to be sent by the master to the device
for each sync period and the device will generate a ramp that will drive the motor to that
position on the end of the NEXT sync period", with the period set in 0x60C2 ("allowed interpolation
period range is 1.0ms ... 100.0ms"), and "profile parameters don't influence trajectory
generation; the master is responsible of limiting speed/acceleration/deceleration". So every SYNC,
early or not, starts the ramp to the setpoint the SYNC before validated, from where the demand is,
ending 0x60C2 later on the drive's clock; only the 0x607D / 0x607F sanity checks judge it.

Having no ramp of its own, it judges each SYNC's setpoint as it validates it (a SYNC with none holds
the last): the step against 0x607F, the change of step against 0x60C5 (``FixedPeriodDrive._judge``),
so a master that stops it by freezing its setpoints at speed faults it.
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.sim.node.device import SYNC_SETPOINT_MODES
from pvtflow.axes.sim.node.dictionary import ABORT_VALUE_RANGE
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive

MIN_PERIOD_MS, MAX_PERIOD_MS = 1.0, 100.0


class SyncSetpointDrive(FixedPeriodDrive):
    PROFILE = DriveProfile.SYNC_SETPOINT
    EDS = "sync_setpoint.eds"
    MODES = SYNC_SETPOINT_MODES
    HOMING_METHODS = od.CIA402_HOMING_METHODS  # its 0x60E3 lists "the methods of the servodrive manual"
    delay_periods = 2

    def _reset_stream(self) -> None:
        self._pending: int | None = None  # validated at the last SYNC, ramped to from this one

    def _check_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.INTERPOLATION_SUBMODE and value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # only the default linear interpolation

    def _activate(self) -> bool:
        period = self.period_ms
        if not MIN_PERIOD_MS - 1e-9 <= period <= MAX_PERIOD_MS + 1e-9:
            why = f"interpolation period 0x60C2 = {period:g} ms outside 1.0-100.0 ms"
            self.fault(od.EMCY_PARAMETER_ERROR, why)
            return False
        return super()._activate()

    def _validated(self, now: float, target: int | None) -> None:
        if not self._judge(target):
            return
        if self._pending is not None:
            self._ramp(now, self._pending, self.period_ms)
        self._pending = target
