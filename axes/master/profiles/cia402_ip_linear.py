"""CiA 402 interpolated position mode, linear, one target (seed cia402-ip-linear-single-setpoint).

Configuration: mode 7, 0x60C2:01 = the axis period in ms (0x60C2:02 = -3), 0x60C4:06 = 1 to allow
writing the target, 0x607F/0x60C5/0x607D/0x6065 where the drive has them, read back
(``Profile.write_settings``); synchronous RPDO1 with 0x60C1:01 and RPDO2 with
the controlword, synchronous TPDO1 with statusword + position that answers every SYNC; the master's
heartbeat watched (0x1016) with 0x6007 = 3, quick stop (``Profile.supervise_master``): without it the drive
would hold its last target with nobody watching.
Enable: 0x60C1:01 primed with the actual position (``prime``). Feed: one target position (0x60C1:01,
INT32) per period. Delay: the drive moves linearly from
where it is to the target over the period that follows the SYNC validating it, so the target of
record k is validated one period before its program time (k + 1) periods. End: the last target is
held and bit 4 of the controlword is cleared.
"""

from __future__ import annotations

import struct
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.stop_ramp import braking_records
from pvtflow.axes.master.group.feeder import Feeder, RecordAllowance, SetpointFeeder
from pvtflow.axes.master.profiles.base import Profile

if TYPE_CHECKING:
    from collections.abc import Callable

    from pvtflow.axes.drive.program import AxisProgram

MS_INDEX = -3  # 0x60C2:02: the period is given in 10^-3 s


def target_frame(cob_id: int, record: NDArray[np.int64]) -> tuple[int, bytes]:
    """The setpoint RPDO of one record: 0x60C1:01, the target position (INT32)."""
    return cob_id, struct.pack("<i", int(record[0]))


class FixedPeriodProfile(Profile):
    """Shared by the fixed-period behaviours: a SetpointFeeder on RPDO1, TPDO1 answers SYNC."""

    rpdos = DriveProfile.CIA402_IP_LINEAR.spec.rpdos
    tpdos = DriveProfile.CIA402_IP_LINEAR.spec.tpdos
    sync_tpdo = DriveProfile.CIA402_IP_LINEAR.spec.sync_tpdo

    @property
    def period_ms(self) -> int:
        period = self.config.period_ms
        if period is None:
            raise ValueError(f"axis {self.config.joint}: a fixed-period profile needs period_ms")
        return period

    @property
    def delay_periods(self) -> int:
        return 1

    def frame(self, record: NDArray[np.int64]) -> tuple[int, bytes]:
        return self.frame_packer(self._cob)(record)

    def frame_packer(self, cob_id: int) -> Callable[[NDArray[np.int64]], tuple[int, bytes]]:
        """``frame`` as a function another process can take (picklable: the cyclic process packs a stop
        ramp's setpoints with it, ``axes.master.cyclic.process``)."""
        return partial(target_frame, cob_id)

    def feeder(self, program: AxisProgram, allowance: RecordAllowance | None = None) -> Feeder:
        self._cob = self.rpdos[0].cob_id(self.link.node_id, receive=True)
        bus = self.link.bus
        return SetpointFeeder(program.records, self.frame, bus.network.send_message, self.period_ms, self.lead_periods)

    def enable(self, fresh: bool = False) -> None:
        self.enable_operation(fresh)
        self.prime()

    def stop_records(self, feeder: SetpointFeeder, quick: bool) -> NDArray[np.int64]:
        """The master's stop ramp for a drive that has none (``ramps_by_itself`` False): braking
        records from the last setpoint the feeder sent and the step before it (``axes.drive.stop_ramp``)."""
        last, previous = feeder.last_commanded()
        return braking_records(last, previous, feeder.period_ms, self.config.limits, self.config.scaling, quick)

    def prime(self) -> None:
        """0x60C1:01 = 0x6064 before interpolation is enabled: a drive whose start SYNC brings no new
        setpoint (the Parker below 2.5 ms, lead 0) latches the object as it stands, which holds 0
        after power-up or the last run's end; primed, it holds where it is."""
        position = self.link.read(od.POSITION_ACTUAL_VALUE, 0, "i")
        self.link.write(od.INTERPOLATION_DATA_RECORD, 1, position, "i")

    def write_period(self) -> None:
        self.link.write(od.INTERPOLATION_TIME_PERIOD, 1, self.period_ms, "B")
        self.link.write_optional(od.INTERPOLATION_TIME_PERIOD, 2, MS_INDEX, "b")


class Cia402IpLinear(FixedPeriodProfile):
    name = DriveProfile.CIA402_IP_LINEAR

    def configure(self) -> None:
        link = self.link
        link.write(od.MODES_OF_OPERATION, 0, od.INTERPOLATED_POSITION_MODE, "b")
        self.write_period()
        self.write_settings()
        link.map_pdos(self.rpdos, self.tpdos)
        self.write_heartbeat()
        self.supervise_master()

    def enable(self, fresh: bool = False) -> None:
        self.enable_operation(fresh)
        self.link.write(od.INTERPOLATION_DATA_CONFIGURATION, 6, 1, "B")  # allow writing 0x60C1:01
        self.prime()
