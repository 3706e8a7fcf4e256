"""Drive-side PDOs of a simulated drive, configured the CiA 301 way through its object dictionary.

python-canopen's ``LocalNode`` keeps PDO maps but does not act on what a master writes to
0x1400-0x1BFF over SDO, and neither sends TPDOs on SYNC nor applies synchronous RPDOs at the SYNC.
This module does, from the object dictionary itself: a PDO's configuration is re-read whenever one
of its communication or mapping entries is written (so "disable via COB-ID bit 31, write the
mapping, re-enable" takes effect at the re-enable) and on every NMT state change.

Rules enforced on writes, as strict stacks enforce CiA 301 (SDO abort codes): a valid PDO's
mapping is not written (0x06010000), an entry only while sub 0 is 0 (0x08000022); mapped objects
must exist, be PDO-mappable, readable (TPDO) or writable (RPDO) and be mapped with their own length
(0x06040041), at most 64 bits (0x06040042); a valid PDO's COB-ID (bits 0-29) is not changed, not
even by the write that invalidates it (0x06090030: "shall not be changed while the PDO exists"),
nor its inhibit time (0x06090030). So a master invalidates with the COB-ID it reads, then moves it.
An event-driven TPDO keeps its inhibit time and event timer (``axes.sim.node.tpdo_timing``); a
synchronous TPDO of type n goes out on every n-th SYNC counted from its last reload (CANopenNode's
reading of CiA 301: the first on the n-th SYNC after the drive entered OPERATIONAL or the PDO was
configured). Not simulated: SYNC start value, RTR.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import canopen
from canopen import objectdictionary
from canopen.sdo import SdoAbortedError

from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.objects import EMCY_PDO_LENGTH, PDO_INVALID
from pvtflow.axes.sim.node.dictionary import ABORT_DEVICE_STATE
from pvtflow.axes.sim.node.tpdo_timing import TpdoTiming

RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00

ABORT_UNSUPPORTED_ACCESS = 0x06010000
COB_ID_BITS = 0x3FFF_FFFF  # bits 0-28 the identifier, 29 the frame (CAN 2.0A/B); 30 RTR and 31 invalid not
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_VALUE_RANGE = 0x06090030


def is_pdo_object(index: int) -> bool:
    return 0x1400 <= index <= 0x1BFF


@dataclass
class PdoState:
    """One PDO as the drive currently runs it."""

    number: int
    receive: bool
    cob_id: int
    valid: bool
    transmission_type: int
    entries: tuple[tuple[int, int, int], ...]
    sync_counter: int = 0
    last_sent: bytes | None = None
    pending: bytes | None = None  # synchronous RPDO data waiting for the SYNC
    received: int = 0
    timing: TpdoTiming = field(default_factory=TpdoTiming)  # event-driven TPDO: inhibit time, event timer
    held: threading.Timer | None = None  # a change waits for its inhibit time: the look after it

    @property
    def bits(self) -> int:
        return sum(e[2] for e in self.entries)

    @property
    def synchronous(self) -> bool:
        return self.transmission_type <= 240


class PdoHost(Protocol):
    """What the PDO engine needs of its drive: its node and dictionary, its network and time, where an
    RPDO's data goes and how an EMCY leaves (a ``SimulatedDrive``: the engine does not know the class)."""

    node: canopen.LocalNode
    network: canopen.Network
    lock: threading.RLock
    rejected_writes: list[tuple[int, int, int]]
    time_us: int

    @property
    def operational(self) -> bool: ...

    def read(self, index: int, subindex: int = 0) -> int: ...

    def read_or(self, index: int, subindex: int, default: int) -> int: ...

    def on_rpdo_frame(self, can_id: int, data: bytes) -> None: ...

    def send_emcy(self, code: int, register: int | None = None, data: bytes = b"") -> None: ...


@dataclass
class PdoEngine:
    drive: PdoHost
    rpdos: dict[int, PdoState] = field(default_factory=dict)
    tpdos: dict[int, PdoState] = field(default_factory=dict)
    _subscribed: dict[int, Callable[[int, bytearray, float], None]] = field(default_factory=dict)

    # --- configuration ---------------------------------------------------------------------------
    def _od_entry(self, index: int, subindex: int) -> objectdictionary.ODVariable:
        od = self.drive.node.object_dictionary[index]
        if isinstance(od, objectdictionary.ODVariable):
            return od
        return od[subindex]

    def check_write(self, index: int, subindex: int, value: int) -> None:
        """Refuse a write that CiA 301 forbids (raises SdoAbortedError)."""
        receive = index < TPDO_COMM
        base_comm = RPDO_COMM if receive else TPDO_COMM
        number = (index & 0x1FF) + 1
        stored = self.drive.read(base_comm + number - 1, 1)
        valid = stored & PDO_INVALID == 0
        if (index & 0x200) == 0:  # communication parameter
            moved = (value & COB_ID_BITS) != (stored & COB_ID_BITS)
            if subindex == 1 and moved and valid:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            if subindex == 2 and not (value <= 240 or value >= 252):
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            if subindex == 3 and valid:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            return
        if valid:
            raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)
        if subindex == 0:
            total = 0
            for k in range(1, value + 1):
                try:
                    entry = self.drive.read(index, k)
                except (KeyError, SdoAbortedError):
                    raise SdoAbortedError(ABORT_PDO_LENGTH) from None
                total += entry & 0xFF
            if total > 64:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            return
        if self.drive.read(index, 0) != 0:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        if value == 0:
            return
        self._check_mappable(value >> 16, (value >> 8) & 0xFF, value & 0xFF, receive)

    def _check_mappable(self, index: int, subindex: int, bits: int, receive: bool) -> None:
        try:
            var = self._od_entry(index, subindex)
        except KeyError:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE) from None
        if not var.pdo_mappable or len(var) != bits:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        if (receive and not var.writable) or (not receive and not var.readable):
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)

    def reload(self) -> None:
        """Re-read every PDO from the object dictionary and (re)subscribe the valid RPDOs."""
        network = self.drive.network
        for cob_id, callback in self._subscribed.items():
            unsubscribe(network, cob_id, callback)
        self._subscribed.clear()
        self.rpdos = self._read_all(RPDO_COMM, RPDO_MAP, True)
        self.tpdos = self._read_all(TPDO_COMM, TPDO_MAP, False)
        for pdo in self.rpdos.values():
            if pdo.valid and pdo.entries and pdo.cob_id not in self._subscribed:
                subscribe(network, pdo.cob_id, self._on_frame)
                self._subscribed[pdo.cob_id] = self._on_frame

    def unsubscribe(self) -> None:
        """Leave the network: no frame in, and no held TPDO out once the drive is off the bus."""
        for cob_id, callback in self._subscribed.items():
            unsubscribe(self.drive.network, cob_id, callback)
        self._subscribed.clear()
        for pdo in self.tpdos.values():
            if pdo.held is not None:
                pdo.held.cancel()
                pdo.held = None

    def _read_all(self, comm: int, mapping: int, receive: bool) -> dict[int, PdoState]:
        out: dict[int, PdoState] = {}
        od = self.drive.node.object_dictionary
        for n in range(512):
            if comm + n not in od or mapping + n not in od:
                continue
            cob = self.drive.read(comm + n, 1)
            ttype = self.drive.read(comm + n, 2)
            entries = []
            for k in range(1, self.drive.read(mapping + n, 0) + 1):
                value = self.drive.read(mapping + n, k)
                if value >> 16 and value & 0xFF:
                    entries.append((value >> 16, (value >> 8) & 0xFF, value & 0xFF))
            pdo = PdoState(n + 1, receive, cob & 0x7FF, not cob & PDO_INVALID, ttype, tuple(entries))
            if not receive:
                inhibit, timer = self.drive.read_or(comm + n, 3, 0), self.drive.read_or(comm + n, 5, 0)
                pdo.timing = TpdoTiming.from_objects(inhibit, timer)
            out[n + 1] = pdo
        return out

    # --- reception -------------------------------------------------------------------------------
    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.drive.on_rpdo_frame(can_id, bytes(data))

    def receive(self, can_id: int, data: bytes) -> None:
        """An RPDO frame (the drive holds its lock): asynchronous ones act now, synchronous ones at SYNC."""
        for pdo in self.rpdos.values():
            if not (pdo.valid and pdo.cob_id == can_id and pdo.entries):
                continue
            if len(data) * 8 < pdo.bits:
                self.drive.send_emcy(EMCY_PDO_LENGTH)
                continue
            pdo.received += 1
            if pdo.synchronous:
                pdo.pending = data
            else:
                self._apply(pdo, data)

    def apply_synchronous(self) -> None:
        """At a SYNC: hand the synchronous RPDOs received since the last SYNC to the application."""
        for number in sorted(self.rpdos):
            pdo = self.rpdos[number]
            if pdo.pending is not None:
                data, pdo.pending = pdo.pending, None
                self._apply(pdo, data)

    def _apply(self, pdo: PdoState, data: bytes) -> None:
        offset = 0
        for index, subindex, bits in pdo.entries:
            chunk = data[offset // 8 : (offset + bits) // 8]
            offset += bits
            try:
                self.drive.node.set_data(index, subindex, chunk)
            except SdoAbortedError as exc:
                self.drive.rejected_writes.append((index, subindex, exc.code))

    # --- transmission ----------------------------------------------------------------------------
    def _pack(self, pdo: PdoState) -> bytes:
        out = b""
        for index, subindex, bits in pdo.entries:
            out += self.drive.node.get_data(index, subindex)[: bits // 8]
        return out

    def transmit_on_sync(self) -> None:
        for pdo in self.tpdos.values():
            if not (pdo.valid and pdo.entries and pdo.synchronous):
                continue
            data = self._pack(pdo)
            if pdo.transmission_type == 0:
                if data != pdo.last_sent:
                    self._send(pdo, data)
                continue
            pdo.sync_counter += 1
            if pdo.sync_counter >= pdo.transmission_type:
                pdo.sync_counter = 0
                self._send(pdo, data)

    def transmit_events(self) -> None:
        """Event-driven TPDOs whose data changed (or whose event timer ran out), each once its inhibit
        time has passed: a change within it waits for the next look after it."""
        now = self.drive.time_us
        for pdo in self.tpdos.values():
            if not (pdo.valid and pdo.entries and pdo.transmission_type >= 254):
                continue
            data = self._pack(pdo)
            if data == pdo.last_sent and not pdo.timing.timer_due(now):
                continue
            if pdo.timing.may_send(now):
                pdo.timing.sent(now)
                self._send(pdo, data)
            else:
                self._look_again(pdo)

    def _look_again(self, pdo: PdoState) -> None:
        """A change held by the inhibit time while the drive's clock stands still since the last frame
        (lockstep, no SYNC): look at the TPDOs again once it has passed on the wall clock. A clock
        that moves looks by itself (each SYNC, each wall-clock tick)."""
        if pdo.held is not None or self.drive.time_us != pdo.timing.last_sent_us:
            return

        def look() -> None:
            with self.drive.lock:
                pdo.held = None
                if self.drive.node.has_network() and self.drive.operational and self.tpdos.get(pdo.number) is pdo:
                    self.transmit_events()

        pdo.held = threading.Timer(max(pdo.timing.wall_left(), 0.0) + 1e-4, look)
        pdo.held.daemon = True
        pdo.held.start()

    def _send(self, pdo: PdoState, data: bytes) -> None:
        pdo.last_sent = data
        self.drive.network.send_message(pdo.cob_id, data)
