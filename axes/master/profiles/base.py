"""Profile: what one drive behaviour adds to an ``AxisLink``, and the settings every profile writes.

The base class holds what the behaviours share (the master-loss supervision, the stop options, the
limit settings written and read back, the start/halt/end controlwords); one module per profile
(``axes.master.profiles``) sets its PDOs and implements its configuration and feed.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import (
    CONTROLWORD_ENABLE_OPERATION,
    CONTROLWORD_HALT,
    CONTROLWORD_SHUTDOWN,
    CONTROLWORD_START_IP,
    PowerState,
)
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.objects import PdoLayout
from pvtflow.axes.master.bus.sync import DEFAULT_MAX_GAP_PERIODS
from pvtflow.axes.master.link import DriveError
from pvtflow.axes.master.tpdo_rates import answer_every, with_rates

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from pvtflow.axes.drive.program import AxisProgram
    from pvtflow.axes.master.group.feeder import Feeder, RecordAllowance, SetpointFeeder
    from pvtflow.axes.master.link import AxisLink

DEFAULT_MAX_FOLLOWING_ERROR_QC = 2000  # app note Table 17 default for 0x6065


@dataclass(frozen=True)
class Setting:
    """One object pvtflow writes from the axis at configuration (and reads back)."""

    index: int
    subindex: int
    fmt: str
    value: int
    name: str

    @property
    def where(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X}"


def expected_settings(config: AxisConfig) -> list[Setting]:
    """The drive's limit objects in its units from the axis: 0x607F (velocity units), 0x60C5 (rpm/s),
    0x607D:01/:02 (qc), 0x6065 (qc: maxon's default, the cell has no setting of its own), 0x6085
    (rpm/s, the quick stop ramp = 0x60C5). One list:
    configuration writes it (``Profile.write_settings``), commissioning compares it (axes/master/commission.py)."""
    lim = config.limits
    unit = config.scaling.velocity_unit_rpm
    return [
        Setting(od.MAX_PROFILE_VELOCITY, 0, "I", round(lim.max_profile_velocity_rpm / unit), "max profile velocity"),
        Setting(od.MAX_ACCELERATION, 0, "I", lim.braking_rpm_s, "max acceleration"),
        Setting(od.SOFTWARE_POSITION_LIMIT, 1, "i", lim.min_position_qc, "min position limit"),
        Setting(od.SOFTWARE_POSITION_LIMIT, 2, "i", lim.max_position_qc, "max position limit"),
        Setting(od.MAX_FOLLOWING_ERROR, 0, "I", DEFAULT_MAX_FOLLOWING_ERROR_QC, "max following error"),
        # the quick stop ramp (0x6007 = 3 on a lost master, 0x605A = 2) brakes as hard as the axis may
        Setting(od.QUICK_STOP_DECELERATION, 0, "I", lim.braking_rpm_s, "quick stop deceleration"),
    ]


class Profile:
    """One drive behaviour. Subclasses set the class attributes and implement configure/feeder."""

    name: ClassVar[DriveProfile]
    rpdos: ClassVar[tuple[PdoLayout, ...]]
    tpdos: ClassVar[tuple[PdoLayout, ...]]
    sync_tpdo: ClassVar[int]  # the synchronous TPDO that answers SYNC (every n-th: bus.status_every_syncs)
    # 0x6007 when the master's heartbeat stops: quick stop, braking on the quick stop ramp (0x6085 =
    # the drive's 0x60C5) rather than coasting (2, disable voltage); EMCY 0x8130 tells who is listening
    abort_connection_option: ClassVar[od.AbortConnectionOption] = od.AbortConnectionOption.QUICK_STOP
    # 0x605E, where a lost master is one of the drive's own errors (the EPOS2): its fault reaction brakes
    fault_reaction_on_master_loss: ClassVar[od.FaultReaction | None] = None
    homing_methods: ClassVar[frozenset[int]] = frozenset()  # 0x6098 values it homes with (none: no mode 6)
    home_position_object: ClassVar[int] = od.HOME_OFFSET  # what 0x6064 reads at the home (maxon: 0x2081)

    def __init__(self, link: AxisLink) -> None:
        self.link = link
        self.config = link.config

    @property
    def fixed_period(self) -> bool:
        """One setpoint per SYNC, sent right after the SYNC before it (``DriveProfile.fixed_period``)."""
        return self.name.fixed_period

    @property
    def sync_answer_cob_id(self) -> int:
        return od.pdo_cob_id(self.sync_tpdo, self.link.node_id, receive=False)

    @property
    def sync_answer_every(self) -> int:
        """The SYNCs one answer of the synchronous status TPDO stands for (its type n at the cell's rate)."""
        layout = next(t for t in self.tpdos if t.number == self.sync_tpdo)
        return answer_every(with_rates(layout, self.link.bus.config))

    @property
    def delay_periods(self) -> int:
        """SYNC periods from the SYNC that validates a setpoint to the one where it is reached
        (fixed-period profiles; 0 for the buffered EPOS2, which runs on the records' own times)."""
        return 0

    @property
    def ramps_by_itself(self) -> bool:
        """The drive brakes on its own ramp when halted (bit 8, 0x605D on 0x6084); False: it has none,
        and the master brakes it with setpoints (``axes.drive.stop_ramp``)."""
        return True

    @property
    def lead_periods(self) -> int:
        """How far ahead of the program's timeline the master sends: the drive's delay, less the part
        the program's reconstruction (axes.drive.interpolation) already contains."""
        return self.delay_periods

    def max_sync_gap_ms(self, program: AxisProgram) -> float:
        """The longest time between two SYNCs this drive rides out while it runs ``program``: two
        periods for a drive that takes a setpoint per SYNC (one SYNC skipped, ``axes.master.bus.sync``: it holds one
        period, no more)."""
        return DEFAULT_MAX_GAP_PERIODS * self.link.bus.config.sync_period_ms

    def configure(self) -> None:
        """The SDO configuration sequence (node in PRE-OPERATIONAL)."""
        raise NotImplementedError

    def enable(self, fresh: bool = False) -> None:
        """From any state to OPERATION ENABLED, then whatever the mode needs before records
        (``fresh``: the link's statusword was read just now, see ``AxisLink.reach``)."""
        self.enable_operation(fresh)

    def enable_operation(self, fresh: bool = False) -> None:
        """OPERATION ENABLED with bits 4 and 8 low (0x000F), so that the start word is a rising bit 4."""
        self.link.reach(PowerState.OPERATION_ENABLED, fresh=fresh)
        self.link.write_controlword(self.end_controlword())

    def feeder(self, program: AxisProgram, allowance: RecordAllowance | None = None) -> Feeder:
        """The axis's feeder for ``program`` (``allowance``: the cell's records per SYNC period, for
        buffered drives)."""
        raise NotImplementedError

    def stop_records(self, feeder: SetpointFeeder, quick: bool) -> NDArray[np.int64]:
        """The master's braking records for a drive that has no ramp of its own (``ramps_by_itself``
        False; ``quick``: a halt on a fault, within 0x6085 as well)."""
        raise NotImplementedError(f"{self.name} brakes on its own ramp")

    def clear_buffer(self) -> None:
        """Empty the drive's setpoint buffer in any power state (after a fault: nothing of the
        interrupted run may be left for the next one). Bufferless drives have nothing to clear."""

    def start_controlword(self) -> int:
        return CONTROLWORD_START_IP

    def halt_controlword(self) -> int:
        return CONTROLWORD_HALT

    def end_controlword(self) -> int:
        """After the end: ip mode off, operation still enabled (0x000F)."""
        return int(CONTROLWORD_ENABLE_OPERATION)

    def write_settings(self) -> None:
        """0x607F, 0x60C5, 0x607D, 0x6065 and 0x6085 from the axis (``expected_settings``) on every drive that
        has them, each read back: a drive that holds another value than the one written is refused
        (DriveError), so the limits the planner times against are the ones the drive enforces."""
        link = self.link
        for s in expected_settings(self.config):
            if not link.write_optional(s.index, s.subindex, s.value, s.fmt):
                continue  # the drive has no such object (abort 0x0602 / 0x0609)
            back = link.read(s.index, s.subindex, s.fmt)
            if back != s.value:
                raise DriveError(link.node_id, f"{s.where} ({s.name}) reads back {back} after writing {s.value}")

    def write_profile_motion(self) -> None:
        """0x6081/0x6083 in drive units (the drive's warning levels; 0x6084 is a stop option)."""
        lim = self.config.limits
        unit = self.config.scaling.velocity_unit_rpm
        link = self.link
        profile_velocity = lim.profile_velocity_rpm or lim.max_profile_velocity_rpm
        profile_acceleration = lim.profile_acceleration_rpm_s or lim.max_acceleration_rpm_s
        link.write(od.PROFILE_VELOCITY, 0, round(profile_velocity / unit), "I")
        link.write(od.PROFILE_ACCELERATION, 0, round(profile_acceleration), "I")

    def write_homing(self) -> None:
        """The axis's homing settings (0x6098, 0x6099:01/02, 0x609A, the home position as the drive
        defines it: 0x607C, or maxon's 0x2081 with 0x607C = 0; maxon's 0x2080), in drive
        units; nothing for an axis without homing. A method the profile does not have is refused."""
        homing = self.config.homing
        if homing is None:
            return
        if homing.method not in self.homing_methods:
            have = ", ".join(str(m) for m in sorted(self.homing_methods)) or "none: no homing mode"
            raise DriveError(self.link.node_id, f"homing method {homing.method} is not one of {self.name}'s ({have})")
        unit = self.config.scaling.velocity_unit_rpm
        link = self.link
        link.write(od.HOMING_METHOD, 0, homing.method, "b")
        link.write(od.HOMING_SPEEDS, 1, round(homing.switch_speed_rpm / unit), "I")
        link.write(od.HOMING_SPEEDS, 2, round(homing.zero_speed_rpm / unit), "I")
        link.write(od.HOMING_ACCELERATION, 0, round(homing.acceleration_rpm_s), "I")
        if self.home_position_object == od.HOME_OFFSET:
            link.write(od.HOME_OFFSET, 0, homing.offset_qc, "i")
        else:  # maxon: 0x2081 is what the position reads at home, 0x607C a move past the reference (none)
            link.write(self.home_position_object, 0, homing.offset_qc, "i")
            link.write(od.HOME_OFFSET, 0, 0, "i")
        if homing.current_threshold_ma is not None:
            link.write(od.EPOS2_HOMING_CURRENT_THRESHOLD, 0, homing.current_threshold_ma, "H")

    def write_heartbeat(self) -> None:
        self.link.write(od.PRODUCER_HEARTBEAT_TIME, 0, self.link.bus.config.heartbeat_ms, "H")

    def supervise_master(self) -> None:
        """Make the drive stop by itself when the master is lost: 0x1016:01 watches the master's
        heartbeat (node id, consumer time), 0x6007 says what to do when it stops (and 0x605E, for a
        drive that takes the loss as a fault of its own), 0x6085 (where the drive has it) is the
        quick stop ramp its reaction brakes on (the drive's 0x60C5). All but 0x6085 are read back; a
        drive that does not take them is refused, naming node and object: it would go on moving
        without a master."""
        bus = self.link.bus.config
        entry = (bus.master_node_id << od.CONSUMER_NODE_SHIFT) | bus.master_consumer_time_ms
        self._release_other_entries(bus.master_node_id)
        what = f"watching the master's heartbeat (node {bus.master_node_id}, {bus.master_consumer_time_ms} ms)"
        self._write_read_back(od.CONSUMER_HEARTBEAT_TIME, 1, entry, "I", f"consumer heartbeat time, {what}")
        option = self.abort_connection_option
        self._write_read_back(
            od.ABORT_CONNECTION_OPTION_CODE, 0, int(option), "h", f"abort connection option code {option.name.lower()}"
        )
        reaction = self.fault_reaction_on_master_loss
        if reaction is not None:
            what = f"fault reaction option code {reaction.name.lower()}"
            self._write_read_back(od.FAULT_REACTION_OPTION_CODE, 0, int(reaction), "h", what)
        self.write_stop_options()

    def write_stop_options(self) -> None:
        """How the drive stops by itself, where it has the objects (each read back): 0x605A = 2, a
        quick stop brakes on 0x6085, then SWITCH ON DISABLED (what 0x6007 = 3 relies on; a vendor tool
        may have left 0 = power stage off, coasting), 0x605D = 1, a halt brakes on 0x6084, and, on a
        drive that ramps by itself, 0x6084 = 0x60C5: a halt brakes as hard as the axis may, never on
        a deceleration a vendor tool left (steeper than 0x60C5, or so gentle the axis overruns)."""
        settings = [
            (od.QUICK_STOP_OPTION_CODE, od.QUICK_STOP_ON_QUICK_STOP_RAMP, "h", "quick stop option code"),
            (od.HALT_OPTION_CODE, od.HALT_ON_PROFILE_DECELERATION, "h", "halt option code"),
        ]
        if self.ramps_by_itself:
            braking = self.config.limits.braking_rpm_s
            settings.append((od.PROFILE_DECELERATION, braking, "I", "profile deceleration, the halt's ramp"))
        for index, value, fmt, what in settings:
            if self.link.write_optional(index, 0, value, fmt):
                back = self.link.read(index, 0, fmt)
                if back != value:
                    raise DriveError(
                        self.link.node_id, f"0x{index:04X} ({what}) reads back {back} after writing {value}"
                    )

    def release_master(self) -> None:
        """A master that closes at rest says goodbye: the shutdown controlword first (0x0006: READY TO
        SWITCH ON, power stage off, as CiA 402 leaves a drive nobody commands), then 0x1016:01 off, so
        that the drive does not take an orderly close for a lost master (which would quick stop it,
        and fault an EPOS2 the next master would have to recover). In that order a drive is never
        enabled without a master watched. A master that dies or hangs says nothing: the drive
        stops. Best effort: a drive that does not answer is left as it is, watching."""
        with contextlib.suppress(DriveError):
            self.link.write_controlword(CONTROLWORD_SHUTDOWN)
            self.link.write(od.CONSUMER_HEARTBEAT_TIME, 1, 0, "I")

    def _release_other_entries(self, node_id: int) -> None:
        """CiA 301 refuses a second 0x1016 entry for one node (abort 0x06040043): an entry past :01
        that already watches the master's node id (an earlier commissioning) is switched off."""
        try:
            count = self.link.read(od.CONSUMER_HEARTBEAT_TIME, 0, "B")
        except DriveError:
            return  # no 0x1016 at all: the write of :01 says so
        for sub in range(2, count + 1):
            value = self.link.read(od.CONSUMER_HEARTBEAT_TIME, sub, "I")
            if (value >> od.CONSUMER_NODE_SHIFT) & 0xFF == node_id and value & 0xFFFF:
                self.link.write(od.CONSUMER_HEARTBEAT_TIME, sub, 0, "I")

    def _write_read_back(self, index: int, subindex: int, value: int, fmt: str, what: str) -> None:
        where = f"0x{index:04X}:{subindex:02X}"
        why = "without it the drive goes on moving when the master is lost"
        try:
            self.link.write(index, subindex, value, fmt)
            back = self.link.read(index, subindex, fmt)
        except DriveError as exc:
            raise DriveError(self.link.node_id, f"{where} ({what}) not accepted: {exc.detail}; {why}") from None
        if back != value:
            raise DriveError(
                self.link.node_id, f"{where} ({what}) reads back 0x{back:X} after writing 0x{value:X}; {why}"
            )
