"""Commissioning: what each drive is, read from the drive over SDO, against what the cell expects.

Everything else the master knows about a drive comes from the cell file. A real machine's first
surprise is a drive that is not what the file says: another encoder, an inverted polarity, another
product, limits a vendor tool stored. Each ``Check`` names the object, what the cell expects, what
the drive holds, and whether they agree. Three kinds:

- ``FACT``: what the drive is and the master must not change: its identity 0x1018:01/:02 (the axis's
  ``identity`` in the cell file, or one of the profile's ``DriveProfile.identities``), its
  supported modes 0x6502 (interpolated position, and homing where the axis homes), its encoder
  (CiA 402's 0x608F :01 increments per :02 revolutions, or maxon's 0x2210:01 pulses x 4) against
  the cell's ``qc_per_motor_rev``, its polarity 0x607E = 0
  (the cell's direction is the sign of its scaling; a drive that inverts as well turns the axis the
  wrong way), maxon's position sensor type 0x2210:02 (an incremental encoder) and polarity
  0x2210:04 = 0, the velocity unit (maxon's 0x608B notation index and 0x608C dimension: 10^index rpm
  = the cell's ``velocity_unit_rpm``) and maxon's 0x6410:04, the motor's maximal speed at or above
  the cell's 0x607F. ``AxisGroup.configure`` reads these first and refuses the cell on any mismatch, naming it,
  before it writes anything: nothing moves.
- ``SETTING``: what pvtflow writes at configuration from the axis (``expected_settings``: 0x607F,
  0x60C5, 0x607D, 0x6065, 0x6085 where the drive has them). ``pvtflow commission`` shows them as the drive
  stores them (a vendor tool, an earlier setup) and counts a difference; configuration writes them
  where the drive has them and reads them back (``Profile.write_settings``).
- ``INFO``: heartbeat 0x1017 / 0x1016:01, the PDOs pvtflow uses as the drive maps them, the error
  history 0x1003: shown, never a mismatch.

Each check's ``status`` is ``ok``, ``mismatch`` or ``not_checked``: the drive lacks the object (named
in ``found``), so nothing was compared. ``not_checked`` is never ``ok``: it is shown as such, and a
check the cell requires (the axis's ``commission_requires``, by object, e.g. maxon's 0x2210:02 on a
real EPOS2) that cannot be made fails the report as a mismatch does. A cell setting whose object the
drive lacks (the status TPDOs' event timer without 0x1800:05) is required: it is refused, not dropped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from canopen.profiles.p402 import OperationMode

from pvtflow.axes.drive import objects as od
from pvtflow.axes.master.link import DriveError
from pvtflow.axes.master.profiles.base import expected_settings
from pvtflow.axes.master.tpdo_rates import with_rates

if TYPE_CHECKING:
    from pvtflow.axes.drive.objects import PdoLayout
    from pvtflow.axes.master.link import AxisLink
    from pvtflow.axes.master.profiles.base import Profile

ABSENT = "absent"
# maxon's 0x2210:02 position sensor types the cell's qc scaling describes (EPOS2 firmware specification):
# 1 incremental encoder 1 with index (3-channel), 2 without index (2-channel)
EPOS2_INCREMENTAL_SENSOR_TYPES = (1, 2)
# the FACT checks' objects a cell can require (``AxisConfig.commission_requires``)
REQUIRABLE_OBJECTS = (
    "0x1018:01-02",
    "0x6502",
    "0x608F",
    "0x2210:01",
    "0x2210:02",
    "0x2210:04",
    "0x607E",
    "0x6410:04",
    "0x608B",
    "0x608C",
)
EPOS2_VELOCITY_DIMENSION_RPM = 0xA4  # 0x608C: CiA 402's dimension index of rpm (maxon's EDS default)
_IP_MODE_BIT = OperationMode.SUPPORTED["INTERPOLATED POSITION"]
_HOMING_MODE_BIT = OperationMode.SUPPORTED["HOMING"]


class Status(StrEnum):
    OK = "ok"
    MISMATCH = "mismatch"
    NOT_CHECKED = "not_checked"  # the drive lacks the object: nothing was compared


class CheckKind(StrEnum):
    FACT = "fact"  # the drive is this; a mismatch refuses the cell
    SETTING = "setting"  # pvtflow writes it at configuration; commissioning shows it as stored
    INFO = "info"  # shown, never a mismatch


@dataclass(frozen=True)
class Check:
    object: str  # "0x1018:01-02"
    name: str  # what it is, in words
    expected: str
    found: str  # ABSENT: the drive has no such object
    agrees: bool  # what was found agrees with what was expected (meaningless when not checked)
    kind: CheckKind
    required: bool = False  # the cell requires the check to be made (not_checked fails it)

    @property
    def status(self) -> Status:
        if self.found == ABSENT:
            return Status.NOT_CHECKED
        return Status.OK if self.agrees else Status.MISMATCH

    @property
    def ok(self) -> bool:
        return self.status is Status.OK

    @property
    def fails(self) -> bool:
        """A mismatch of a FACT or SETTING, or a required check that could not be made."""
        if self.status is Status.NOT_CHECKED:
            return self.required
        return self.status is Status.MISMATCH and self.kind is not CheckKind.INFO

    def __str__(self) -> str:
        if self.status is Status.NOT_CHECKED:
            need = " (required by the cell)" if self.required else ""
            return f"{self.object} {self.name}: not checked, the drive has no {self.object}{need}"
        return f"{self.object} {self.name}: expected {self.expected}, found {self.found}"

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "kind": str(self.kind), "status": str(self.status)}


@dataclass
class AxisCommission:
    joint: str
    node_id: int
    profile: str
    checks: list[Check] = field(default_factory=list)

    @property
    def mismatches(self) -> list[Check]:
        """The checks that fail the axis (``Check.fails``)."""
        return [c for c in self.checks if c.fails]

    @property
    def not_checked(self) -> list[Check]:
        return [c for c in self.checks if c.status is Status.NOT_CHECKED]

    @property
    def ok(self) -> bool:
        return not self.mismatches


@dataclass
class CommissionReport:
    """Per axis, the checks of one cell's drives (``ok``: every axis agrees with the cell)."""

    axes: list[AxisCommission]
    sdo_transfers: int = 0  # SDO round trips the report took

    @property
    def ok(self) -> bool:
        return all(a.ok for a in self.axes)

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "sdo_transfers": self.sdo_transfers,
            "axes": [
                {
                    "joint": a.joint,
                    "node_id": a.node_id,
                    "profile": a.profile,
                    "ok": a.ok,
                    "not_checked": len(a.not_checked),
                    "checks": [c.to_json() for c in a.checks],
                }
                for a in self.axes
            ],
        }


# --- the checks ----------------------------------------------------------------------------------
def drive_facts(link: AxisLink) -> list[Check]:
    """What the drive is against what the cell expects of it (identity, modes, encoder, polarity,
    motor speed): the checks that refuse a cell."""
    config = link.config
    checks: list[Check] = []
    known = config.profile.identities
    if config.identity is not None:
        known = (od.DriveIdentity(*config.identity, "the cell's identity"), *known)
    vendor = link.read_optional(od.IDENTITY, 1, "I")
    product = link.read_optional(od.IDENTITY, 2, "I")
    expected = " or ".join(str(i) for i in known)
    if vendor is None or product is None:
        checks.append(Check("0x1018:01-02", "identity", expected, ABSENT, False, CheckKind.FACT))
    else:
        found = next((i for i in known if (i.vendor_id, i.product_code) == (vendor, product)), None)
        text = str(found) if found else f"vendor 0x{vendor:08X} product 0x{product:08X}"
        checks.append(Check("0x1018:01-02", "identity", expected, text, found is not None, CheckKind.FACT))

    want = _IP_MODE_BIT | (_HOMING_MODE_BIT if config.homing is not None else 0)
    words = "interpolated position (7)" + (" and homing (6)" if config.homing is not None else "")
    modes = link.read_optional(od.SUPPORTED_DRIVE_MODES, 0, "I")
    if modes is None:
        checks.append(Check("0x6502", "supported drive modes", words, ABSENT, False, CheckKind.FACT))
    else:
        checks.append(
            Check("0x6502", "supported drive modes", words, f"0x{modes:08X}", modes & want == want, CheckKind.FACT)
        )

    checks.append(_encoder_check(link))
    checks.extend(_epos2_sensor_checks(link))

    polarity = link.read_optional(od.POLARITY, 0, "B")
    found_polarity = ABSENT if polarity is None else f"0x{polarity:02X}"
    checks.append(
        Check("0x607E", "polarity", "0x00 (not inverted)", found_polarity, polarity in (None, 0), CheckKind.FACT)
    )

    speed = link.read_optional(od.MOTOR_DATA, od.MOTOR_MAX_SPEED_SUB, "I")
    cell_rpm = config.limits.max_profile_velocity_rpm
    checks.append(
        Check(
            "0x6410:04",
            "motor maximal speed",
            f">= {cell_rpm:g} rpm (the cell's 0x607F)",
            ABSENT if speed is None else f"{speed} rpm",
            speed is not None and speed >= cell_rpm,
            CheckKind.FACT,
        )
    )
    checks.extend(_velocity_unit_checks(link))
    return [_required(c, config.commission_requires) for c in checks]


def _required(check: Check, requires: Sequence[str]) -> Check:
    """The check as the cell requires it (``commission_requires`` names its object)."""
    if any(r in check.object.split(" or ") for r in requires):
        return replace(check, required=True)
    return check


def _epos2_sensor_checks(link: AxisLink) -> list[Check]:
    """maxon's 0x2210:02 position sensor type (an incremental encoder: what the cell's qc scaling counts)
    and 0x2210:04 position sensor polarity (0: not inverted; an inverted sensor turns the axis the wrong
    way as 0x607E would, and the EPOS2 has no 0x607E)."""
    kinds = " or ".join(str(k) for k in EPOS2_INCREMENTAL_SENSOR_TYPES)
    sensor = link.read_optional(od.EPOS2_SENSOR_CONFIGURATION, od.EPOS2_SENSOR_TYPE_SUB, "H")
    polarity = link.read_optional(od.EPOS2_SENSOR_CONFIGURATION, od.EPOS2_SENSOR_POLARITY_SUB, "H")
    return [
        Check(
            "0x2210:02",
            "position sensor type",
            f"{kinds} (incremental encoder)",
            ABSENT if sensor is None else str(sensor),
            sensor in EPOS2_INCREMENTAL_SENSOR_TYPES,
            CheckKind.FACT,
        ),
        Check(
            "0x2210:04",
            "position sensor polarity",
            "0x0000 (not inverted)",
            ABSENT if polarity is None else f"0x{polarity:04X}",
            polarity == 0,
            CheckKind.FACT,
        ),
    ]


def _velocity_unit_checks(link: AxisLink) -> list[Check]:
    """The drive's velocity unit (0x608B notation index: 10^index of 0x608C's dimension, rpm) against
    the cell's ``velocity_unit_rpm``: 0x607F and every PVT velocity are written in it."""
    unit = link.config.scaling.velocity_unit_rpm
    notation = link.read_optional(od.VELOCITY_NOTATION_INDEX, 0, "b")
    dimension = link.read_optional(od.VELOCITY_DIMENSION_INDEX, 0, "B")
    return [
        Check(
            "0x608B",
            "velocity notation index",
            f"{math.log10(unit):g} (10^index rpm = the cell's {unit:g} rpm)",
            ABSENT if notation is None else str(notation),
            notation is not None and math.isclose(10.0**notation, unit, rel_tol=1e-9),
            CheckKind.FACT,
        ),
        Check(
            "0x608C",
            "velocity dimension index",
            f"0x{EPOS2_VELOCITY_DIMENSION_RPM:02X} (rpm)",
            ABSENT if dimension is None else f"0x{dimension:02X}",
            dimension == EPOS2_VELOCITY_DIMENSION_RPM,
            CheckKind.FACT,
        ),
    ]


def _encoder_check(link: AxisLink) -> Check:
    expected = f"{link.config.scaling.qc_per_motor_rev:g} qc/rev"
    increments = link.read_optional(od.POSITION_ENCODER_RESOLUTION, 1, "I")
    revolutions = link.read_optional(od.POSITION_ENCODER_RESOLUTION, 2, "I")
    if increments is not None and revolutions:
        qc = increments / revolutions
        found = f"{qc:g} qc/rev ({increments} increments per {revolutions} rev)"
        where = "0x608F:01-02"
    else:
        pulses = link.read_optional(od.EPOS2_SENSOR_CONFIGURATION, 1, "I")
        if pulses is None:
            return Check("0x608F or 0x2210:01", "encoder resolution", expected, ABSENT, False, CheckKind.FACT)
        qc = pulses * od.EPOS2_QC_PER_PULSE
        found = f"{qc:g} qc/rev ({pulses} pulses)"
        where = "0x2210:01"
    ok = abs(qc - link.config.scaling.qc_per_motor_rev) < 0.5
    return Check(where, "encoder resolution", expected, found, ok, CheckKind.FACT)


def drive_settings(link: AxisLink) -> list[Check]:
    """The limit objects as the drive stores them, against what configuration writes."""
    checks = []
    for s in expected_settings(link.config):
        value = link.read_optional(s.index, s.subindex, s.fmt)
        found = ABSENT if value is None else str(value)
        checks.append(Check(s.where, s.name, str(s.value), found, value == s.value, CheckKind.SETTING))
    return checks


def cell_settings_supported(link: AxisLink, profile: Profile) -> list[Check]:
    """The cell's settings that need an object not every drive has, each required: a drive without it
    cannot take the setting, and the cell is refused rather than the setting dropped. The status
    TPDOs' event timer (``bus.status_event_timer_ms``) is 0x1800+n:05 (maxon's EDS has no :05)."""
    checks = []
    timer = link.bus.config.status_event_timer_ms
    for layout in profile.tpdos:
        if with_rates(layout, link.bus.config).event_timer_ms:
            comm = od.pdo_communication_index(layout.number, receive=False)
            value = link.read_optional(comm, 5, "H")
            checks.append(
                Check(
                    f"0x{comm:04X}:05",
                    f"TPDO{layout.number} event timer (the cell's status_event_timer_ms)",
                    f"{timer} ms can be written",
                    ABSENT if value is None else f"present ({value} ms)",
                    True,
                    CheckKind.SETTING,
                    required=True,
                )
            )
    return checks


def drive_info(link: AxisLink, profile: Profile) -> list[Check]:
    """Heartbeat settings, the PDOs pvtflow uses as mapped on the drive, the error history."""
    checks = []
    bus = link.bus.config
    producer = link.read_optional(od.PRODUCER_HEARTBEAT_TIME, 0, "H")
    checks.append(
        Check(
            "0x1017",
            "producer heartbeat",
            f"{bus.heartbeat_ms} ms (written at configuration)",
            ABSENT if producer is None else f"{producer} ms",
            True,
            CheckKind.INFO,
        )
    )
    consumer = link.read_optional(od.CONSUMER_HEARTBEAT_TIME, 1, "I")
    watched = (
        ABSENT
        if consumer is None
        else ("off" if not consumer & 0xFFFF else f"node {consumer >> 16 & 0xFF}, {consumer & 0xFFFF} ms")
    )
    checks.append(
        Check(
            "0x1016:01",
            "consumer heartbeat",
            f"node {bus.master_node_id}, {bus.master_consumer_time_ms} ms (written at configuration)",
            watched,
            True,
            CheckKind.INFO,
        )
    )
    for layouts, receive in ((profile.rpdos, True), (profile.tpdos, False)):
        for layout in layouts:  # the status TPDOs at the cell's rates, as configuration writes them
            checks.append(_pdo_info(link, layout if receive else with_rates(layout, link.bus.config), receive))
    checks.append(_error_history(link))
    return checks


def describe_pdo(link: AxisLink, number: int, receive: bool) -> str:
    """One PDO as the drive maps it: COB-ID, valid, transmission type, mapped objects."""
    comm = od.pdo_communication_index(number, receive)
    mapping = od.pdo_mapping_index(number, receive)
    cob = link.read_optional(comm, 1, "I")
    if cob is None:
        return ABSENT
    ttype = link.read_optional(comm, 2, "B")
    count = link.read_optional(mapping, 0, "B") or 0
    entries = [link.read(mapping, k, "I") for k in range(1, count + 1)]
    mapped = ", ".join(f"0x{e >> 16:04X}:{e >> 8 & 0xFF:02X}/{e & 0xFF}" for e in entries) or "nothing"
    valid = "invalid" if cob & od.PDO_INVALID else "valid"
    return f"0x{cob & 0x7FF:03X} {valid}, type {ttype}: {mapped}"


def _pdo_info(link: AxisLink, layout: PdoLayout, receive: bool) -> Check:
    kind = "RPDO" if receive else "TPDO"
    entries = ", ".join(f"0x{i:04X}:{s:02X}/{b}" for i, s, b in layout.entries)
    cob = layout.cob_id(link.node_id, receive)
    expected = f"0x{cob:03X} valid, type {layout.transmission_type}: {entries} (mapped at configuration)"
    comm = od.pdo_communication_index(layout.number, receive)
    found = describe_pdo(link, layout.number, receive)
    return Check(f"0x{comm:04X}", f"{kind}{layout.number}", expected, found, True, CheckKind.INFO)


def _error_history(link: AxisLink) -> Check:
    count = link.read_optional(od.ERROR_HISTORY, 0, "B")
    if count is None:
        found = ABSENT
    elif count == 0:
        found = "empty"
    else:
        codes = [link.read_optional(od.ERROR_HISTORY, k, "I") for k in range(1, count + 1)]
        found = ", ".join("?" if c is None else f"0x{c & 0xFFFF:04X}" for c in codes)
    return Check("0x1003", "error history", "(the drive's own)", found, True, CheckKind.INFO)


def commission_axis(link: AxisLink, profile: Profile) -> AxisCommission:
    """Every check of one drive; a drive that does not answer is one mismatch that says so."""
    report = AxisCommission(link.joint, link.node_id, link.config.profile)
    try:
        report.checks = (
            drive_facts(link)
            + cell_settings_supported(link, profile)
            + drive_settings(link)
            + drive_info(link, profile)
        )
    except DriveError as exc:
        report.checks.append(Check("SDO", "answer", "an SDO answer", exc.detail, False, CheckKind.FACT))
    return report


def commission(links: Sequence[AxisLink], profiles: Sequence[Profile]) -> CommissionReport:
    """Read every drive of a cell and compare it with the cell (nothing is written)."""
    before = sum(link.sdo_transfers for link in links)
    axes = [commission_axis(link, profile) for link, profile in zip(links, profiles, strict=True)]
    return CommissionReport(axes, sum(link.sdo_transfers for link in links) - before)


def refuse_on_facts(links: Sequence[AxisLink], profiles: Sequence[Profile]) -> None:
    """Configuration's first step: every drive's FACT checks and the cell settings it must be able to
    take; DriveError naming the first drive that is not what the cell expects, with each of its
    mismatches and each required check it cannot answer (nothing written to any drive)."""
    for link, profile in zip(links, profiles, strict=True):
        wrong = [c for c in drive_facts(link) + cell_settings_supported(link, profile) if c.fails]
        if wrong:
            raise DriveError(
                link.node_id,
                f"axis {link.joint} is not the drive the cell expects: " + "; ".join(str(c) for c in wrong),
            )
