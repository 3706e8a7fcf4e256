"""Object dictionary facts shared by the master and the simulated drives.

Indices, the EPOS2 record (complex data structure 0x0040) and its packing, the bits of the EPOS2
interpolation buffer status 0x20C4:01, and the PDO layout pvtflow configures for each drive
profile. Both sides of the bus import these; nothing else restates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, IntFlag, StrEnum

from pvtflow.axes.drive.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN

# --- CiA 301 / CiA 402 objects ----------------------------------------------------------------
ERROR_HISTORY = 0x1003  # :00 number of errors, :n the n-th latest (error code, manufacturer bits above)
COMMUNICATION_CYCLE_PERIOD = 0x1006  # us; the Parker SLVDN takes its cycle from it
HIGH_RESOLUTION_TIME_STAMP = 0x1013  # us, written after each SYNC (EPOS2 app note 2.4)
CONSUMER_HEARTBEAT_TIME = 0x1016  # :n = node id << 16 | time in ms: the heartbeats this node watches
PRODUCER_HEARTBEAT_TIME = 0x1017
IDENTITY = 0x1018  # :01 vendor id, :02 product code, :03 revision number, :04 serial number
ABORT_CONNECTION_OPTION_CODE = 0x6007  # what a CiA 402 drive does when it loses its master (heartbeat)
FAULT_REACTION_OPTION_CODE = 0x605E  # how it brakes on a fault (2: on the quick stop ramp)
QUICK_STOP_OPTION_CODE = 0x605A  # how a quick stop brakes
QUICK_STOP_ON_QUICK_STOP_RAMP = 2  # 0x605A: on 0x6085, then SWITCH ON DISABLED
HALT_OPTION_CODE = 0x605D  # how a halt (controlword bit 8) brakes
HALT_ON_PROFILE_DECELERATION = 1  # 0x605D: on 0x6084
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
POSITION_DEMAND_VALUE = 0x6062
POSITION_ACTUAL_INTERNAL_VALUE = 0x6063  # increments, before the factor group (the Parker's in IP mode)
POSITION_ACTUAL_VALUE = 0x6064
MAX_FOLLOWING_ERROR = 0x6065
HOME_OFFSET = 0x607C  # qc: what the position reads at the home position once homing is attained
SOFTWARE_POSITION_LIMIT = 0x607D  # :01 min, :02 max
POLARITY = 0x607E  # bit 7 position, bit 6 velocity: the drive inverts what it is given (0: it does not)
MAX_PROFILE_VELOCITY = 0x607F
PROFILE_VELOCITY = 0x6081
PROFILE_ACCELERATION = 0x6083
PROFILE_DECELERATION = 0x6084  # what a halt (bit 8) brakes on; app note Table 17: quick stop deceleration
QUICK_STOP_DECELERATION = 0x6085  # the quick stop ramp (maxon's EDS: QuickStop Deceleration)
HOMING_METHOD = 0x6098
HOMING_SPEEDS = 0x6099  # :01 speed for switch search, :02 speed for zero search (velocity units)
HOMING_ACCELERATION = 0x609A
INTERPOLATION_SUBMODE = 0x60C0
INTERPOLATION_DATA_RECORD = 0x60C1  # :01 target position, :02 velocity (counts/s), :03 velocity (rpm)
INTERPOLATION_TIME_PERIOD = 0x60C2  # :01 value, :02 index (10^index s)
INTERPOLATION_DATA_CONFIGURATION = 0x60C4  # :01 max size, :02 free size, ..., :06 buffer clear
MAX_ACCELERATION = 0x60C5
POSITION_ENCODER_RESOLUTION = 0x608F  # :01 encoder increments per :02 motor revolutions
MOTOR_DATA = 0x6410  # maxon's motor data; :04 the motor's maximal speed (rpm)
MOTOR_MAX_SPEED_SUB = 4
SUPPORTED_DRIVE_MODES = 0x6502

INTERPOLATED_POSITION_MODE = 7
HOMING_MODE = 6

CONSUMER_NODE_SHIFT = 16  # 0x1016:n bits 23-16: the watched node id; bits 15-0: its time in ms (0: unused)


class AbortConnectionOption(IntEnum):
    """0x6007 (CiA 402): what the drive does when its connection to the master is lost (heartbeat)."""

    NO_ACTION = 0
    FAULT_SIGNAL = 1  # the drive faults: its fault reaction (0x605E) brakes it, then FAULT
    DISABLE_VOLTAGE = 2  # power stage off at once: the axis coasts
    QUICK_STOP = 3  # quick stop ramp (0x6085), then SWITCH ON DISABLED (0x605A = 2)


class FaultReaction(IntEnum):
    """0x605E (CiA 402): how a drive brakes on its way into FAULT."""

    DISABLE_DRIVE = 0  # power stage off at once
    SLOW_DOWN = 1  # on the profile deceleration 0x6084
    QUICK_STOP = 2  # on the quick stop deceleration 0x6085 (maxon's EDS default)


# --- maxon EPOS2 ---------------------------------------------------------------------------------
EPOS2_INTERPOLATION_DATA_RECORD = 0x20C1  # the PVT FIFO input, u64
EPOS2_INTERPOLATION_BUFFER = 0x20C4  # :01 status, :02 underflow warning level, :03 overflow warning level
EPOS2_BUFFER_SIZE = 64

EPOS2_HOMING_CURRENT_THRESHOLD = 0x2080  # mA: the current that says "hard stop" (methods -1 to -4)
# maxon's Home Position (INTEGER32, qc): what 0x6064 reads at the home position once homing is attained;
# on the EPOS2 0x607C is the move from the reference found to that home position (maxon's firmware)
EPOS2_HOME_POSITION = 0x2081
EPOS2_SENSOR_CONFIGURATION = 0x2210  # :01 pulses per motor revolution of the incremental encoder (qc / 4)
EPOS2_SENSOR_TYPE_SUB = 2  # 0x2210:02 position sensor type (1, 2: incremental encoder with / without index)
EPOS2_SENSOR_POLARITY_SUB = 4  # 0x2210:04 position sensor polarity (0: not inverted)
VELOCITY_NOTATION_INDEX = 0x608B  # the velocity unit is 10^index of 0x608C's dimension (maxon's EPOS2)
VELOCITY_DIMENSION_INDEX = 0x608C  # 0xA4: rpm
EPOS2_QC_PER_PULSE = 4  # quadrature: four counts per encoder pulse


@dataclass(frozen=True)
class DriveIdentity:
    """0x1018:01/:02 of one kind of drive, and what it is in words."""

    vendor_id: int
    product_code: int
    name: str

    def __str__(self) -> str:
        return f"vendor 0x{self.vendor_id:08X} product 0x{self.product_code:08X} ({self.name})"


# pvtflow's simulated drives have vendor 0 and one product code per profile (axes.drive.drive_profile); the real
# drives whose identity a vendor EDS states: maxon's EPOS2 70/10 (configs/eds/vendor)
SIMULATED_VENDOR_ID = 0
MAXON_EPOS2_70_10 = DriveIdentity(0x000000FB, 0x64200000, "maxon EPOS2 70/10")


class HomingMethod(IntEnum):
    """0x6098 values pvtflow knows (CiA 402 methods; negative: maxon's, current threshold at a hard stop).

    Where the home position is: at a switch's edge, at the first index pulse past it, at a hard stop,
    or where the axis stands. "Positive/negative home switch": the switch is active on that side of
    its edge. The number is the drive's, the name says what it does."""

    NEGATIVE_LIMIT_SWITCH_INDEX = 1  # to the negative limit switch, back off it to the first index pulse
    POSITIVE_LIMIT_SWITCH_INDEX = 2
    NEGATIVE_LIMIT_SWITCH = 17  # home where the negative limit switch goes inactive
    POSITIVE_LIMIT_SWITCH = 18
    POSITIVE_HOME_SWITCH_FROM_ABOVE = 19  # positive home switch, its edge approached moving negative
    POSITIVE_HOME_SWITCH_FROM_BELOW = 20  # approached moving positive
    NEGATIVE_HOME_SWITCH_FROM_BELOW = 21  # negative home switch, its edge approached moving positive
    NEGATIVE_HOME_SWITCH_FROM_ABOVE = 22  # approached moving negative
    INDEX_NEGATIVE = 33  # the first index pulse moving negative
    INDEX_POSITIVE = 34
    CURRENT_POSITION = 35  # no motion: here is home (CiA 402 before 2016)
    CURRENT_POSITION_37 = 37  # the same, as CiA 402 numbers it since (EPOS4 and later drives)
    HARD_STOP_POSITIVE_INDEX = -1  # maxon: current threshold moving positive, then the index pulse moving back
    HARD_STOP_NEGATIVE_INDEX = -2
    HARD_STOP_POSITIVE = -3  # maxon: current threshold moving positive: home at the hard stop
    HARD_STOP_NEGATIVE = -4


# What the drives pvtflow knows do in mode 6 (and what their simulations implement): the CiA 402
# methods above for every drive with homing, maxon's hard-stop methods on the EPOS2 only.
CIA402_HOMING_METHODS = frozenset(m for m in HomingMethod if m > 0)
EPOS2_HOMING_METHODS = frozenset(HomingMethod)


# --- Parker SLVDN --------------------------------------------------------------------------------
# Parker drive parameters PrN are reached at 0x2000 + N (pvtflow's simulated SLVDN and configuration).
PARKER_PARAMETER_BASE = 0x2000
PARKER_OPERATIVE_MODE = PARKER_PARAMETER_BASE + 31  # Pr31
PARKER_IP_MODE = 202
PARKER_CUBIC_THRESHOLD_US = 2500  # below: direct position loop; from it on: interpolated


# --- EMCY error codes the (simulated) drives send: CiA 301 / CiA 402 standard codes, and one -----------
# manufacturer-specific code for the EPOS2 IPM errors.
EMCY_NO_ERROR = 0x0000  # error reset (sent after a fault reset)
EMCY_PARAMETER_ERROR = 0x6320  # a configuration the drive cannot run (e.g. interpolation period)
EMCY_PDO_LENGTH = 0x8210  # PDO not processed due to length error
EMCY_VELOCITY_LIMIT = 0x8400  # velocity beyond 0x607F (sanity check of the fixed-period drives)
EMCY_SOFTWARE_POSITION_LIMIT = 0x8612  # position demand outside 0x607D
# The simulated machine (axes/sim/cia402/homing_mode.py) outside homing: a limit switch reached is CiA 402's
# "reference limit" too (the seeds give no code of maxon's own for it), a hard stop run into the
# drive's following error.
EMCY_LIMIT_SWITCH = EMCY_SOFTWARE_POSITION_LIMIT
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_HEARTBEAT_ERROR = 0x8130  # CiA 301 life guard / heartbeat error: a watched node (the master) fell silent
EMCY_CAN_OVERRUN = 0x8110  # CiA 301: CAN overrun, frames lost
EMCY_CAN_ERROR_PASSIVE = 0x8120  # CiA 301: the drive's CAN controller is error passive
EMCY_CAN_BUS_OFF_RECOVERED = 0x8140  # CiA 301: the drive's CAN controller recovered from bus off
# what the CAN communication EMCYs mean, in the words the master reports them with
CAN_EMCY_WORDS = {
    EMCY_CAN_OVERRUN: "CAN overrun (frames lost)",
    EMCY_CAN_ERROR_PASSIVE: "CAN in error passive",
    EMCY_HEARTBEAT_ERROR: "heartbeat error (a watched node fell silent)",
    EMCY_CAN_BUS_OFF_RECOVERED: "recovered from bus off",
}
# EPOS2 "interpolated position mode error" (underflow, overflow, 0x607F or 0x60C5 exceeded). The seeds
# give no code: 0xFF0C is taken from memory of maxon's firmware specification, to be checked on a real
# drive; which error it was is in 0x20C4:01, which the simulated EPOS2 also puts (little endian) in the
# first two manufacturer-specific bytes of the EMCY.
EMCY_EPOS2_IPM_ERROR = 0xFF0C


class BufferStatus(IntFlag):
    """EPOS2 0x20C4:01, as the firmware sets it (DESIGN.md section 5; the app note's Table 13 repeats
    bits 2 and 3 for the errors, Table 12 reserves 10-13: the firmware uses 10 and 11)."""

    UNDERFLOW_WARNING = 1 << 0
    OVERFLOW_WARNING = 1 << 1
    VELOCITY_WARNING = 1 << 2
    ACCELERATION_WARNING = 1 << 3
    UNDERFLOW_ERROR = 1 << 8
    OVERFLOW_ERROR = 1 << 9
    VELOCITY_ERROR = 1 << 10
    ACCELERATION_ERROR = 1 << 11
    BUFFER_ENABLED = 1 << 14
    IP_MODE_ACTIVE = 1 << 15


BUFFER_ERRORS = (
    BufferStatus.UNDERFLOW_ERROR
    | BufferStatus.OVERFLOW_ERROR
    | BufferStatus.VELOCITY_ERROR
    | BufferStatus.ACCELERATION_ERROR
)


@dataclass(frozen=True)
class Record:
    """One PVT reference point as the EPOS2 takes it (time in ms, velocity in velocity units, qc)."""

    position: int
    velocity: int
    time: int

    def pack(self) -> int:
        """The u64 of 0x20C1: time (u8) << 56 | velocity (s24) << 32 | position (s32)."""
        if not INT32_MIN <= self.position <= INT32_MAX:
            raise ValueError(f"record position {self.position} is outside int32")
        if not INT24_MIN <= self.velocity <= INT24_MAX:
            raise ValueError(f"record velocity {self.velocity} is outside int24")
        if not 0 <= self.time <= 255:
            raise ValueError(f"record time {self.time} is outside 0..255 ms")
        return (self.time << 56) | ((self.velocity & 0xFFFFFF) << 32) | (self.position & 0xFFFFFFFF)

    def to_bytes(self) -> bytes:
        """The 8 data bytes of the record as they travel in the RPDO or SDO (little endian)."""
        return self.pack().to_bytes(8, "little")

    @classmethod
    def unpack(cls, value: int) -> Record:
        position = value & 0xFFFFFFFF
        velocity = (value >> 32) & 0xFFFFFF
        time = (value >> 56) & 0xFF
        if position >= 1 << 31:
            position -= 1 << 32
        if velocity >= 1 << 23:
            velocity -= 1 << 24
        return cls(position, velocity, time)

    @classmethod
    def from_bytes(cls, data: bytes) -> Record:
        return cls.unpack(int.from_bytes(data[:8], "little"))


# --- COB-IDs and PDO parameters (CiA 301 predefined connection set: function code + node id) ---------------
NODE_ID_BITS = 0x7F  # the node id in a predefined COB-ID (bits 0-6)
SDO_REQUEST_COB_ID_BASE = 0x600  # client -> server SDO (the master's requests)
SDO_RESPONSE_COB_ID_BASE = 0x580  # server -> client SDO (the drives' answers)
PDO_INVALID = 0x8000_0000  # a PDO COB-ID's bit 31 (CiA 301 7.5.2.35): the PDO does not exist


def pdo_cob_id(number: int, node_id: int, receive: bool) -> int:
    """PDO ``number`` (1-4) of a node: TPDO1 0x180 + node, RPDO1 0x200 + node, and 0x100 up for each next."""
    return (0x100 if receive else 0x080) + 0x100 * number + node_id


def pdo_communication_index(number: int, receive: bool) -> int:
    """The communication parameter object of PDO ``number``: 0x1400 + n - 1 (RPDO), 0x1800 + n - 1 (TPDO)."""
    return (0x1400 if receive else 0x1800) + number - 1


def pdo_mapping_index(number: int, receive: bool) -> int:
    """The mapping object of PDO ``number``: 0x1600 + n - 1 (RPDO), 0x1A00 + n - 1 (TPDO)."""
    return (0x1600 if receive else 0x1A00) + number - 1


def node_of_cob_id(cob_id: int) -> int:
    """The node a predefined COB-ID belongs to."""
    return cob_id & NODE_ID_BITS


# --- PDO layout (the contract between the master's configuration and the drives) ----------------
class PdoRole(StrEnum):
    """What a PDO carries, which says how often it is on the bus (``PdoLayout.frames_per_sync``)."""

    RECORD = "record"  # EPOS2 records: as many as the cell's record allowance per SYNC (axes.master.budget)
    SETPOINT = "setpoint"  # a fixed-period setpoint: the master sends one every SYNC
    CONTROLWORD = "controlword"  # start, halt, end: at most one per axis in a SYNC period
    STATUS = "status"  # a drive's TPDO: by its transmission type (every n SYNCs, or on event)
    TIME_STAMP = "time_stamp"  # the master's one 0x1013 frame after every SYNC, shared by every drive


@dataclass(frozen=True)
class PdoLayout:
    """One PDO as pvtflow maps it: number (1-4), transmission type, mapped (index, subindex, bits),
    what it carries and, for an event-driven TPDO, its inhibit time (0x1800:03) in SYNC periods and
    its event timer (0x1800:05, ms; 0: none)."""

    number: int
    transmission_type: int  # 1..240 = synchronous (every n-th SYNC), 254/255 = asynchronous / event driven
    entries: tuple[tuple[int, int, int], ...]
    role: PdoRole = PdoRole.STATUS
    inhibit_periods: float = 0  # event TPDO: at least this many SYNC periods between two of its frames
    event_timer_ms: int = 0  # event TPDO: sent at least this often, changed or not (0: on a change only)

    def cob_id(self, node_id: int, receive: bool) -> int:
        return pdo_cob_id(self.number, node_id, receive)

    @property
    def payload_bytes(self) -> int:
        return sum(bits for _, _, bits in self.entries) // 8

    def frames_per_sync(self) -> tuple[float, int]:
        """(frames per SYNC period on average, most frames in one SYNC period) of one axis's PDO; the
        records' count is the cell's (``axes.master.budget``), the time stamp's the bus's, not an axis's."""
        if self.role in (PdoRole.RECORD, PdoRole.TIME_STAMP):
            return 0.0, 0
        if self.role in (PdoRole.SETPOINT, PdoRole.CONTROLWORD):
            return 1.0, 1
        if 1 <= self.transmission_type <= 240:  # every n-th SYNC
            return 1.0 / self.transmission_type, 1
        if self.transmission_type == 0:  # acyclic synchronous: on a change, at a SYNC
            return 1.0, 1
        if self.inhibit_periods <= 0:
            raise ValueError(f"event-driven TPDO{self.number} without an inhibit time: its traffic has no bound")
        return 1.0 / self.inhibit_periods, math.ceil(1.0 / self.inhibit_periods)

    def frames_in(self, periods: int) -> int:
        """The most frames of one axis's PDO in ``periods`` consecutive SYNC periods (setpoints and
        controlwords: one per period; a TPDO of type n: one every n-th SYNC; an event TPDO: one per
        inhibit time)."""
        if self.role in (PdoRole.RECORD, PdoRole.TIME_STAMP):
            return 0
        if self.role in (PdoRole.SETPOINT, PdoRole.CONTROLWORD) or self.transmission_type == 0:
            return periods
        if 1 <= self.transmission_type <= 240:
            return math.ceil(periods / self.transmission_type)
        self.frames_per_sync()  # an event TPDO without an inhibit time is refused there
        return math.ceil(periods / self.inhibit_periods - 1e-9)


SYNCHRONOUS = 1
ASYNCHRONOUS = 255

# EPOS2 buffered PVT (app note 3.7): records through an asynchronous RPDO, buffer status and
# statusword through an event TPDO, the controlword through a synchronous RPDO (synchronous
# start), and a synchronous TPDO with the position for telemetry and the SYNC-lockstep clock.
EPOS2_RPDOS = (
    PdoLayout(1, ASYNCHRONOUS, ((EPOS2_INTERPOLATION_DATA_RECORD, 0, 64),), PdoRole.RECORD),
    PdoLayout(2, SYNCHRONOUS, ((CONTROLWORD, 0, 16),), PdoRole.CONTROLWORD),
)
# the event TPDO sends at most once per SYNC period (inhibit time 0x1800:03 = the SYNC period): the
# feeder reacts to a buffer warning within a period, and a burst of changes cannot flood the bus
EPOS2_TPDOS = (
    PdoLayout(1, ASYNCHRONOUS, ((EPOS2_INTERPOLATION_BUFFER, 1, 16), (STATUSWORD, 0, 16)), inhibit_periods=1),
    PdoLayout(2, SYNCHRONOUS, ((STATUSWORD, 0, 16), (POSITION_ACTUAL_VALUE, 0, 32))),
)

# Fixed-period drives: one setpoint per period, validated by SYNC, controlword synchronous as well.
SETPOINT_RPDOS = (
    PdoLayout(1, SYNCHRONOUS, ((INTERPOLATION_DATA_RECORD, 1, 32),), PdoRole.SETPOINT),
    PdoLayout(2, SYNCHRONOUS, ((CONTROLWORD, 0, 16),), PdoRole.CONTROLWORD),
)
SETPOINT_TPDOS = (PdoLayout(1, SYNCHRONOUS, ((STATUSWORD, 0, 16), (POSITION_ACTUAL_VALUE, 0, 32))),)

# Parker SLVDN mode 202: position + velocity feed-forward in rpm on the synchronous PDO 4 rx.
PARKER_RPDOS = (
    PdoLayout(
        4, SYNCHRONOUS, ((INTERPOLATION_DATA_RECORD, 1, 32), (INTERPOLATION_DATA_RECORD, 3, 32)), PdoRole.SETPOINT
    ),
    PdoLayout(2, SYNCHRONOUS, ((CONTROLWORD, 0, 16),), PdoRole.CONTROLWORD),
)
# Its TPDO1 maps 0x6063, the position the seed lists for IP mode ("Position actual value*"; it lists
# no 0x6064): in IP mode the SLVDN's factor group is not active, so 0x6063, in encoder increments,
# is in the units of the setpoints 0x60C1:01 it follows.
PARKER_TPDOS = (PdoLayout(1, SYNCHRONOUS, ((STATUSWORD, 0, 16), (POSITION_ACTUAL_INTERNAL_VALUE, 0, 32))),)

# EPOS2 clock synchronisation (app note 2.4 and 3.7): after each SYNC the master sends the time that
# SYNC left the wire (0x1013, us) once, on one COB-ID that every EPOS2 takes through its asynchronous RPDO3.
EMCY_COB_ID_BASE = 0x080


def time_stamp_cob_id(master_node_id: int) -> int:
    """The COB-ID of the master's 0x1013 frame: 0x80 + the master's own node id, the EMCY identifier of
    the predefined connection set that belongs to the master, which sends no EMCY (it has no error to
    signal on the bus; its faults are its own reports). Why there: the time stamp must reach the drive
    before the next SYNC, and a lower identifier wins arbitration. 0x081-0x0FF lie above SYNC (0x080)
    and below every PDO (0x180-0x57F) and SDO (0x580-0x67F), so no PDO or SDO traffic can hold it back;
    it yields only to NMT, SYNC and the drives' own EMCYs (0x080 + their ids: rare, and a fault then
    halts the motion anyway). TIME (0x100, CiA 301's own time object) is not an option: on an EPOS2 it
    resets the motion clock to zero (app note 2.4). The old choice, 0x400, lost arbitration to every
    PDO below it: a loaded bus delayed it past the next SYNC."""
    return EMCY_COB_ID_BASE + master_node_id


TIME_STAMP_COB_ID = time_stamp_cob_id(127)  # with the default master node id (BusConfig.master_node_id)
SYNC_COB_ID = 0x080  # CiA 301 default COB-ID of SYNC (0x1005), which every drive of a cell keeps
# pvtflow's SYNC carries no counter (0x1019 = 0, no data byte): every TPDO answers from the first SYNC
# after the start, as the master counts them (axes.master.bus.sync). CiA 301 uses a TPDO's SYNC start value
# 0x1800:06 only with a counter, so configuration writes it 0 where the drive has it, clearing a value
# an earlier setup may have left for a SYNC with a counter; the simulated drives have no 0x1800:06.


class NmtCommand(IntEnum):
    """CiA 301 NMT command specifiers (the first byte of a frame on COB-ID 0)."""

    START = 0x01
    STOP = 0x02
    PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


# CiA 301 NMT error control: a node's heartbeat is one byte, its NMT state, on 0x700 + node id
HEARTBEAT_COB_ID_BASE = 0x700
NMT_STATE_OPERATIONAL = 5
EPOS2_TIME_STAMP_RPDO = PdoLayout(3, ASYNCHRONOUS, ((HIGH_RESOLUTION_TIME_STAMP, 0, 32),), PdoRole.TIME_STAMP)
