"""Simulated maxon EPOS2 in interpolated position mode (buffered cubic PVT, app note "IPM").

Behaviour, as the app note and DESIGN sections 4-5 state it, with the points the note leaves open
decided here:

* Mode 7; records enter a 64-entry FIFO through 0x20C1 (asynchronous RPDO or SDO) only while the
  buffer is enabled (0x60C4:06 = 1; 0 clears it and denies access: a record is refused with SDO
  abort 0x08000022). Selecting mode 7 clears the FIFO (transition I).
* Controlword bit 4 rising (0x001F) requests interpolation; it starts at the next SYNC, or at the
  SYNC that applies it when it comes through the synchronous RPDO: that SYNC is t = 0 of the path.
  Fewer than 2 records in the FIFO then is an underflow error.
* The first record is the start point (its time a dwell); each record ends a segment of its time,
  joined by ``axes.drive.interpolation.hermite_coefficients`` from the previous end point (the first
  segment starts from the present demand at rest): the demand equals ``epos2_pvt`` of the records.
* A segment that ends needs the next record then: an empty FIFO is an underflow error. A time-0
  record ends interpolation without error (ip mode inactive, target reached).
* A record arriving with 64 in the FIFO is an overflow error.
* Every 1 ms sample: |v| above 0x607F or |a| above 0x60C5 (converted with the axis scaling) is a
  velocity / acceleration error; above 0x6081 / 0x6083 only sets the warning bit (kept until the
  next start or fault reset). The end of each segment is checked too (the boundary sample).
* Errors set their bit of 0x20C4:01, send EMCY 0xFF0C with 0x20C4:01 in the data and fault the
  drive (app note 3.8); the error bits stay until the fault reset.
* 0x20C4:01 warnings: underflow when the level is at or below 0x20C4:02, overflow at or above
  0x20C4:03 ("level is reached", Table 13). 0x60C4:02 is the free size, 0x60C4:04 the level.
* Halt (bit 8) stops interpolating and brakes with 0x6084; bit 4 falling does the same.
* 0x1013 writes are kept (``time_stamps``); on the wall clock they correct the motion clock (below).
* Wall clock (``clock="wall"``, axes/sim/clock.py): once started the records run on the drive's own
  clock (1 ms samples by the cell's ticker), SYNC or no SYNC: a late SYNC does not stop them, a
  missing record is a buffer underflow as above. The start SYNC's arrival is t = 0 ("setting the
  SYNC arrival time as the 'zero' time of the path specification"); every later SYNC is latched on
  the motion clock ("The reception time (Td1) of the SYNC message will be stored by latching the
  device internal motion clock timer") and the drive "adjusts then its internal motion clock time in
  relation to the time latched in the last SYNC": it compares the latched time with start + n x
  period (n: the period boundary nearest to it, not a SYNC count, so a master that skips a period is
  not read as a drive a period fast; the period is 0x1006 where written, else the cell's SYNC
  period) and runs its clock at 1 - error/period for one period from that SYNC's arrival, then at 1
  again, bounded to +-1 % (``MAX_SLEW``): the error is closed within a period when it can be and a
  late next SYNC cannot make the correction overshoot; the clock is a function of the SYNC
  instants, not of when the simulation got to them. The drift itself is not estimated: it adds
  period x drift (1 us at 1 ms and 1000 ppm) to the error each period and the next SYNC removes it.
  Why 1 %: it covers 20 times the 500 ppm the tests give the quartz (a real crystal: about
  100 ppm), so the drift is taken out within a SYNC or two, while one SYNC that is off by a whole
  period (late, or one of a burst) moves the path by at most 1 % of a period and changes its speed
  by 1 %: a burst cannot make it jump. Once the master's time stamps come (0x1013 after a SYNC:
  the time that SYNC left the wire on the master's clock, Tm1), the latch is compared with the
  master's time instead (``_on_time_stamp``): start + (Tm1 - Tm0), the same slew; a SYNC's jitter
  moves both and is no error, a stamp that is not the SYNC's time is followed and shows as drift.
  The dynamics checks judge the interpolation's own
  velocity and acceleration, as the note's "calculated velocity from the interpolation".
* Homing (mode 6, axes/sim/cia402/homing_mode.py): the CiA 402 methods and maxon's hard-stop methods -1 to -4
  (current threshold 0x2080); statusword bit 15 says the position is referenced (homed since power-on).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Statusword
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.interpolation import exceeds
from pvtflow.axes.drive.objects import BUFFER_ERRORS, BufferStatus, Record
from pvtflow.axes.sim.cia402.homing_mode import Homing
from pvtflow.axes.sim.cia402.power_states import OPERATION_ENABLED
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.drive import SimulatedDrive
from pvtflow.axes.sim.node.device import EPOS2_MODES, Value
from pvtflow.axes.sim.node.dictionary import ABORT_DEVICE_STATE, ABORT_VALUE_RANGE

EPOS2_VERSION = 0x2003  # :01 software version, :02 hardware version (maxon's EDS)
MAX_SLEW = 0.01  # wall clock: the largest clock rate correction per SYNC (see the module docstring)


@dataclass(frozen=True, slots=True)
class ClockCheck:
    """Wall clock: one SYNC's comparison of the drive's time with start + n x period (tests, benches)."""

    sync: int
    n: int  # the period boundary it was compared with
    error_us: float  # latched time - (start + n x period): > 0, the drive's clock runs ahead
    rate: float  # the motion clock's rate (per quartz us) for the period after this SYNC


class Epos2Homing(Homing):
    def placement(self, home: float) -> tuple[float, float | None]:
        """maxon's definitions: 0x607C (Home Offset) is the move from the reference found to the home
        position, where the position reads 0x2081 (Home Position); the axis goes there and stands."""
        read_or = self._dictionary.read_or
        method = read_or(od.HOMING_METHOD, 0, 0)
        here = method in (od.HomingMethod.CURRENT_POSITION, od.HomingMethod.CURRENT_POSITION_37)
        at = home if here else home + read_or(od.HOME_OFFSET, 0, 0)  # "actual position" does not move
        return at - read_or(od.EPOS2_HOME_POSITION, 0, 0), at


class Epos2Drive(SimulatedDrive):
    PROFILE = DriveProfile.EPOS2_PVT
    EDS = "epos2.eds"
    MODES = EPOS2_MODES
    # maxon's firmware: a heartbeat error (EMCY 0x8130) is a device error like any other, so the
    # error reaction runs (0x605E, maxon's default 2: quick stop ramp), the FIFO is emptied, FAULT
    HEARTBEAT_ERROR_FAULTS = True
    HOMING_METHODS = od.EPOS2_HOMING_METHODS
    REFERENCED_BIT = int(Statusword.MANUFACTURER_15)  # maxon: "position referenced to home position"
    HOMING = Epos2Homing

    def _own_values(self) -> dict[tuple[int, int], Value]:
        """Where maxon's EDS gives no default: cubic PVT (0x60C0 = -1, app note 3.6.5), the buffer
        size, and the firmware / hardware versions (0x2003:01/:02), which maxon's EDS carries in the
        high words of its revision number and product code (0x2122, 0x6420 in its comments)."""
        info = self.node.object_dictionary.device_information
        return {
            (od.INTERPOLATION_SUBMODE, 0): -1,
            (od.INTERPOLATION_DATA_CONFIGURATION, 1): od.EPOS2_BUFFER_SIZE,
            (EPOS2_VERSION, 1): (info.revision_number or 0) >> 16,
            (EPOS2_VERSION, 2): (info.product_number or 0) >> 16,
        }

    def _reset_profile(self) -> None:
        self.fifo: deque[Record] = deque()
        self.buffer_enabled = False
        self.ip_active = False
        self._ip_requested = False
        self._segment: Segment | None = None
        self.sticky = BufferStatus(0)  # errors and warnings, kept until a start / fault reset
        self.records_received = 0
        self.records_consumed: deque[Record] = deque(maxlen=self.history.maxlen)  # in order (start included)
        self.max_level = 0
        self.min_level_active: int | None = None
        self.ended_by_time_zero = 0
        self._sync_origin: float | None = None  # wall clock: the start SYNC on the motion clock (us)
        self._latched: tuple[int, float] | None = None  # the last SYNC: its count and its latch (us)
        self._stamp_origin: tuple[float, int] | None = None  # the run's first (latch, 0x1013) pair
        self.clock_checks: deque[ClockCheck] = deque(maxlen=self.history.maxlen)

    # --- status -----------------------------------------------------------------------------------
    @property
    def level(self) -> int:
        return len(self.fifo)

    def buffer_status(self) -> BufferStatus:
        status = self.sticky
        if self.buffer_enabled:
            status |= BufferStatus.BUFFER_ENABLED
        if self.level <= self.read(od.EPOS2_INTERPOLATION_BUFFER, 2):
            status |= BufferStatus.UNDERFLOW_WARNING
        if self.level >= self.read(od.EPOS2_INTERPOLATION_BUFFER, 3):
            status |= BufferStatus.OVERFLOW_WARNING
        if self.ip_active:
            status |= BufferStatus.IP_MODE_ACTIVE
        return status

    def _publish(self) -> None:
        self.publish(od.EPOS2_INTERPOLATION_BUFFER, 1, int(self.buffer_status()))
        self.publish(od.INTERPOLATION_DATA_CONFIGURATION, 1, od.EPOS2_BUFFER_SIZE)
        self.publish(od.INTERPOLATION_DATA_CONFIGURATION, 2, od.EPOS2_BUFFER_SIZE - self.level)
        self.publish(od.INTERPOLATION_DATA_CONFIGURATION, 4, self.level)

    def _warning(self) -> bool:
        return bool(self.sticky & (BufferStatus.VELOCITY_WARNING | BufferStatus.ACCELERATION_WARNING))

    def _target_reached(self) -> bool:
        return not self.ip_active and not self._ip_requested

    # --- writes -----------------------------------------------------------------------------------
    def _check_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.EPOS2_INTERPOLATION_DATA_RECORD and not self.buffer_enabled:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        if index == od.EPOS2_INTERPOLATION_BUFFER and (
            (subindex == 2 and not 0 <= value < od.EPOS2_BUFFER_SIZE)
            or (subindex == 3 and not 1 <= value <= od.EPOS2_BUFFER_SIZE)
        ):
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == od.INTERPOLATION_DATA_CONFIGURATION and subindex == 6 and value not in (0, 1):
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == od.INTERPOLATION_SUBMODE and value != -1:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # the EPOS2 has cubic PVT only
        if index == od.INTERPOLATION_TIME_PERIOD and value != {1: 1, 2: -3}.get(subindex, value):
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # fixed at 1 ms: the records carry their own times

    def _on_object_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.EPOS2_INTERPOLATION_DATA_RECORD:
            self._push(Record.unpack(value))
        elif index == od.INTERPOLATION_DATA_CONFIGURATION and subindex == 6:
            self.buffer_enabled = value == 1
            if not self.buffer_enabled:
                self.fifo.clear()

    def _push(self, record: Record) -> None:
        self.records_received += 1
        if self.level >= od.EPOS2_BUFFER_SIZE:
            self._ipm_error(BufferStatus.OVERFLOW_ERROR, "buffer overflow")
            return
        self.fifo.append(record)
        self.max_level = max(self.max_level, self.level)

    def _on_mode_change(self, old: int, new: int) -> None:
        if new == od.INTERPOLATED_POSITION_MODE:
            self.fifo.clear()  # transition I
        elif self.ip_active or self._ip_requested:
            self._abort_motion()  # transition II

    # --- faults -----------------------------------------------------------------------------------
    def _ipm_error(self, bit: BufferStatus, check: str) -> None:
        self.sticky |= bit
        status = int(self.buffer_status())
        self.fault(od.EMCY_EPOS2_IPM_ERROR, check, status.to_bytes(2, "little"))

    def _abort_motion(self) -> None:
        self.ip_active = False
        self._ip_requested = False
        self._segment = None
        if self.state != OPERATION_ENABLED or self.sticky & BUFFER_ERRORS:
            self.fifo.clear()  # app note 3.8: restart only after re-synchronisation

    def _request_ip(self) -> None:
        self._ip_requested = True

    def _on_fault_reset(self) -> None:
        self.sticky = BufferStatus(0)

    # --- interpolation ----------------------------------------------------------------------------
    def _on_sync_validated(self) -> None:
        if self._ip_requested and self.state == OPERATION_ENABLED:
            self._ip_requested = False
            self._start()

    def _on_sync_clock(self, instant_us: float, mono: float) -> None:
        """Wall clock: the start SYNC is the path's zero; every later one slews the clock toward
        start + n x period (module docstring)."""
        clock = self.motion_clock
        if clock is None:
            return
        if not self.ip_active:
            self._sync_origin = None
            if clock.rate != 1.0:
                clock.slew(1.0, mono)
            return
        self._latched = (self.sync_count, instant_us)
        if self._sync_origin is None or self.ip_active_sync == self.sync_count:
            self._sync_origin = instant_us
            self._stamp_origin = None
            return
        if self._stamp_origin is not None:
            return  # the master's time stamps say when this SYNC left: its 0x1013 corrects the clock
        period = self._clock_period_us
        n = round((instant_us - self._sync_origin) / period)
        error = instant_us - (self._sync_origin + n * period)
        rate = 1.0 - min(max(error / period, -MAX_SLEW), MAX_SLEW)
        clock.slew(rate, mono, period)  # from the SYNC's arrival: a function of the SYNC instants
        self.clock_checks.append(ClockCheck(self.sync_count, n, error, rate))

    @property
    def _clock_period_us(self) -> float:
        cycle = self.read_or(od.COMMUNICATION_CYCLE_PERIOD, 0, 0)
        return float(cycle or self.sync_period_us)

    def _on_time_stamp(self, stamp_us: int) -> None:
        """Wall clock: the master's time (0x1013, us) of the last SYNC, Tm1, against the motion clock's
        latch of that SYNC's reception, Td1 (app note "Clock synchronization"): from the first pair of
        a run on, the clock is slewed as for a SYNC (``_on_sync_clock``), toward Td0 + (Tm1 - Tm0), so it
        follows the master's clock, not the SYNCs' arrival: a SYNC's jitter on the wire moves Td1 and Tm1
        alike, and is not read as a drift. A stamp that is not the SYNC's time (its send time, another
        clock) is followed all the same: the path then drifts with it."""
        clock = self.motion_clock
        latched = self._latched
        if clock is None or not self.ip_active or latched is None or self._sync_origin is None:
            return
        sync, td = latched
        if self._stamp_origin is None:
            self._stamp_origin = (td, stamp_us)
            return
        td0, tm0 = self._stamp_origin
        master_us = (stamp_us - tm0) & 0xFFFFFFFF  # UNSIGNED32 us: wraps every 71.6 minutes
        period = self._clock_period_us
        error = td - (td0 + master_us)
        rate = 1.0 - min(max(error / period, -MAX_SLEW), MAX_SLEW)
        clock.slew(rate, time.monotonic(), period)  # from the stamp's arrival, for one period
        self.clock_checks.append(ClockCheck(sync, round(master_us / period), error, rate))

    def _start(self) -> None:
        self.sticky &= ~(BufferStatus.VELOCITY_WARNING | BufferStatus.ACCELERATION_WARNING)
        if self.level < 2:
            self._ipm_error(BufferStatus.UNDERFLOW_ERROR, "buffer underflow at start (fewer than 2 records)")
            return
        self.ip_active = True
        self.ip_active_sync = self.sync_count
        self.min_level_active = self.level
        self.motion.zero_rates()
        self._begin(self.sync_time_us / 1000.0, self.demand, 0.0)

    def _begin(self, start: float, p0: float, v0: float) -> bool:
        """Take the next record at ``start``: a new segment, the end (time 0) or an underflow."""
        if not self.fifo:
            self._ipm_error(BufferStatus.UNDERFLOW_ERROR, "buffer underflow")
            return False
        record = self.fifo.popleft()
        self.records_consumed.append(record)
        self.min_level_active = min(
            self.level, self.min_level_active if self.min_level_active is not None else self.level
        )
        if record.time == 0:
            self.ip_active = False
            self._segment = None
            self.ended_by_time_zero += 1
            return False
        self._segment = Segment.cubic(
            start, p0, v0, float(record.position), record.velocity * self.velocity_factor, float(record.time)
        )
        return True

    def _motion_at(self, t: float) -> tuple[float, float, float] | None:
        if not self.ip_active or self._segment is None:
            return None
        segment = self._segment
        while t >= segment.end - 1e-9:
            end = segment.at(segment.end)
            self._check_dynamics(end[1], end[2])
            if self.state != OPERATION_ENABLED:
                return None
            if not self._begin(segment.end, segment.p1, segment.v1):
                if self.ip_active is False and self.state == OPERATION_ENABLED:
                    return end[0], 0.0, 0.0  # time-0 end: hold the last point
                return None
            segment = self._segment
            assert segment is not None
        return segment.at(t)

    def _check_dynamics(self, v: float, a: float) -> None:
        speed = abs(v) * self._units_per_qc_ms  # in 0x607F's unit
        rpm_s = abs(a) * self._rpm_s_per_qc_ms2
        if exceeds(speed, self.read(od.PROFILE_VELOCITY)):
            self.sticky |= BufferStatus.VELOCITY_WARNING
        if exceeds(rpm_s, self.read(od.PROFILE_ACCELERATION)):
            self.sticky |= BufferStatus.ACCELERATION_WARNING
        if exceeds(speed, self.read(od.MAX_PROFILE_VELOCITY)):
            self._ipm_error(BufferStatus.VELOCITY_ERROR, "max profile velocity 0x607F")
        elif exceeds(rpm_s, self.read(od.MAX_ACCELERATION)):
            self._ipm_error(BufferStatus.ACCELERATION_ERROR, "max acceleration 0x60C5")
