"""Writes configs/eds/*.eds, the object dictionaries of pvtflow's simulated drives.

The EDS files are the artefacts (a master or a commissioning tool reads them); this module is how
they are made, so that the four dictionaries share their CiA 301 / CiA 402 part and stay
consistent. Regenerate with ``python -m pvtflow.axes.sim.edsgen``; tests check the files are up to date.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.sim.node import device
from pvtflow.configs import EDS_DIR

# CiA 301 data types
BOOLEAN, I8, I16, I32, U8, U16, U32, U64 = 0x1, 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x1B


@dataclass(frozen=True)
class Var:
    name: str
    data_type: int
    access: str = "rw"
    default: str | int | None = 0
    pdo: bool = False


@dataclass(frozen=True)
class Rec:
    name: str
    subs: tuple[Var, ...]  # sub-index 1..n; sub 0 (highest sub-index) is generated
    array: bool = False
    count_access: str = "ro"  # sub 0: "rw" where it is the number of entries in use (PDO mapping)
    count_default: int | None = None  # None: the number of sub-indices


Entry = Var | Rec


def _pdo_objects(n_rpdo: int, n_tpdo: int) -> dict[int, Entry]:
    out: dict[int, Entry] = {}
    for i in range(n_rpdo):
        out[0x1400 + i] = Rec(
            f"Receive PDO {i + 1} parameter",
            (
                Var(f"COB-ID used by RPDO {i + 1}", U32, "rw", f"$NODEID+0x{od.pdo_cob_id(i + 1, 0, receive=True):X}"),
                Var("Transmission type", U8, "rw", 255),
            ),
        )
        out[0x1600 + i] = Rec(
            f"Receive PDO {i + 1} mapping",
            tuple(Var(f"Mapped object {k}", U32, "rw", 0) for k in range(1, 9)),
            count_access="rw",
            count_default=0,
        )
    for i in range(n_tpdo):
        out[0x1800 + i] = Rec(
            f"Transmit PDO {i + 1} parameter",
            (
                Var(
                    f"COB-ID used by TPDO {i + 1}",
                    U32,
                    "rw",
                    f"$NODEID+0x{od.PDO_INVALID | od.pdo_cob_id(i + 1, 0, receive=False):X}",
                ),
                Var("Transmission type", U8, "rw", 255),
                Var("Inhibit time", U16, "rw", 0),
                Var("Reserved", U8, "rw", 0),
                Var("Event timer", U16, "rw", 0),
            ),
        )
        out[0x1A00 + i] = Rec(
            f"Transmit PDO {i + 1} mapping",
            tuple(Var(f"Mapped object {k}", U32, "rw", 0) for k in range(1, 9)),
            count_access="rw",
            count_default=0,
        )
    return out


def _common(modes: device.DriveModes, profile: DriveProfile) -> dict[int, Entry]:
    """CiA 301 communication objects and the CiA 402 objects every simulated drive has; 0x6502 says
    which modes 0x6060 accepts (axes/sim/node/device.py)."""
    d: dict[int, Entry] = {
        0x1000: Var("Device type", U32, "ro", device.CIA402_SERVO_DRIVE),
        0x1001: Var("Error register", U8, "ro", 0),
        0x1003: Rec(
            "Pre-defined error field",
            tuple(Var(f"Standard error field {k}", U32, "ro", 0) for k in range(1, 5)),
            array=True,
            count_access="rw",
            count_default=0,
        ),
        0x1005: Var("COB-ID SYNC message", U32, "rw", 0x80),
        0x1008: Var("Manufacturer device name", 0x9, "const", profile.spec.simulated_name),
        0x1014: Var("COB-ID EMCY", U32, "ro", "$NODEID+0x80"),
        # two consumer entries, as maxon's EPOS2 has: pvtflow's master takes :01 for its own heartbeat
        od.CONSUMER_HEARTBEAT_TIME: Rec(
            "Consumer heartbeat time",
            tuple(Var(f"Consumer heartbeat time {k}", U32, "rw", 0) for k in (1, 2)),
            array=True,
        ),
        0x1017: Var("Producer heartbeat time", U16, "rw", 0),
        0x1018: Rec(
            "Identity object",
            (
                Var("Vendor-ID", U32, "ro", od.SIMULATED_VENDOR_ID),
                Var("Product code", U32, "ro", profile.spec.product_code),
                Var("Revision number", U32, "ro", 0x00010000),
                Var("Serial number", U32, "ro", 0),
            ),
        ),
        od.HIGH_RESOLUTION_TIME_STAMP: Var("High resolution time stamp", U32, "rw", 0, pdo=True),
        0x603F: Var("Error code", U16, "ro", 0, pdo=True),
        # 0: no action until a master says what to do when it is lost (pvtflow writes 1, fault)
        od.ABORT_CONNECTION_OPTION_CODE: Var("Abort connection option code", I16, "rw", 0),
        od.CONTROLWORD: Var("Controlword", U16, "rw", 0, pdo=True),
        od.STATUSWORD: Var("Statusword", U16, "ro", 0, pdo=True),
        0x605A: Var("Quick stop option code", I16, "rw", 2),
        od.FAULT_REACTION_OPTION_CODE: Var("Fault reaction option code", I16, "rw", 2),
        od.MODES_OF_OPERATION: Var("Modes of operation", I8, "rw", 0, pdo=True),
        od.MODES_OF_OPERATION_DISPLAY: Var("Modes of operation display", I8, "ro", 0, pdo=True),
        od.POSITION_DEMAND_VALUE: Var("Position demand value", I32, "ro", 0, pdo=True),
        od.POSITION_ACTUAL_VALUE: Var("Position actual value", I32, "ro", 0, pdo=True),
        od.MAX_FOLLOWING_ERROR: Var("Max following error", U32, "rw", 2000, pdo=True),
        od.SOFTWARE_POSITION_LIMIT: Rec(
            "Software position limit",
            (
                Var("Min position limit", I32, "rw", -(2**31)),
                Var("Max position limit", I32, "rw", 2**31 - 1),
            ),
            array=True,
        ),
        od.MAX_PROFILE_VELOCITY: Var("Max profile velocity", U32, "rw", 25000),
        od.PROFILE_VELOCITY: Var("Profile velocity", U32, "rw", 1000, pdo=True),
        od.PROFILE_ACCELERATION: Var("Profile acceleration", U32, "rw", 10000, pdo=True),
        od.PROFILE_DECELERATION: Var("Profile deceleration", U32, "rw", 10000, pdo=True),
        od.QUICK_STOP_DECELERATION: Var("Quick stop deceleration", U32, "rw", 10000, pdo=True),
        od.MAX_ACCELERATION: Var("Max acceleration", U32, "rw", 0xFFFFFFFF),
        od.POLARITY: Var("Polarity", U8, "rw", 0),
        device.SUPPORTED_DRIVE_MODES: Var("Supported drive modes", U32, "ro", modes.supported),
    }
    return d


def _encoder_resolution() -> Rec:
    """CiA 402's 0x608F; the simulated drive reports its own encoder in it (axes/sim/node/dictionary.py)."""
    return Rec(
        "Position encoder resolution",
        (Var("Encoder increments", U32, "ro", 2000), Var("Motor revolutions", U32, "ro", 1)),
    )


def _homing(default_method: int) -> dict[int, Entry]:
    """The CiA 402 homing objects (mode 6), with maxon's data types and defaults but the method."""
    return {
        od.HOME_OFFSET: Var("Home offset", I32, "rw", 0, pdo=True),
        od.HOMING_METHOD: Var("Homing method", I8, "rw", default_method, pdo=True),
        od.HOMING_SPEEDS: Rec(
            "Homing speeds",
            (
                Var("Speed for switch search", U32, "rw", 100, pdo=True),
                Var("Speed for zero search", U32, "rw", 10, pdo=True),
            ),
            array=True,
        ),
        od.HOMING_ACCELERATION: Var("Homing acceleration", U32, "rw", 1000, pdo=True),
    }


def epos2() -> dict[int, Entry]:
    d = _common(device.EPOS2_MODES, DriveProfile.EPOS2_PVT)
    d.update(_pdo_objects(4, 4))
    d.update(_homing(od.HomingMethod.CURRENT_POSITION))  # maxon's default, 7, is a method not simulated
    d[od.EPOS2_HOMING_CURRENT_THRESHOLD] = Var("Current threshold for homing mode", U16, "rw", 500, pdo=True)
    d[od.EPOS2_HOME_POSITION] = Var("Home Position", I32, "rw", 0, pdo=True)
    # maxon's sensor configuration and motor data (names, types and defaults of maxon's EDS); the
    # simulated drive reports its own encoder in :01 (axes/sim/node/dictionary.py)
    d[od.EPOS2_SENSOR_CONFIGURATION] = Rec(
        "Sensor configuration",
        (
            Var("Pulse number incremental encoder 1", U32, "rw", 500),
            Var("Position sensor type", U16, "rw", 1),
            Var("Internal absolute position offset", U16, "rw", 0),
            Var("Position sensor polarity", U16, "rw", 0),
        ),
    )
    # maxon's velocity unit: 10^notation x the dimension (0xA4 rpm), defaults as in maxon's EDS
    d[od.VELOCITY_NOTATION_INDEX] = Var("Velocity notation index", I8, "rw", 0)
    d[od.VELOCITY_DIMENSION_INDEX] = Var("Velocity dimension index", U8, "rw", 0xA4)
    d[od.MOTOR_DATA] = Rec(
        "Motor data",
        (
            Var("Continuous current limit", U16, "rw", 10000),
            Var("Output current limit", U16, "rw", 25000),
            Var("Pole pair number", U8, "rw", 1),
            Var("Maximal motor speed", U32, "rw", 25000),
            Var("Thermal time constant winding", U16, "rw", 40),
        ),
    )
    d[od.INTERPOLATION_SUBMODE] = Var("Interpolation sub mode selection", I16, "rw", -1)
    d[od.INTERPOLATION_TIME_PERIOD] = Rec(
        "Interpolation time period",
        (
            Var("Interpolation time period value", U8, "rw", 1),
            Var("Interpolation time index", I8, "rw", -3),
        ),
    )
    d[od.INTERPOLATION_DATA_CONFIGURATION] = _buffer_config()
    d[od.EPOS2_INTERPOLATION_DATA_RECORD] = Var("Interpolation data record", U64, "wo", None, pdo=True)
    d[od.EPOS2_INTERPOLATION_BUFFER] = Rec(
        "Interpolation buffer",
        (
            Var("Interpolation buffer status", U16, "ro", 0, pdo=True),
            Var("Interpolation buffer underflow warning", U16, "rw", 4),
            Var("Interpolation buffer overflow warning", U16, "rw", 60),
        ),
    )
    return d


def _buffer_config() -> Rec:
    return Rec(
        "Interpolation data configuration",
        (
            Var("Maximum buffer size", U32, "ro", od.EPOS2_BUFFER_SIZE),
            Var("Actual buffer size", U32, "ro", od.EPOS2_BUFFER_SIZE),
            Var("Buffer organisation", U8, "rw", 0),
            Var("Buffer position", U16, "rw", 0),
            Var("Size of data record", U8, "wo", 8),
            Var("Buffer clear", U8, "wo", 0),
        ),
    )


def _setpoint_record(with_velocity: bool) -> Rec:
    subs = [Var("Interpolation target position", I32, "rw", 0, pdo=True)]
    if with_velocity:
        subs += [
            Var("Interpolation velocity (counts/s)", I32, "rw", 0, pdo=True),
            Var("Interpolation velocity (rpm)", I32, "rw", 0, pdo=True),
        ]
    return Rec("Interpolation data record", tuple(subs), array=True)


def _time_period() -> Rec:
    return Rec(
        "Interpolation time period",
        (
            Var("Interpolation time period value", U8, "rw", 1),
            Var("Interpolation time index", I8, "rw", -3),
        ),
    )


def cia402_ip_linear() -> dict[int, Entry]:
    d = _common(device.IP_LINEAR_MODES, DriveProfile.CIA402_IP_LINEAR)
    d.update(_pdo_objects(4, 4))
    d[od.POSITION_ENCODER_RESOLUTION] = _encoder_resolution()
    d[od.INTERPOLATION_SUBMODE] = Var("Interpolation sub mode select", I16, "rw", 0)
    d[od.INTERPOLATION_DATA_RECORD] = _setpoint_record(False)
    d[od.INTERPOLATION_TIME_PERIOD] = _time_period()
    d[od.INTERPOLATION_DATA_CONFIGURATION] = Rec(
        "Interpolation data configuration",
        (
            Var("Maximum buffer size", U32, "ro", 1),
            Var("Actual buffer size", U32, "ro", 1),
            Var("Buffer organisation", U8, "rw", 0),
            Var("Buffer position", U16, "rw", 0),
            Var("Size of data record", U8, "wo", 4),
            Var("Buffer clear", U8, "wo", 0),
        ),
    )
    return d


def sync_setpoint() -> dict[int, Entry]:
    d = _common(device.SYNC_SETPOINT_MODES, DriveProfile.SYNC_SETPOINT)
    d.update(_pdo_objects(4, 4))
    d[od.POSITION_ENCODER_RESOLUTION] = _encoder_resolution()
    d.update(_homing(od.HomingMethod.CURRENT_POSITION))
    d[od.INTERPOLATION_SUBMODE] = Var("Interpolation sub mode select", I16, "rw", 0)
    d[od.INTERPOLATION_DATA_RECORD] = _setpoint_record(False)
    d[od.INTERPOLATION_TIME_PERIOD] = _time_period()
    return d


def parker_slvdn() -> dict[int, Entry]:
    d = _common(device.PARKER_MODES, DriveProfile.PARKER_SLVDN)
    d.update(_pdo_objects(4, 4))
    d[od.POSITION_ENCODER_RESOLUTION] = _encoder_resolution()
    d[od.POSITION_ACTUAL_INTERNAL_VALUE] = Var("Position actual value (increments)", I32, "ro", 0, pdo=True)
    d[od.COMMUNICATION_CYCLE_PERIOD] = Var("Communication cycle period", U32, "rw", 0)
    d[od.PARKER_OPERATIVE_MODE] = Var("Pr31 operative mode", I16, "rw", 0)
    d[od.INTERPOLATION_SUBMODE] = Var("Interpolation sub mode select", I16, "rw", 0)
    d[od.INTERPOLATION_DATA_RECORD] = _setpoint_record(True)
    return d


DRIVES = {
    "epos2.eds": (epos2, "maxon EPOS2 (buffered PVT, interpolated position mode 7)"),
    "cia402_ip_linear.eds": (cia402_ip_linear, "CiA 402 linear interpolation, one target point"),
    "sync_setpoint.eds": (sync_setpoint, "servodrive IP without buffer, one setpoint per SYNC"),
    "parker_slvdn.eds": (parker_slvdn, "Parker SLVDN operative mode 202"),
}


PROFILES = {
    "epos2.eds": DriveProfile.EPOS2_PVT,
    "cia402_ip_linear.eds": DriveProfile.CIA402_IP_LINEAR,
    "sync_setpoint.eds": DriveProfile.SYNC_SETPOINT,
    "parker_slvdn.eds": DriveProfile.PARKER_SLVDN,
}


def _fmt(value: str | int, data_type: int) -> str:
    if isinstance(value, str):
        return value
    if data_type in (U32, U64, U16) and value >= 0x100:
        return f"0x{value:X}"
    return str(value)


def _var_lines(section: str, v: Var) -> list[str]:
    lines = [
        f"[{section}]",
        f"ParameterName={v.name}",
        "ObjectType=0x7",
        f"DataType=0x{v.data_type:04X}",
        f"AccessType={v.access}",
    ]
    if v.default is not None:
        lines.append(f"DefaultValue={_fmt(v.default, v.data_type)}")
    lines += [f"PDOMapping={int(v.pdo)}", ""]
    return lines


def render(filename: str) -> str:
    """The text of one EDS file."""
    build, description = DRIVES[filename]
    d = build()
    mandatory = [i for i in (0x1000, 0x1001, 0x1018) if i in d]
    optional = [i for i in sorted(d) if i not in mandatory and (i < 0x2000 or i >= 0x6000)]
    manufacturer = [i for i in sorted(d) if 0x2000 <= i < 0x6000]
    out = [
        "; pvtflow simulated drive object dictionary: generated by axes/sim/edsgen.py, do not edit",
        "[FileInfo]",
        f"FileName={filename}",
        "FileVersion=1",
        "FileRevision=0",
        "EDSVersion=4.0",
        f"Description={description}",
        "CreatedBy=pvtflow",
        "",
        "[DeviceInfo]",
        "VendorName=pvtflow (simulated)",
        f"VendorNumber=0x{od.SIMULATED_VENDOR_ID:08X}",
        f"ProductName={filename[:-4]}",
        f"ProductNumber=0x{PROFILES[filename].spec.product_code:X}",
        "RevisionNumber=0x00010000",
        "BaudRate_10=1",
        "BaudRate_20=1",
        "BaudRate_50=1",
        "BaudRate_125=1",
        "BaudRate_250=1",
        "BaudRate_500=1",
        "BaudRate_800=1",
        "BaudRate_1000=1",
        "SimpleBootUpMaster=0",
        "SimpleBootUpSlave=1",
        "Granularity=8",
        "DynamicChannelsSupported=0",
        "GroupMessaging=0",
        "NrOfRXPDO=4",
        "NrOfTXPDO=4",
        "LSS_Supported=0",
        "",
        "[DummyUsage]",
        *(f"Dummy000{k}=0" for k in range(1, 8)),
        "",
    ]
    for title, indices in (
        ("MandatoryObjects", mandatory),
        ("OptionalObjects", optional),
        ("ManufacturerObjects", manufacturer),
    ):
        out += [f"[{title}]", f"SupportedObjects={len(indices)}"]
        out += [f"{k}=0x{i:04X}" for k, i in enumerate(indices, 1)]
        out.append("")
    for index in sorted(d):
        e = d[index]
        if isinstance(e, Var):
            out += _var_lines(f"{index:04X}", e)
            continue
        out += [
            f"[{index:04X}]",
            f"ParameterName={e.name}",
            f"ObjectType=0x{8 if e.array else 9:X}",
            f"SubNumber={len(e.subs) + 1}",
            "",
        ]
        count = len(e.subs) if e.count_default is None else e.count_default
        out += _var_lines(f"{index:04X}sub0", Var("Highest sub-index supported", U8, e.count_access, count))
        for k, v in enumerate(e.subs, 1):
            out += _var_lines(f"{index:04X}sub{k:X}", v)
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    EDS_DIR.mkdir(parents=True, exist_ok=True)
    for filename in DRIVES:
        (EDS_DIR / filename).write_text(render(filename), encoding="ascii")
        print(EDS_DIR / filename)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
