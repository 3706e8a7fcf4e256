"""Drive behaviours: one module per profile, each with its configuration, its feed, its delay, its end.

``AxisLink`` is the master's handle on one drive (SDO access by index, controlword, the values its
TPDOs bring); ``Profile`` is what a behaviour adds to it. ``profile_for(link)`` picks the module
from ``AxisConfig.profile``.
"""

from __future__ import annotations

import contextlib
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from axes import objects as od
from axes.cia402 import (
    CONTROLWORD_FAULT_RESET,
    CONTROLWORD_SHUTDOWN,
    Controlword,
    PowerState,
    PowerStateMachine,
    decode_state,
)
from axes.config import AxisConfig
from axes.drive_profile import DriveProfile
from axes.objects import BufferStatus, PdoLayout
from axes.subscriptions import subscribe, unsubscribe
from axes.sync import DEFAULT_MAX_GAP_PERIODS
from axes.tpdo_rates import answer_every, with_rates

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from axes.bus import CellBus
    from axes.feeder import Feeder, RecordAllowance, SetpointFeeder
    from axes.program import AxisProgram

DEFAULT_MAX_FOLLOWING_ERROR_QC = 2000  # app note Table 17 default for 0x6065
PDO_INVALID = 0x8000_0000  # COB-ID bit 31: the PDO does not exist
PDO_RTR_BIT = 0x4000_0000  # COB-ID bit 30: no RTR allowed on this PDO
PDO_COB_ID_BITS = 0x3FFF_FFFF  # bits 0-29: the identifier and its frame format


class DriveError(RuntimeError):
    """A drive did not accept its configuration or a state change (node, object, what happened)."""

    def __init__(self, node_id: int, message: str) -> None:
        self.node_id = node_id
        self.detail = message  # the message without the node
        super().__init__(f"node {node_id}: {message}")


# Signedness and size of the objects pvtflow maps into PDOs (decode by the layouts of axes.objects).
_PDO_FORMATS: dict[tuple[int, int], str] = {
    (od.STATUSWORD, 0): "H",
    (od.CONTROLWORD, 0): "H",
    (od.POSITION_ACTUAL_VALUE, 0): "i",
    (od.POSITION_ACTUAL_INTERNAL_VALUE, 0): "i",
    (od.POSITION_DEMAND_VALUE, 0): "i",
    (od.EPOS2_INTERPOLATION_BUFFER, 1): "H",
    (od.INTERPOLATION_DATA_RECORD, 1): "i",
    (od.INTERPOLATION_DATA_RECORD, 2): "i",
    (od.INTERPOLATION_DATA_RECORD, 3): "i",
    (od.EPOS2_INTERPOLATION_DATA_RECORD, 0): "Q",
    (od.HIGH_RESOLUTION_TIME_STAMP, 0): "I",
}


# a TPDO's position: 0x6064, or 0x6063 where the factor group is not active (the Parker in IP mode)
_POSITION_KEYS = frozenset({(od.POSITION_ACTUAL_VALUE, 0), (od.POSITION_ACTUAL_INTERNAL_VALUE, 0)})


def pdo_struct(layout: PdoLayout) -> struct.Struct:
    """The little-endian struct of one PDO's data bytes, from its layout."""
    return struct.Struct("<" + "".join(_PDO_FORMATS[(i, s)] for i, s, _ in layout.entries))


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
    0x607D:01/:02 (qc), 0x6065 (qc: maxon's default, the cell has no setting of its own). One list:
    configuration writes it (``Profile.write_settings``), commissioning compares it (axes/commission.py)."""
    lim = config.limits
    unit = config.scaling.velocity_unit_rpm
    return [
        Setting(od.MAX_PROFILE_VELOCITY, 0, "I", round(lim.max_profile_velocity_rpm / unit), "max profile velocity"),
        Setting(od.MAX_ACCELERATION, 0, "I", round(lim.max_acceleration_rpm_s), "max acceleration"),
        Setting(od.SOFTWARE_POSITION_LIMIT, 1, "i", lim.min_position_qc, "min position limit"),
        Setting(od.SOFTWARE_POSITION_LIMIT, 2, "i", lim.max_position_qc, "max position limit"),
        Setting(od.MAX_FOLLOWING_ERROR, 0, "I", DEFAULT_MAX_FOLLOWING_ERROR_QC, "max following error"),
    ]


class AxisLink:
    """The master's view of one drive: SDO by index, controlword out, statusword/position/buffer in."""

    def __init__(self, bus: CellBus, config: AxisConfig) -> None:
        self.bus = bus
        self.config = config
        self.node_id = config.node_id
        self.node: canopen.RemoteNode = bus.add_node(config.node_id)
        self.psm = PowerStateMachine()
        self.statusword = 0
        self.position: int | None = None
        self.status_sync = 0  # the SYNC count when the last status TPDO arrived: what its values are as of
        self.buffer_status = 0
        self.last_emcy: tuple[int, str] | None = None
        self.updated = threading.Condition()
        self.status_listeners: list[Callable[[AxisLink], None]] = []
        self.controlwords_sent = 0  # every controlword the master sends, by SDO or RPDO, counts
        self.sdo_transfers = 0  # SDO requests the master made of this drive (each one round trip)
        self._subscribed: list[tuple[int, Callable[..., None]]] = []
        self._sdo = threading.Lock()  # one SDO transfer at a time: the node has one SDO server channel

    @property
    def joint(self) -> str:
        return self.config.joint

    @property
    def state(self) -> PowerState:
        return decode_state(self.statusword)

    # --- SDO -------------------------------------------------------------------------------------
    def write(self, index: int, subindex: int, value: int, fmt: str) -> None:
        """Expedited SDO download of one value packed as ``fmt`` (struct code: B, H, I, b, h, i)."""
        if not self._download(index, subindex, value, fmt, optional=False):
            raise AssertionError("unreachable")

    def write_optional(self, index: int, subindex: int, value: int, fmt: str) -> bool:
        """An SDO write the drive may not have the object for (abort 0x0602xxxx / 0x0609xxxx): False then."""
        return self._download(index, subindex, value, fmt, optional=True)

    def _download(self, index: int, subindex: int, value: int, fmt: str, optional: bool) -> bool:
        where = f"0x{index:04X}:{subindex:02X}"
        self.sdo_transfers += 1
        try:
            with self._sdo:
                self.node.sdo.download(index, subindex, struct.pack("<" + fmt, value))
        except SdoAbortedError as exc:
            if optional and exc.code >> 16 in (0x0602, 0x0609):
                return False
            raise DriveError(self.node_id, f"SDO write {where} = {value} failed: {exc}") from None
        except (SdoCommunicationError, struct.error) as exc:
            raise DriveError(self.node_id, f"SDO write {where} = {value} failed: {exc}") from None
        return True

    def read(self, index: int, subindex: int, fmt: str) -> int:
        self.sdo_transfers += 1
        try:
            with self._sdo:
                data = self.node.sdo.upload(index, subindex)
            return struct.unpack_from("<" + fmt, data.ljust(struct.calcsize(fmt), b"\0"))[0]
        except (SdoAbortedError, SdoCommunicationError, struct.error) as exc:
            raise DriveError(self.node_id, f"SDO read 0x{index:04X}:{subindex:02X} failed: {exc}") from None

    def read_optional(self, index: int, subindex: int, fmt: str) -> int | None:
        """An SDO read of an object the drive may not have (abort 0x0602xxxx / 0x0609xxxx): None then."""
        self.sdo_transfers += 1
        try:
            with self._sdo:
                data = self.node.sdo.upload(index, subindex)
            return struct.unpack_from("<" + fmt, data.ljust(struct.calcsize(fmt), b"\0"))[0]
        except SdoAbortedError as exc:
            if exc.code >> 16 in (0x0602, 0x0609):
                return None
            raise DriveError(self.node_id, f"SDO read 0x{index:04X}:{subindex:02X} failed: {exc}") from None
        except (SdoCommunicationError, struct.error) as exc:
            raise DriveError(self.node_id, f"SDO read 0x{index:04X}:{subindex:02X} failed: {exc}") from None

    def read_statusword(self) -> int:
        self._set_statusword(self.read(od.STATUSWORD, 0, "H"))
        return self.statusword

    # --- PDO configuration (CiA 301 7.5.2.35-38) ----------------------------------------------------
    def map_pdo(self, layout: PdoLayout, receive: bool, cob_id: int | None = None) -> None:
        """Configure one PDO as CiA 301 says, in the order a strict stack accepts: invalidate it with
        the COB-ID it has (bits 0-29 may not change while it is valid), move the COB-ID while it is
        invalid, clear the mapping count, map, set the count, write the transmission type and, for a
        TPDO, the inhibit time and event timer (0: none; an event TPDO sends on a change only), then
        validate; bit 30 (RTR) stays as the drive has it. The result is read back: a drive that
        holds anything else is refused (DriveError naming the PDO)."""
        comm = (0x1400 if receive else 0x1800) + layout.number - 1
        mapping = (0x1600 if receive else 0x1A00) + layout.number - 1
        cob = layout.cob_id(self.node_id, receive) if cob_id is None else cob_id
        stored = self.read(comm, 1, "I")
        rtr = stored & PDO_RTR_BIT
        if not stored & PDO_INVALID:
            self.write(comm, 1, stored | PDO_INVALID, "I")
        if stored & PDO_COB_ID_BITS != cob:
            self.write(comm, 1, rtr | PDO_INVALID | cob, "I")
        self.write(mapping, 0, 0, "B")
        for k, (index, subindex, bits) in enumerate(layout.entries, start=1):
            self.write(mapping, k, (index << 16) | (subindex << 8) | bits, "I")
        self.write(mapping, 0, len(layout.entries), "B")
        self.write(comm, 2, layout.transmission_type, "B")
        if not receive:  # 0x1800:03 in 100 us, :05 in ms; a drive without :03 / :05 has neither to set
            inhibit = round(layout.inhibit_periods * self.bus.config.sync_period_ms * 10)
            self.write_optional(comm, 3, min(inhibit, 0xFFFF), "H")
            self.write_optional(comm, 5, layout.event_timer_ms, "H")
            self.write_optional(comm, 6, 0, "B")  # SYNC start value: 0, pvtflow's SYNC has no counter (SYNC_COB_ID)
        self.write(comm, 1, rtr | cob, "I")
        self._check_pdo(layout, receive, rtr | cob)

    def _check_pdo(self, layout: PdoLayout, receive: bool, cob: int) -> None:
        """The PDO as the drive holds it now against what was written: COB-ID, type, mapping."""
        comm = (0x1400 if receive else 0x1800) + layout.number - 1
        mapping = (0x1600 if receive else 0x1A00) + layout.number - 1
        count = self.read(mapping, 0, "B")
        found = (
            self.read(comm, 1, "I"),
            self.read(comm, 2, "B"),
            tuple(self.read(mapping, k, "I") for k in range(1, count + 1)),
        )
        entries = tuple((index << 16) | (subindex << 8) | bits for index, subindex, bits in layout.entries)
        wanted = (cob, layout.transmission_type, entries)
        if found != wanted:
            name = f"{'R' if receive else 'T'}PDO{layout.number}"

            def text(v: tuple[int, int, tuple[int, ...]]) -> str:
                return f"COB-ID 0x{v[0]:08X} type {v[1]} mapping [{', '.join(f'0x{e:08X}' for e in v[2])}]"

            raise DriveError(self.node_id, f"{name} reads back {text(found)} after writing {text(wanted)}")

    def disable_pdo(self, number: int, receive: bool) -> None:
        """Invalidate a PDO pvtflow does not use, with the COB-ID it has (skipped where the drive has
        no such PDO or it is invalid already): what an earlier setup left mapped sends nothing."""
        comm = (0x1400 if receive else 0x1800) + number - 1
        cob = self.read_optional(comm, 1, "I")
        if cob is not None and not cob & PDO_INVALID:
            self.write(comm, 1, cob | PDO_INVALID, "I")

    def map_pdos(
        self, rpdos: tuple[PdoLayout, ...], tpdos: tuple[PdoLayout, ...], rpdo_cob_ids: dict[int, int] | None = None
    ) -> None:
        """Map pvtflow's PDOs and invalidate the others (``rpdo_cob_ids``: RPDO number -> shared COB-ID);
        the status TPDOs at the cell's rates (``axes.tpdo_rates``)."""
        cobs = rpdo_cob_ids or {}
        used_r = {p.number for p in rpdos}
        used_t = {p.number for p in tpdos}
        for n in range(1, 5):
            if n not in used_r:
                self.disable_pdo(n, True)
            if n not in used_t:
                self.disable_pdo(n, False)
        for p in rpdos:
            self.map_pdo(p, True, cobs.get(p.number))
        for p in tpdos:
            self.map_pdo(with_rates(p, self.bus.config), False)

    def subscribe_tpdos(self, tpdos: tuple[PdoLayout, ...]) -> None:
        self.unsubscribe()
        for layout in tpdos:
            cob = layout.cob_id(self.node_id, receive=False)
            cb = self._decoder(layout)
            subscribe(self.bus.network, cob, cb)
            self._subscribed.append((cob, cb))

    def unsubscribe(self) -> None:
        for cob, cb in self._subscribed:
            unsubscribe(self.bus.network, cob, cb)
        self._subscribed.clear()

    def _decoder(self, layout: PdoLayout) -> Callable[[int, bytearray, float], None]:
        fmt = pdo_struct(layout)
        keys = [(i, s) for i, s, _ in layout.entries]

        def on_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < fmt.size:
                return
            self.status_sync = self.bus.sync.count
            for key, value in zip(keys, fmt.unpack_from(data), strict=True):
                if key == (od.STATUSWORD, 0):
                    self._set_statusword(value)
                elif key in _POSITION_KEYS:
                    self.position = value
                elif key == (od.EPOS2_INTERPOLATION_BUFFER, 1):
                    self.buffer_status = value
            for cb in list(self.status_listeners):
                cb(self)

        return on_tpdo

    def _set_statusword(self, value: int) -> None:
        self.statusword = value
        self.psm.update(value)

    # --- controlword -----------------------------------------------------------------------------
    def controlword_cob_id(self) -> int:
        """The synchronous RPDO that carries the controlword (RPDO2 in every pvtflow layout)."""
        return 0x300 + self.node_id

    def send_controlword(self, controlword: int) -> None:
        """Through the synchronous RPDO: takes effect at the next SYNC."""
        self.bus.network.send_message(self.controlword_cob_id(), struct.pack("<H", controlword))
        self.psm.sent(controlword)
        self.controlwords_sent += 1

    def write_controlword(self, controlword: int) -> None:
        """By SDO: takes effect at once (configuration, enable, recovery)."""
        self.write(od.CONTROLWORD, 0, controlword, "H")
        self.psm.sent(controlword)
        self.controlwords_sent += 1

    def reach(self, target: PowerState, timeout_s: float = 2.0, fresh: bool = False) -> PowerState:
        """Walk the power state machine to ``target`` by SDO (fault reset on a rising bit 7 included).

        Each step is confirmed by reading the statusword back; the timeout only detects a drive
        that does not move. ``fresh``: ``statusword`` was read just now (a start's check), so the
        first reading is that one, not another SDO round trip.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            state = decode_state(self.statusword if fresh else self.read_statusword())
            fresh = False
            if state == target:
                return state
            words = self.psm.step(self.statusword, target)
            if state == PowerState.FAULT and not words:
                words = [CONTROLWORD_FAULT_RESET]
            for word in words:
                self.write_controlword(word)
            if time.monotonic() > deadline:
                raise DriveError(
                    self.node_id,
                    f"did not reach {target.value} (state {state.value}, statusword 0x{self.statusword:04X})",
                )
            if not words:
                time.sleep(0.001)  # a transition the drive makes by itself (fault reaction, boot)

    def describe_buffer(self) -> str:
        names = [f.name.lower() for f in BufferStatus if f & self.buffer_status and f.name]
        return ", ".join(names) if names else "none"


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
        return 0x80 + 0x100 * self.sync_tpdo + self.link.node_id

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
        and the master brakes it with setpoints (``axes.stop_ramp``)."""
        return True

    @property
    def lead_periods(self) -> int:
        """How far ahead of the program's timeline the master sends: the drive's delay, less the part
        the program's reconstruction (axes.interpolation) already contains."""
        return self.delay_periods

    def max_sync_gap_ms(self, program: AxisProgram) -> float:
        """The longest time between two SYNCs this drive rides out while it runs ``program``: two
        periods for a drive that takes a setpoint per SYNC (one SYNC skipped, ``axes.sync``: it holds one
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
        return int(
            Controlword.ENABLE_OPERATION
            | Controlword.ENABLE_IP_MODE
            | Controlword.ENABLE_VOLTAGE
            | Controlword.QUICK_STOP
            | Controlword.SWITCH_ON
        )

    def halt_controlword(self) -> int:
        return self.start_controlword() | int(Controlword.HALT)

    def end_controlword(self) -> int:
        """After the end: ip mode off, operation still enabled (0x000F)."""
        return self.start_controlword() & ~int(Controlword.ENABLE_IP_MODE)

    def write_settings(self) -> None:
        """0x607F, 0x60C5, 0x607D and 0x6065 from the axis (``expected_settings``) on every drive that
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
        """0x6081/0x6083/0x6084 in drive units (a drive that ramps by itself: warning levels, braking)."""
        lim = self.config.limits
        unit = self.config.scaling.velocity_unit_rpm
        link = self.link
        profile_velocity = lim.profile_velocity_rpm or lim.max_profile_velocity_rpm
        profile_acceleration = lim.profile_acceleration_rpm_s or lim.max_acceleration_rpm_s
        link.write(od.PROFILE_VELOCITY, 0, round(profile_velocity / unit), "I")
        link.write(od.PROFILE_ACCELERATION, 0, round(profile_acceleration), "I")
        link.write(od.QUICK_STOP_DECELERATION, 0, round(lim.max_acceleration_rpm_s), "I")

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
        self.link.write_optional(
            od.QUICK_STOP_DECELERATION_CIA402, 0, round(self.config.limits.max_acceleration_rpm_s), "I"
        )
        self.write_stop_options()

    def write_stop_options(self) -> None:
        """How the drive stops by itself, where it has the objects (each read back): 0x605A = 2, a
        quick stop brakes on 0x6085, then SWITCH ON DISABLED (what 0x6007 = 3 relies on; a vendor tool
        may have left 0 = power stage off, coasting), and 0x605D = 1, a halt brakes on 0x6084."""
        for index, value, what in (
            (od.QUICK_STOP_OPTION_CODE, od.QUICK_STOP_ON_QUICK_STOP_RAMP, "quick stop option code"),
            (od.HALT_OPTION_CODE, od.HALT_ON_PROFILE_DECELERATION, "halt option code"),
        ):
            if self.link.write_optional(index, 0, value, "h"):
                back = self.link.read(index, 0, "h")
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


def profile_class(name: DriveProfile) -> type[Profile]:
    """The profile module's class by its name (KeyError: no such profile)."""
    from axes.profiles.cia402_ip_linear import Cia402IpLinear
    from axes.profiles.epos2_pvt import Epos2Pvt
    from axes.profiles.parker_slvdn import ParkerSlvdn
    from axes.profiles.sync_setpoint import SyncSetpoint

    classes = {c.name: c for c in (Epos2Pvt, Cia402IpLinear, SyncSetpoint, ParkerSlvdn)}
    return classes[name]


def profile_for(link: AxisLink) -> Profile:
    """The profile module named by the axis's configuration."""
    try:
        return profile_class(link.config.profile)(link)
    except KeyError:
        raise DriveError(link.node_id, f"unknown profile {link.config.profile!r}") from None
