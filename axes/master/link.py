"""AxisLink: the master's handle on one drive: SDO by index, PDO configuration, controlword, status.

What every drive profile shares on the wire (CiA 301 SDO and PDO mapping, CiA 402 controlword and
power states, the values its TPDOs bring) lives here, apart from what a behaviour adds to it
(``axes.master.profiles``): a link knows its node, not its profile.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import canopen
from can import CanError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import (
    CONTROLWORD_FAULT_RESET,
    PowerState,
    PowerStateSteering,
    decode_state,
)
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.objects import BufferStatus, PdoLayout
from pvtflow.axes.master.tpdo_rates import with_rates

# an SDO transfer that did not complete: no answer, a frame the bus refused (a full transmit queue), a short reply
TRANSFER_FAILED = (SdoCommunicationError, CanError, struct.error)

if TYPE_CHECKING:
    from pvtflow.axes.master.bus.cell_bus import CellBus

PDO_RTR_BIT = 0x4000_0000  # COB-ID bit 30: no RTR allowed on this PDO
PDO_COB_ID_BITS = 0x3FFF_FFFF  # bits 0-29: the identifier and its frame format


class DriveError(RuntimeError):
    """A drive did not accept its configuration or a state change (node, object, what happened)."""

    def __init__(self, node_id: int, message: str) -> None:
        self.node_id = node_id
        self.detail = message  # the message without the node
        super().__init__(f"node {node_id}: {message}")


# Signedness and size of the objects pvtflow maps into PDOs (decode by the layouts of axes.drive.objects).
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


class AxisLink:
    """The master's view of one drive: SDO by index, controlword out, statusword/position/buffer in."""

    def __init__(self, bus: CellBus, config: AxisConfig) -> None:
        self.bus = bus
        self.config = config
        self.node_id = config.node_id
        self.node: canopen.RemoteNode = bus.add_node(config.node_id)
        self.psm = PowerStateSteering()
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
        except TRANSFER_FAILED as exc:
            raise DriveError(self.node_id, f"SDO write {where} = {value} failed: {exc}") from None
        return True

    def read(self, index: int, subindex: int, fmt: str) -> int:
        self.sdo_transfers += 1
        try:
            with self._sdo:
                data = self.node.sdo.upload(index, subindex)
            return struct.unpack_from("<" + fmt, data.ljust(struct.calcsize(fmt), b"\0"))[0]
        except (SdoAbortedError, *TRANSFER_FAILED) as exc:
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
        except TRANSFER_FAILED as exc:
            raise DriveError(self.node_id, f"SDO read 0x{index:04X}:{subindex:02X} failed: {exc}") from None

    def read_statusword(self) -> int:
        self._set_statusword(self.read(od.STATUSWORD, 0, "H"))
        return self.statusword

    def note_emcy(self, code: int, message: str) -> None:
        """The drive's last EMCY (the bus reports it), told with its fault."""
        self.last_emcy = (code, message)

    def forget_faults(self) -> None:
        """The drive was reset and enabled again: its last EMCY and buffer errors are history."""
        self.last_emcy = None
        self.buffer_status &= ~int(od.BUFFER_ERRORS)

    def read_position(self) -> int:
        """0x6064 by SDO (between runs no TPDO reports it)."""
        self.position = self.read(od.POSITION_ACTUAL_VALUE, 0, "i")
        return self.position

    # --- PDO configuration (CiA 301 7.5.2.35-38) ----------------------------------------------------
    def map_pdo(self, layout: PdoLayout, receive: bool, cob_id: int | None = None) -> None:
        """Configure one PDO as CiA 301 says, in the order a strict stack accepts: invalidate it with
        the COB-ID it has (bits 0-29 may not change while it is valid), move the COB-ID while it is
        invalid, clear the mapping count, map, set the count, write the transmission type and, for a
        TPDO, the inhibit time and event timer (0: none; an event TPDO sends on a change only), then
        validate; bit 30 (RTR) stays as the drive has it. The result is read back: a drive that
        holds anything else is refused (DriveError naming the PDO)."""
        comm = od.pdo_communication_index(layout.number, receive)
        mapping = od.pdo_mapping_index(layout.number, receive)
        cob = layout.cob_id(self.node_id, receive) if cob_id is None else cob_id
        stored = self.read(comm, 1, "I")
        rtr = stored & PDO_RTR_BIT
        if not stored & od.PDO_INVALID:
            self.write(comm, 1, stored | od.PDO_INVALID, "I")
        if stored & PDO_COB_ID_BITS != cob:
            self.write(comm, 1, rtr | od.PDO_INVALID | cob, "I")
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
        comm = od.pdo_communication_index(layout.number, receive)
        mapping = od.pdo_mapping_index(layout.number, receive)
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
        comm = od.pdo_communication_index(number, receive)
        cob = self.read_optional(comm, 1, "I")
        if cob is not None and not cob & od.PDO_INVALID:
            self.write(comm, 1, cob | od.PDO_INVALID, "I")

    def map_pdos(
        self, rpdos: tuple[PdoLayout, ...], tpdos: tuple[PdoLayout, ...], rpdo_cob_ids: dict[int, int] | None = None
    ) -> None:
        """Map pvtflow's PDOs and invalidate the others (``rpdo_cob_ids``: RPDO number -> shared COB-ID);
        the status TPDOs at the cell's rates (``axes.master.tpdo_rates``)."""
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
        return od.pdo_cob_id(2, self.node_id, receive=True)

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
