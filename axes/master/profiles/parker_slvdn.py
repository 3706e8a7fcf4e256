"""Parker SLVDN interpolated position mode, operative mode 202 (seed parker-slvdn-ip-mode-202).

Configuration: Pr31 = 202 (0x2000 + 31), the cycle in 0x1006 (us) = the SYNC period, 0x60C0 the
interpolation submode (0 linear, -1 cubic position + velocity, -2 cubic position only),
0x607F/0x60C5/0x607D/0x6065 where the drive has them, read back (``Profile.write_settings``), PDO 4 rx
synchronous with the target position 0x60C1:01 and the velocity feed-forward in rpm 0x60C1:03,
RPDO2 controlword, TPDO1 statusword + position answering every SYNC; the master's heartbeat
watched (0x1016, 0x6007 = 3, quick stop: ``Profile.supervise_master``; the seed names neither object, so a real
SLVDN that lacks them is refused at configuration).
Feed: position + velocity (record velocity x velocity unit, in rpm) per cycle. Delay: below
2500 us the position loop takes the setpoint at the SYNC that validates it (no delay: record k is
validated at its own program time); from 2500 us on it is reached one cycle after validation
(submodes 0 and -1). Submode -2 lags two cycles; the second is in the planner's reconstruction
(``interpolation.cubic_p`` starts one cycle late), so it is fed one cycle ahead like -1.
End: hold, clear bit 4. Halt and stop: from 2500 us the drive interpolates and brakes on its own
ramp (halt bit); below, its position loop takes each setpoint as it comes and has no ramp, so the
master brakes it with setpoints within 0x60C5 (``axes.drive.stop_ramp``).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from functools import partial

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.interpolation import Interpolation
from pvtflow.axes.master.profiles.cia402_ip_linear import FixedPeriodProfile


def parker_frame(cob_id: int, velocity_unit_rpm: float, record: NDArray[np.int64]) -> tuple[int, bytes]:
    """PDO 4 rx of one record: the target position 0x60C1:01 and the velocity feed-forward 0x60C1:03 in rpm."""
    rpm = round(float(record[1]) * velocity_unit_rpm)
    return cob_id, struct.pack("<ii", int(record[0]), rpm)


class ParkerSlvdn(FixedPeriodProfile):
    name = DriveProfile.PARKER_SLVDN
    rpdos = name.spec.rpdos
    tpdos = name.spec.tpdos
    sync_tpdo = name.spec.sync_tpdo

    @property
    def cycle_us(self) -> int:
        return round(self.link.bus.config.sync_period_ms * 1000)

    @property
    def submode(self) -> int:
        return int(self.name.submode(self.config.interpolation_submode))  # type: ignore[arg-type]

    @property
    def delay_periods(self) -> int:
        if self.cycle_us < od.PARKER_CUBIC_THRESHOLD_US:
            return 0
        return 2 if self.name.spec.submodes[self.submode] is Interpolation.CUBIC_P else 1

    @property
    def lead_periods(self) -> int:
        return min(self.delay_periods, 1)

    @property
    def ramps_by_itself(self) -> bool:
        return self.cycle_us >= od.PARKER_CUBIC_THRESHOLD_US  # below: the direct loop

    def configure(self) -> None:
        link = self.link
        link.write(od.PARKER_OPERATIVE_MODE, 0, od.PARKER_IP_MODE, "H")
        link.write(od.COMMUNICATION_CYCLE_PERIOD, 0, self.cycle_us, "I")
        link.write(od.INTERPOLATION_SUBMODE, 0, self.submode, "h")
        self.write_settings()
        link.map_pdos(self.rpdos, self.tpdos)
        self.write_heartbeat()
        self.supervise_master()

    def frame_packer(self, cob_id: int) -> Callable[[NDArray[np.int64]], tuple[int, bytes]]:
        return partial(parker_frame, cob_id, self.config.scaling.velocity_unit_rpm)
