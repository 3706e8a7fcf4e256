"""What a simulated drive does when its master is lost: the heartbeat consumer (0x1016) and 0x6007.

When a heartbeat 0x1016 watches stops (``axes/sim/node/consumer.py``), the drive sends
EMCY 0x8130 (CiA 301 heartbeat error, error register generic + communication) and does what 0x6007
says: 3 quick stop (the ramp 0x6085, then SWITCH ON DISABLED), 2 disable voltage, 1 fault, braking
first as 0x605E says (2: on the quick stop ramp; FAULT REACTION ACTIVE until the demand is at rest,
then FAULT), 0 nothing more. A drive whose firmware treats a heartbeat error as one of its errors
(``HEARTBEAT_ERROR_FAULTS``: the EPOS2) takes the fault path whatever 0x6007 says (but 0).
In lockstep its motion clock then runs on the wall clock as long as it brakes and no SYNC comes:
without SYNC a lockstep drive's clock stands still (a real drive's runs on), and a lost master
sends no SYNC; on the wall clock the drive's own clock brakes it.

An NMT STOPPED while OPERATIONAL is an abort connection event too (CiA 402), with EMCY 0x8100 where
0x6007 says fault.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

import canopen
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.sim.cia402.records import MasterLoss
from pvtflow.axes.sim.clock import MotionClock
from pvtflow.axes.sim.node.consumer import HeartbeatConsumer
from pvtflow.axes.sim.node.dictionary import ABORT_PARAMETER_INCOMPATIBLE, DriveDictionary
from pvtflow.axes.sim.node.emcy import EMCY_COMMUNICATION, REGISTER_COMMUNICATION, REGISTER_GENERIC, Emcy


class MotionClockRun(Protocol):
    """What the reaction asks of the drive's motion (``sampling.Motion``): where it is, and to run on."""

    velocity: float
    sync_count: int
    time_us: int

    @property
    def braking(self) -> bool: ...

    def run_clock_to(self, new_time_us: int) -> None: ...


class MasterLossHost(Protocol):
    """What the reaction needs of its drive (a ``SimulatedDrive``: the reaction does not know the class):
    its node, dictionary and EMCY, its power state and motion, the fault and controlword paths, and
    how to run its motion clock (under the drive's lock, ``_in_own_thread``)."""

    node: canopen.LocalNode
    dictionary: DriveDictionary
    emcy: Emcy
    state: PowerState
    motion: MotionClockRun
    motion_clock: MotionClock | None

    def fault_braking(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None: ...

    def _on_controlword(self, cw: int) -> None: ...

    def _refresh(self, events: bool = True) -> None: ...

    def _in_own_thread(self, action: Callable[[], None]) -> None: ...


class MasterLossReaction:
    """The heartbeat consumer's configuration and the reaction to a lost master, a part of a
    ``SimulatedDrive`` (given as ``drive``; the consumer's thread calls in, and every action runs under
    the drive's lock). It owns the consumer, the losses it saw and the wall-clock ticking of a drive
    that brakes without SYNC."""

    def __init__(self, drive: MasterLossHost, *, heartbeat_error_faults: bool, rpm_per_qc_ms: float) -> None:
        self._drive = drive
        self._heartbeat_error_faults = heartbeat_error_faults  # the drive's firmware: a heartbeat error faults
        self._rpm_per_qc_ms = rpm_per_qc_ms
        self.consumer = HeartbeatConsumer(str(drive.node.id), self._on_heartbeat_lost, self._wall_clock_tick)
        self.losses: list[MasterLoss] = []
        self._tick_at = 0.0  # wall clock (time.monotonic()) up to which the motion clock has run on its own
        self._tick_sync = 0  # sync_count at the last wall-clock tick: a SYNC since then runs the clock itself
        self._braking_on_own_clock = False  # clock="wall": braking after a lost master, standstill not yet seen

    def configure_consumer(self) -> None:
        """0x1016 as it now is, to the consumer (after a write, and after every reset)."""
        entries: dict[int, int] = {}
        sub = 1
        while self._drive.dictionary.has(od.CONSUMER_HEARTBEAT_TIME, sub):
            value = self._drive.dictionary.read(od.CONSUMER_HEARTBEAT_TIME, sub)
            node, ms = (value >> od.CONSUMER_NODE_SHIFT) & 0xFF, value & 0xFFFF
            if node and ms:
                entries[node] = ms
            sub += 1
        self.consumer.configure(entries)

    def check_consumer_entry(self, subindex: int, value: int) -> None:
        """CiA 301: one entry per watched node (another entry for the same node: abort 0x06040043)."""
        node = (value >> od.CONSUMER_NODE_SHIFT) & 0xFF
        if subindex == 0 or not node or not value & 0xFFFF:
            return
        sub = 1
        while self._drive.dictionary.has(od.CONSUMER_HEARTBEAT_TIME, sub):
            other = self._drive.dictionary.read(od.CONSUMER_HEARTBEAT_TIME, sub)
            if sub != subindex and (other >> od.CONSUMER_NODE_SHIFT) & 0xFF == node and other & 0xFFFF:
                raise SdoAbortedError(ABORT_PARAMETER_INCOMPATIBLE)
            sub += 1

    def _on_heartbeat_lost(self, node_id: int, silent_s: float) -> None:
        """The consumer's thread: a watched heartbeat stopped. EMCY 0x8130, then 0x6007's action."""

        def act() -> None:
            d = self._drive
            if not d.node.has_network():
                return
            now = time.monotonic()
            option = self._drive.dictionary.read_or(
                od.ABORT_CONNECTION_OPTION_CODE, 0, od.AbortConnectionOption.NO_ACTION
            )
            loss = MasterLoss(
                node_id,
                silent_s,
                now,
                self.consumer.last_heard.get(node_id),
                option,
                d.state.value,
                d.motion.velocity * self._rpm_per_qc_ms,
            )
            self.losses.append(loss)
            register = REGISTER_GENERIC | REGISTER_COMMUNICATION
            check = f"heartbeat of node {node_id} lost ({silent_s * 1000:.0f} ms silent)"
            if option == od.AbortConnectionOption.FAULT_SIGNAL or (
                self._heartbeat_error_faults and option != od.AbortConnectionOption.NO_ACTION
            ):
                d.fault_braking(od.EMCY_HEARTBEAT_ERROR, check, register=register)
            else:
                d.emcy.send(od.EMCY_HEARTBEAT_ERROR, register)
                if option == od.AbortConnectionOption.DISABLE_VOLTAGE:
                    d._on_controlword(0x0000)  # CiA 402: the disable voltage command
                elif option == od.AbortConnectionOption.QUICK_STOP:
                    d._on_controlword(0x0002)  # the quick stop command
            d._refresh()
            self._tick_at, self._tick_sync = now, d.motion.sync_count
            if d.motion.braking:
                if d.motion_clock is not None:
                    self._braking_on_own_clock = True  # the drive's own clock brakes it (run_to)
                else:
                    self.consumer.tick()  # brake on the wall clock: no SYNC may come any more
            elif option != od.AbortConnectionOption.NO_ACTION or abs(d.motion.velocity) <= 1e-12:
                loss.standstill = now

        self._drive._in_own_thread(act)

    def brake_on_own_clock(self) -> None:
        """A quick stop brakes whether or not SYNC comes (a master that lost SYNC quick stops by SDO):
        the motion clock runs on the wall clock between SYNCs until the demand is at rest. A drive on
        its own clock (``clock="wall"``) brakes on it already (``run_to``)."""
        if self._drive.motion_clock is not None:
            return
        self._tick_at, self._tick_sync = time.monotonic(), self._drive.motion.sync_count
        self.consumer.tick()

    def on_nmt_stopped(self) -> None:
        """CiA 402: entering NMT STOPPED from OPERATIONAL is an abort connection event (0x6007)."""
        option = self._drive.dictionary.read_or(od.ABORT_CONNECTION_OPTION_CODE, 0, od.AbortConnectionOption.NO_ACTION)
        if option == od.AbortConnectionOption.FAULT_SIGNAL:
            self._drive.fault_braking(EMCY_COMMUNICATION, "NMT stopped while operational")
            if self._drive.motion.braking:
                self.brake_on_own_clock()
        elif option == od.AbortConnectionOption.DISABLE_VOLTAGE:
            self._drive._on_controlword(0x0000)  # CiA 402: the disable voltage command
        elif option == od.AbortConnectionOption.QUICK_STOP:
            self._drive._on_controlword(0x0002)  # the quick stop command

    def _wall_clock_tick(self) -> bool:
        """The consumer's thread, every ms while the drive brakes after a lost master: the motion
        clock runs by the wall clock's elapsed time unless a SYNC came since the last tick (then
        SYNC runs it). False once the demand is at rest."""
        result = False

        def act() -> None:
            nonlocal result
            d = self._drive
            now = time.monotonic()
            if d.motion.braking:
                if d.motion.sync_count != self._tick_sync:
                    self._tick_sync = d.motion.sync_count
                elif (elapsed_us := round((now - self._tick_at) * 1e6)) > 0:
                    d.motion.run_clock_to(d.motion.time_us + elapsed_us)
                    d._refresh()
            self._tick_at = now
            if not d.motion.braking:
                self._standstill(now)
                return
            result = True

        self._drive._in_own_thread(act)
        return result

    def at_rest(self) -> None:
        """clock="wall": the drive's own clock braked it to rest (``run_to``): the standstill of a loss it
        braked for."""
        if self._braking_on_own_clock:
            self._braking_on_own_clock = False
            self._standstill(time.monotonic())

    def _standstill(self, now: float) -> None:
        for loss in self.losses:
            if loss.standstill is None:
                loss.standstill = now
