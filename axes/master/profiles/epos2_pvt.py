"""maxon EPOS2 buffered PVT (interpolated position mode, app note "Interpolation Position Mode").

Configuration: app note Table 17 (mode 7, 0x6065, 0x607D, 0x607F, 0x60C5, 0x6081, 0x6083, 0x6084),
the warning levels 0x20C4:02/03, the PDO layout of axes.drive.objects (records on an asynchronous RPDO1,
controlword on the synchronous RPDO2, buffer status + statusword on an event TPDO1, statusword +
position on the synchronous TPDO2 that answers every SYNC), heartbeat 0x1017; with the bus's
``time_stamp`` the asynchronous RPDO3 takes 0x1013 from the master's one time-stamp frame after
each SYNC (app note 2.4, on ``objects.time_stamp_cob_id`` for all drives). Master loss (``supervise_master``):
maxon's EDS has both CiA objects, 0x1016 (two consumer entries: pvtflow takes :01) and 0x6007
(INTEGER16, no default given), and pvtflow writes 0x6007 = 3 (quick stop) as for every profile; but
maxon's firmware takes a heartbeat error as one of its device errors (EMCY 0x8130), so what stops
the axis is its error reaction 0x605E (written: 2, maxon's default, quick stop ramp on 0x6085): the FIFO is
emptied, the axis brakes and waits in FAULT (app note 3.8: restart only after re-synchronisation).
Feed: each record is the u64 of 0x20C1 (``Record.to_bytes``) on RPDO1; a ``BufferFeeder`` keeps
the FIFO filled. Delay: none to compensate, the drive runs on the records' own times from the start
SYNC. End: the time-0 record (interpolation inactive without error).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.objects import EPOS2_TIME_STAMP_RPDO, Record, time_stamp_cob_id
from pvtflow.axes.drive.program import split_long_records
from pvtflow.axes.master.group.feeder import MIN_HELD, BufferFeeder, Feeder, RecordAllowance
from pvtflow.axes.master.profiles.base import Profile

if TYPE_CHECKING:
    from pvtflow.axes.drive.program import AxisProgram

BUFFER_CLEAR = 0
BUFFER_ENABLE = 1


def record_frame(cob_id: int, record: NDArray[np.int64]) -> tuple[int, bytes]:
    """The asynchronous RPDO of one record: 0x20C1, the PVT record (``objects.Record``)."""
    return cob_id, Record(int(record[0]), int(record[1]), int(record[2])).to_bytes()


class Epos2Pvt(Profile):
    name = DriveProfile.EPOS2_PVT
    rpdos = name.spec.rpdos
    tpdos = name.spec.tpdos
    sync_tpdo = name.spec.sync_tpdo
    fault_reaction_on_master_loss = od.FaultReaction.QUICK_STOP
    homing_methods = name.spec.homing_methods
    home_position_object = od.EPOS2_HOME_POSITION  # maxon: 0x2081 is the position at home, 0x607C a move

    def max_sync_gap_ms(self, program: AxisProgram) -> float:
        """The EPOS2 runs its records on its own clock: a gap only holds the feed back, which tops the
        FIFO up on the SYNC answers. The feeder keeps records up to the cell's look-ahead bound ahead
        of the drive, and never fewer than ``MIN_HELD`` (``axes.master.group.feeder.within_lookahead``):
        so it rides out the later of the two, less a SYNC period, in the shortest stretch of this
        program (at least the fixed-period drives' two periods)."""
        times = np.asarray(program.records[:, 2], dtype=np.float64)
        keep = MIN_HELD - 1  # beyond the segment running
        floor = super().max_sync_gap_ms(program)
        if len(times) < keep:
            return max(floor, float(times.sum()))
        window = float(np.convolve(times, np.ones(keep), mode="valid").min())
        ahead = self.link.bus.config.max_lookahead_ms - self.link.bus.config.sync_period_ms
        deep = max(keep, self.config.buffer.overflow_warning - 2)  # the most the FIFO holds beyond the running one
        if len(times) >= deep:  # a bound deeper than the FIFO: the FIFO's own time
            ahead = min(ahead, float(np.convolve(times, np.ones(deep), mode="valid").min()))
        return max(floor, window, ahead)

    def configure(self) -> None:
        link = self.link
        link.write(od.MODES_OF_OPERATION, 0, od.INTERPOLATED_POSITION_MODE, "b")
        self.write_settings()
        self.write_profile_motion()
        if link.bus.config.time_stamp:  # the master's 0x1013 after every SYNC, on one shared COB-ID
            link.map_pdos(
                (*self.rpdos, EPOS2_TIME_STAMP_RPDO),
                self.tpdos,
                {EPOS2_TIME_STAMP_RPDO.number: time_stamp_cob_id(link.bus.config.master_node_id)},
            )
        else:
            link.map_pdos(self.rpdos, self.tpdos)
        buffer = self.config.buffer
        link.write(od.EPOS2_INTERPOLATION_BUFFER, 2, buffer.underflow_warning, "H")
        link.write(od.EPOS2_INTERPOLATION_BUFFER, 3, buffer.overflow_warning, "H")
        self.write_heartbeat()
        self.supervise_master()

    def enable(self, fresh: bool = False) -> None:
        """Shutdown, switch on, enable operation; then clear the FIFO and enable access to it."""
        self.enable_operation(fresh)
        self.clear_buffer()
        self.link.write(od.INTERPOLATION_DATA_CONFIGURATION, 6, BUFFER_ENABLE, "B")

    def clear_buffer(self) -> None:
        """0x60C4:06 = 0: the FIFO and every record in it cleared, access denied until enabled."""
        self.link.write(od.INTERPOLATION_DATA_CONFIGURATION, 6, BUFFER_CLEAR, "B")

    def frame(self, record: NDArray[np.int64]) -> tuple[int, bytes]:
        return record_frame(self._cob, record)

    def frame_packer(self, cob_id: int) -> Callable[[NDArray[np.int64]], tuple[int, bytes]]:
        """``frame`` as a function another process can take (``axes.master.cyclic.process``)."""
        return partial(record_frame, cob_id)

    def feeder(self, program: AxisProgram, allowance: RecordAllowance | None = None) -> Feeder:
        self._cob = self.rpdos[0].cob_id(self.link.node_id, receive=True)
        bus = self.link.bus
        lookahead = bus.config.max_lookahead_ms
        return BufferFeeder(
            split_long_records(program, max(1, int(lookahead / 2))),
            self.frame,
            bus.network.send_message,
            bus.config.sync_period_ms,
            self.config.buffer,
            allowance=allowance,
            lookahead_ms=lookahead,
        )
