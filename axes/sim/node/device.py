"""What a simulated drive says about itself: its modes of operation and a value for every object.

A CiA 402 master that nobody here wrote (python-canopen's ``BaseNode402``, a PLC's CANopen master)
reads Supported Drive Modes (0x6502) before it writes Modes of Operation (0x6060), and may read any
object the drive's EDS declares readable. A real drive answers every one of them with its own value,
whether or not the EDS states a default (maxon's EPOS2 70/10 EDS states none for 166 objects, among
them 0x1000, 0x1018, 0x6502 and 0x60C0); python-canopen's ``LocalNode`` answers only what the EDS or
the simulation stored, and aborts the rest with 0x060A0023. :func:`complete_object_dictionary`
gives each such object the drive's own value as its default, in the drive's private copy of the
dictionary, so a reset restores it as a power cycle would.

Modes (decided here, from the seeds and maxon's EDS; the simulation moves the axis in mode 7,
interpolated position, and homes it in mode 6 where the drive has it (axes/sim/cia402/homing_mode.py): in any
other mode it accepts, the drive holds its position, as a drive does that was given no target in
that mode):

* ``epos2_pvt`` (maxon EPOS2): profile position 1, profile velocity 3, homing 6, interpolated
  position 7 and maxon's position -1, velocity -2, current -3, master encoder -5 and step/direction
  -6 modes. The app note covers mode 7 only; maxon's EDS has the objects of each of these modes
  (0x607A, 0x60FF, 0x6098-0x609A, 0x60C0-0x60C5, 0x2062, 0x206B, 0x2030, 0x2300) and none of the
  cyclic synchronous modes' (0x60B0-0x60B2, 0x6071: they came with the EPOS3/EPOS4), and powers up
  in profile position (0x6060 default 1). 0x6502 = 0x00370065: CiA 402 bits 0, 2, 5, 6 and, for
  maxon's modes, bits 16-18, 20, 21, taken from memory of maxon's firmware specification (the seeds
  give no value): to be checked on a real drive.
* ``cia402_ip_linear`` (seed cia402-ip-linear-single-setpoint): interpolated position 7, the only
  mode the seed documents.
* ``sync_setpoint`` (seed servodrive-ip-no-buffer): homing 6 (its 0x60E3 "supported homing
  methods"), interpolated position 7 and cyclic synchronous position 8, the modes the seed's pages
  describe.
* ``parker_slvdn`` (seed parker-slvdn-ip-mode-202): interpolated position 7, which is operative mode
  202 (Pr31); the seed maps no other operative mode onto a CiA 402 code.

Every drive also accepts 0 ("no mode", CiA 402), the power-on value of pvtflow's own EDS files. Any
other value written to 0x6060 is refused with SDO abort 0x06090030 (value range exceeded), and
0x6061 keeps showing the mode in force.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from canopen import objectdictionary
from canopen.objectdictionary import ObjectDictionary
from canopen.profiles.p402 import OperationMode

from pvtflow.axes.drive.objects import IDENTITY, SUPPORTED_DRIVE_MODES

DEVICE_TYPE = 0x1000
MANUFACTURER_DEVICE_NAME = 0x1008
CIA402_SERVO_DRIVE = 0x00020192  # 0x1000: device profile 402, servo drive (what the EPOS2 reports)

NO_MODE = OperationMode.NO_MODE
SIMULATED_MODE = OperationMode.INTERPOLATED_POSITION  # the one mode in which a simulated drive moves

Value = int | float | str | bytes


@dataclass(frozen=True)
class DriveModes:
    """The modes of operation one drive supports: what 0x6502 reports and 0x6060 accepts."""

    codes: tuple[int, ...]  # 0x6060 values, manufacturer-specific ones negative
    manufacturer_bits: Mapping[int, int] = field(default_factory=dict)  # negative code -> its 0x6502 bit

    def __post_init__(self) -> None:
        for code in self.codes:
            if code < 0 and code not in self.manufacturer_bits:
                raise ValueError(f"manufacturer mode {code} has no bit in 0x6502")
            if code > 0 and code not in OperationMode.CODE2NAME:
                raise ValueError(f"mode {code} is not a CiA 402 mode")

    @property
    def supported(self) -> int:
        """The value of 0x6502: CiA 402's bit for each standard mode (python-canopen's table), the
        manufacturer's for the others."""
        word = 0
        for code in self.codes:
            if code < 0:
                word |= 1 << self.manufacturer_bits[code]
            else:
                word |= OperationMode.SUPPORTED[OperationMode.CODE2NAME[code]]
        return word

    def accepts(self, code: int) -> bool:
        return code == NO_MODE or code in self.codes


EPOS2_MODES = DriveModes(
    (1, 3, 6, 7, -1, -2, -3, -5, -6),
    {-1: 16, -2: 17, -3: 18, -5: 20, -6: 21},
)
IP_LINEAR_MODES = DriveModes((OperationMode.INTERPOLATED_POSITION,))
SYNC_SETPOINT_MODES = DriveModes(
    (OperationMode.HOMING, OperationMode.INTERPOLATED_POSITION, OperationMode.CYCLIC_SYNCHRONOUS_POSITION)
)
PARKER_MODES = DriveModes((OperationMode.INTERPOLATED_POSITION,))


def identity_values(od: ObjectDictionary, modes: DriveModes) -> dict[tuple[int, int], Value]:
    """What every simulated drive reports about itself: device type, name and identity as its EDS's
    [DeviceInfo] states them (a drive's identity object is what its EDS describes), and its modes."""
    info = od.device_information
    values: dict[tuple[int, int], Value] = {
        (DEVICE_TYPE, 0): CIA402_SERVO_DRIVE,
        (SUPPORTED_DRIVE_MODES, 0): modes.supported,
    }
    if info.product_name:
        values[(MANUFACTURER_DEVICE_NAME, 0)] = info.product_name
    for sub, number in ((1, info.vendor_number), (2, info.product_number), (3, info.revision_number)):
        if number is not None:
            values[(IDENTITY, sub)] = number
    return values


def _zero(var: objectdictionary.ODVariable) -> Value:
    """A neutral value of the variable's type, inside its EDS range (LowLimit/HighLimit)."""
    if var.data_type in (objectdictionary.VISIBLE_STRING, objectdictionary.UNICODE_STRING):
        return ""
    if var.data_type in (objectdictionary.DOMAIN, objectdictionary.OCTET_STRING):
        return b""  # an empty domain: an upload answers "no data available" (0x08000024)
    if var.data_type in (objectdictionary.REAL32, objectdictionary.REAL64):
        return 0.0
    value = 0
    if var.min is not None:
        value = max(value, var.min)
    if var.max is not None:
        value = min(value, var.max)
    return value


def _variables(od: ObjectDictionary) -> list[objectdictionary.ODVariable]:
    out: list[objectdictionary.ODVariable] = []
    for entry in od.values():
        if isinstance(entry, objectdictionary.ODVariable):
            out.append(entry)
        else:
            out.extend(entry.values())
    return out


def complete_object_dictionary(
    od: ObjectDictionary, own: Mapping[tuple[int, int], Value], always: frozenset[tuple[int, int]] = frozenset()
) -> list[tuple[int, int]]:
    """Give every readable object the EDS leaves without a value one: the drive's own (``own``) or a
    neutral one of its type. Entries in ``always`` (facts of the drive, such as 0x6502) replace the
    EDS's default too. Returns the objects that got a value. ``od`` must be the drive's own copy."""
    filled: list[tuple[int, int]] = []
    for var in _variables(od):
        key = (var.index, var.subindex)
        if key in always and key in own:
            var.default = own[key]
            if var.value is not None:  # a DCF's ParameterValue would win over the default
                var.value = own[key]
            filled.append(key)
        elif var.readable and var.value is None and var.default is None:
            var.default = own.get(key, _zero(var))
            filled.append(key)
    return filled


__all__ = [
    "CIA402_SERVO_DRIVE",
    "EPOS2_MODES",
    "IP_LINEAR_MODES",
    "NO_MODE",
    "PARKER_MODES",
    "SIMULATED_MODE",
    "SUPPORTED_DRIVE_MODES",
    "SYNC_SETPOINT_MODES",
    "DriveModes",
    "Value",
    "complete_object_dictionary",
    "identity_values",
]
