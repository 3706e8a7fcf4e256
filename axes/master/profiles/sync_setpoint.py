"""A bufferless servodrive: one setpoint per SYNC (seed servodrive-ip-no-buffer).

Configuration: mode 7, 0x60C2:01 = the SYNC period (1-100 ms), no 0x60C4 (the drive has no buffer),
0x607F/0x60C5/0x607D/0x6065 where the drive has them, read back (``Profile.write_settings``);
the same PDOs as the other fixed-period profiles; the master's heartbeat watched (0x1016, 0x6007 = 1:
``Profile.supervise_master``; the seed names neither object, so a real drive that lacks them is
refused at configuration). Feed: one target position per SYNC; the drive
ignores its profile objects, so the program alone keeps speed and acceleration in bounds (the
validator checks the linear reconstruction). Delay: the drive ramps to a setpoint by the end of the
period after the one the validating SYNC starts: two periods from validation (DESIGN section 5,
"two-period delay to compensate"), so record k is validated at program time (k - 1) periods and
record 0, the start position where the axis already is, is not sent. End: the last setpoint is
held and bit 4 cleared. Halt and stop: the drive has no ramp of its own, so the master brakes it
with setpoints within 0x60C5 (``axes.drive.stop_ramp``), not with the halt bit.
"""

from __future__ import annotations

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.master.profiles.cia402_ip_linear import FixedPeriodProfile


class SyncSetpoint(FixedPeriodProfile):
    name = DriveProfile.SYNC_SETPOINT
    homing_methods = name.spec.homing_methods

    @property
    def delay_periods(self) -> int:
        return 2

    @property
    def ramps_by_itself(self) -> bool:
        return False  # "the master is responsible of limiting speed/acceleration/deceleration"

    def configure(self) -> None:
        link = self.link
        link.write(od.MODES_OF_OPERATION, 0, od.INTERPOLATED_POSITION_MODE, "b")
        self.write_period()
        link.write_optional(od.COMMUNICATION_CYCLE_PERIOD, 0, self.period_ms * 1000, "I")
        self.write_settings()
        link.map_pdos(self.rpdos, self.tpdos)
        self.write_heartbeat()
        self.supervise_master()
