"""What every simulated drive shares: a canopen ``LocalNode`` that behaves as a CiA 402 drive.

NMT (boot-up, pre-operational, PDOs only when operational), heartbeat producer per 0x1017 and
heartbeat consumer per 0x1016 (wall clock: the only wall-clock parts), EMCY producer, the DS402
power state machine driven by the controlword, the statusword, SYNC-driven motion clock with 1 kHz
interpolation samples, 0x607D on every demand sample, fault handling and fault injection. The
profile modules (epos2, ip_linear, sync_setpoint, parker) add their interpolation on top through a
few hooks. The machine around the axis (power-up anywhere, limit switches, hard stops) and homing
mode 6 on it come from ``axes/sim/homing.py`` (``HomingMixin``), for drives whose 0x6502 has mode 6.

Master loss: when a heartbeat 0x1016 watches stops (``axes/sim/consumer.py``), the drive sends
EMCY 0x8130 (CiA 301 heartbeat error, error register generic + communication) and does what 0x6007
says: 3 quick stop (the ramp 0x6085, then SWITCH ON DISABLED), 2 disable voltage, 1 fault, braking
first as 0x605E says (2: on the quick stop ramp; FAULT REACTION ACTIVE until the demand is at rest,
then FAULT), 0 nothing more. A drive whose firmware treats a heartbeat error as one of its errors
(``HEARTBEAT_ERROR_FAULTS``: the EPOS2) takes the fault path whatever 0x6007 says (but 0).
In lockstep its motion clock then runs on the wall clock as long as it brakes and no SYNC comes:
without SYNC a lockstep drive's clock stands still (a real drive's runs on), and a lost master
sends no SYNC; on the wall clock the drive's own clock brakes it. Other faults stop the axis at
once (the power stage off, the demand on the actual position).

Motion clock, ``clock="lockstep"`` (the default): each SYNC advances the drive's motion time by the
cell's SYNC period; between two SYNCs the drive samples its interpolation at every whole millisecond
of that clock. Nothing waits on wall-clock time (but the reaction to a lost master, above), so a
test runs a drive exactly as fast as it sends SYNCs, deterministically.

``clock="wall"``: the drive keeps its own time (``axes/sim/clock.py``: its quartz, ``drift_ppm``
fast) and samples every whole ms of it, run by the cell's ``Ticker`` (``run_to``) whatever the SYNCs
do. A SYNC is latched at its arrival on that clock (the frame's bus time stamp when plausible, else
the callback's instant), as a drive latches it in hardware, and the profiles act on it there
(``sync_time_us``) even when the simulation gets to the frame after the ticker has sampled past it
(``SyncSample.behind_us``): a late SYNC or a burst of SYNCs is what the drive sees, as a real one
would, and the simulation's own latency is not.

Threads: every bus callback runs in the simulated network's notifier thread; test code may call in
from other threads, so all state is guarded by one lock, and ``changed`` is notified after each
SYNC, write or frame (``wait_until`` waits on it).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import ClassVar

import canopen
from canopen import objectdictionary
from canopen.profiles.p402 import State402
from canopen.sdo import SdoAbortedError

from axes import objects as od
from axes.cia402 import Controlword, PowerState, Statusword
from axes.config import AxisSimulation
from axes.scaling import INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from axes.sim.clock import LOCKSTEP, WALL, MotionClock, Quartz, arrival, check_clock
from axes.sim.consumer import HeartbeatConsumer
from axes.sim.device import (
    SIMULATED_MODE,
    SUPPORTED_DRIVE_MODES,
    DriveModes,
    Value,
    complete_object_dictionary,
    identity_values,
)
from axes.sim.homing import HomingMixin, HomingState, Machine
from axes.sim.pdo import PdoEngine, is_pdo_object
from axes.sim.records import FaultRecord, MasterLoss, SyncSample
from axes.sim.segment import Segment
from axes.subscriptions import subscribe, unsubscribe

EDS_DIR = Path(__file__).resolve().parent.parent.parent / "configs" / "eds"
# maxon's own published EPOS2 70/10 EDS, kept unchanged as a vendor data file (configs/eds/vendor/README.md)
MAXON_EPOS2_EDS = EDS_DIR / "vendor" / "maxon-epos2-70-10.eds"

# DS402 power states and statusword/controlword bits: the master's definitions (axes/cia402.py),
# short names for the drive side
NOT_READY = PowerState.NOT_READY_TO_SWITCH_ON
SWITCH_ON_DISABLED = PowerState.SWITCH_ON_DISABLED
READY_TO_SWITCH_ON = PowerState.READY_TO_SWITCH_ON
SWITCHED_ON = PowerState.SWITCHED_ON
OPERATION_ENABLED = PowerState.OPERATION_ENABLED
QUICK_STOP_ACTIVE = PowerState.QUICK_STOP_ACTIVE
FAULT_REACTION_ACTIVE = PowerState.FAULT_REACTION_ACTIVE
FAULT = PowerState.FAULT

VOLTAGE_ENABLED = int(Statusword.VOLTAGE_ENABLED)
WARNING = int(Statusword.WARNING)
TARGET_REACHED = int(Statusword.TARGET_REACHED)
IP_MODE_ACTIVE = int(Statusword.IP_MODE_ACTIVE)
CW_HOMING_START = int(Controlword.HOMING_START)
CW_ENABLE_IP = int(Controlword.ENABLE_IP_MODE)
CW_FAULT_RESET = int(Controlword.FAULT_RESET)
CW_HALT = int(Controlword.HALT)

ABORT_VALUE_RANGE = 0x06090030
ABORT_DEVICE_STATE = 0x08000022
ABORT_GENERAL = 0x08000000

ABORT_PARAMETER_INCOMPATIBLE = 0x06040043  # CiA 301: a 0x1016 entry for a node another entry watches
ERROR_CODE = 0x603F
EMCY_COMMUNICATION = 0x8100  # CiA 301: communication, generic
ERROR_REGISTER = 0x1001
ERROR_HISTORY = 0x1003
REGISTER_GENERIC = 0x01  # 0x1001 bits
REGISTER_COMMUNICATION = 0x10


class SimulatedDrive(HomingMixin):
    """A CiA 402 drive on a canopen network, simulated. Subclasses add one interpolation behaviour."""

    PROFILE: ClassVar[str] = ""
    EDS: ClassVar[str] = ""
    EMCY_POSITION_LIMIT: ClassVar[int] = od.EMCY_SOFTWARE_POSITION_LIMIT
    EMCY_VELOCITY: ClassVar[int] = od.EMCY_VELOCITY_LIMIT
    MODES: ClassVar[DriveModes] = DriveModes((SIMULATED_MODE,))  # 0x6502 / 0x6060 (axes/sim/device.py)
    # a lost master's heartbeat is one of the drive's own errors: its fault reaction (0x605E), then FAULT
    HEARTBEAT_ERROR_FAULTS: ClassVar[bool] = False
    HOMING_METHODS: ClassVar[frozenset[int]] = frozenset()  # 0x6098 values it runs in mode 6 (axes/sim/homing.py)
    REFERENCED_BIT: ClassVar[int] = 0  # a manufacturer statusword bit that says "homed since power-on"
    _ip_requested: bool = False  # bit 4 rose: ip mode starts on the next SYNC (profiles reset it)

    def __init__(
        self,
        node_id: int,
        network: canopen.Network | None = None,
        eds_path: str | Path | None = None,
        *,
        scaling: AxisScaling | None = None,
        limits: DriveLimits | None = None,
        sync_period_ms: float = 1.0,
        history_length: int = 20_000,
        simulation: AxisSimulation | None = None,
        clock: str = LOCKSTEP,
        drift_ppm: float = 0.0,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} is outside 1..127")
        if not (math.isfinite(sync_period_ms) and sync_period_ms > 0):
            raise ValueError(f"sync_period_ms must be positive, got {sync_period_ms!r}")
        check_clock(clock, drift_ppm)
        self.clock = clock
        self.quartz = Quartz(drift_ppm)  # the drive's own time on the wall clock (axes/sim/clock.py)
        self.motion_clock: MotionClock | None = None  # wall clock: set when the drive joins a network
        self._loss_braking = False  # wall clock: braking after a lost master, standstill not yet seen
        self.eds_path = Path(eds_path) if eds_path is not None else EDS_DIR / self.EDS
        self.node = canopen.LocalNode(node_id, str(self.eds_path))
        own = {**identity_values(self.node.object_dictionary, self.MODES), **self._own_values()}
        complete_object_dictionary(self.node.object_dictionary, own, frozenset({(SUPPORTED_DRIVE_MODES, 0)}))
        self._entries: dict[tuple[int, int], tuple[objectdictionary.ODVariable, int]] = {}
        self._published: dict[tuple[int, int], tuple[int, int, bytes]] = {}  # see publish()
        self.scaling = scaling if scaling is not None else AxisScaling(2000.0, 1.0)
        if simulation is not None and simulation.qc_per_motor_rev is not None:  # its own encoder, not the cell's
            self.scaling = replace(self.scaling, qc_per_motor_rev=float(simulation.qc_per_motor_rev))
        self.sync_period_us = round(sync_period_ms * 1000.0)
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.network: canopen.Network = canopen.network._UNINITIALIZED_NETWORK
        self.pdo = PdoEngine(self)
        self._internal_position = self.has(od.POSITION_ACTUAL_INTERNAL_VALUE)  # 0x6063 (the Parker's)
        # what tests look at
        self.history: deque[SyncSample] = deque(maxlen=history_length)
        self.faults: list[FaultRecord] = []
        self.emcy_sent: list[tuple[int, int, bytes]] = []
        self.rejected_writes: list[tuple[int, int, int]] = []
        self.internal_errors: list[BaseException] = []
        self.time_stamps: deque[int] = deque(maxlen=history_length)  # 0x1013 values (us); no clock correction
        self.ip_active_sync: int | None = None  # SYNC count at which interpolation last became active
        self.sync_count = 0
        self.halts: list[int] = []  # the SYNC count at every halt (controlword bit 8) taken in OPERATION ENABLED
        self.time_us = 0
        # the SYNC being processed, on the motion clock: time_us in lockstep; on the wall clock its
        # arrival, which the drive's samples may have passed already when the simulation is late
        self.sync_time_us = 0
        self.sample_ms = 0.0  # motion time of the sample being computed (or of the last SYNC)
        self._heartbeat_silenced = False
        self._nmt_left = "INITIALISING"  # the NMT state the last NMT command found (0x6007 on leaving OPERATIONAL)
        self.consumer = HeartbeatConsumer(str(node_id), self._on_heartbeat_lost, self._wall_clock_tick)
        self.master_losses: list[MasterLoss] = []
        self._tick_at = 0.0  # wall clock (time.monotonic()) up to which the motion clock has run on its own
        self._tick_sync = 0  # sync_count at the last wall-clock tick: a SYNC since then runs the clock itself
        self._commissioned: dict[tuple[int, int], int] = {}  # kept through an NMT reset (stored parameters)
        # the machine: where the encoder's 0 is (the machine position = demand + origin; an incremental
        # encoder counts from 0 wherever the axis stands at power-on), switches, index pulse, hard stops
        self.simulation = simulation
        self.machine = Machine(simulation or AxisSimulation())
        self.origin = self._power_up_position(node_id, simulation, limits)
        self.referenced = False  # homed since the last power-on / reset
        self.homing_runs = []  # every homing started (tests, benches)
        self._homing = None
        self._homing_t = 0.0
        # the factor of DESIGN section 4 and the rpm / rpm/s conversions, from axes.scaling
        self.velocity_factor = self.scaling.qc_per_ms_per_velocity_unit  # record velocity unit -> qc/ms
        self._rpm_per_qc_ms = float(self.scaling.qc_per_ms_to_rpm(1.0))
        # velocity objects (0x607F, 0x6081, 0x6099) in the drive's velocity unit, as the master writes them
        self._units_per_qc_ms = self._rpm_per_qc_ms / self.scaling.velocity_unit_rpm
        self._rpm_s_per_qc_ms2 = float(self.scaling.qc_per_ms2_to_rpm_s(1.0))
        self.node._write_callbacks.remove(self.node.nmt.on_write)  # 0x1017 is handled here
        # canopen passes the written entry as the keyword ``od``, which is this module's name for axes.objects
        self.node.add_write_callback(lambda index, subindex, od, data: self._on_write(index, subindex, od, data))
        self._reset_application()
        if limits is not None:
            self.apply_limits(limits)
        self._apply_drive_facts(simulation or AxisSimulation())
        if network is not None:
            self.attach(network)

    # --- object dictionary access (no callbacks) --------------------------------------------------
    def _entry(self, index: int, subindex: int) -> tuple[objectdictionary.ODVariable, int]:
        """The OD variable and the sub-index its value is stored under (0 for a plain variable)."""
        key = (index, subindex)
        hit = self._entries.get(key)
        if hit is None:
            entry = self.node.object_dictionary[index]
            plain = isinstance(entry, objectdictionary.ODVariable)
            hit = (entry, 0) if plain else (entry[subindex], subindex)
            self._entries[key] = hit
        return hit

    def _var(self, index: int, subindex: int = 0) -> objectdictionary.ODVariable:
        return self._entry(index, subindex)[0]

    def has(self, index: int, subindex: int = 0) -> bool:
        try:
            self._entry(index, subindex)
        except KeyError:
            return False
        return True

    def read(self, index: int, subindex: int = 0) -> int:
        """The value of an object as the drive holds it (EDS default if never written)."""
        var, sub = self._entry(index, subindex)
        raw = self.node.data_store.get(index, {}).get(sub)
        return var.decode_raw(raw if raw is not None else self.node.get_data(index, sub))

    def store(self, index: int, subindex: int, value: int) -> None:
        """Set an object's value from the drive's side (no write callbacks)."""
        var, sub = self._entry(index, subindex)
        self.node.data_store.setdefault(index, {})[sub] = var.encode_raw(value)

    def publish(self, index: int, subindex: int, value: int) -> None:
        """``store`` for the status objects every event refreshes: nothing to do when the object
        still holds this value (the same bytes this call stored last; anything that replaced them,
        a write or a reset, makes it store again). Most refreshes change one or two of them."""
        key = (index, subindex)
        held = self._published.get(key)
        if held is not None and held[0] == value and self.node.data_store.get(index, {}).get(held[1]) is held[2]:
            return
        var, sub = self._entry(index, subindex)
        raw = var.encode_raw(value)
        self.node.data_store.setdefault(index, {})[sub] = raw
        self._published[key] = (value, sub, raw)

    def read_or(self, index: int, subindex: int, default: int) -> int:
        return self.read(index, subindex) if self.has(index, subindex) else default

    def apply_limits(self, limits: DriveLimits) -> None:
        """Commission the drive's own limit objects (facts about the drive, DESIGN section 3)."""
        values = {
            (od.MAX_PROFILE_VELOCITY, 0): round(limits.max_profile_velocity_rpm / self.scaling.velocity_unit_rpm),
            (od.MAX_ACCELERATION, 0): round(limits.max_acceleration_rpm_s),
            (od.SOFTWARE_POSITION_LIMIT, 1): limits.min_position_qc,
            (od.SOFTWARE_POSITION_LIMIT, 2): limits.max_position_qc,
        }
        if limits.profile_velocity_rpm is not None:
            values[(od.PROFILE_VELOCITY, 0)] = round(limits.profile_velocity_rpm / self.scaling.velocity_unit_rpm)
        if limits.profile_acceleration_rpm_s is not None:
            values[(od.PROFILE_ACCELERATION, 0)] = round(limits.profile_acceleration_rpm_s)
        with self.lock:
            self._commissioned.update(values)
            for (index, subindex), value in values.items():
                self.store(index, subindex, value)

    def _apply_drive_facts(self, simulation: AxisSimulation) -> None:
        """What the drive is, kept through resets as a drive's stored parameters are: its encoder
        (0x608F, or maxon's pulse number 0x2210:01 in encoder pulses), and where ``simulation`` says
        so its polarity 0x607E, identity 0x1018:01/:02 and motor's maximal speed 0x6410:04."""
        qc = round(self.scaling.qc_per_motor_rev)
        values: dict[tuple[int, int], int] = {}
        if self.has(od.POSITION_ENCODER_RESOLUTION, 1):
            values[(od.POSITION_ENCODER_RESOLUTION, 1)] = qc
            values[(od.POSITION_ENCODER_RESOLUTION, 2)] = 1
        if self.has(od.EPOS2_SENSOR_CONFIGURATION, 1):
            values[(od.EPOS2_SENSOR_CONFIGURATION, 1)] = round(qc / od.EPOS2_QC_PER_PULSE)
        for key, value in (
            ((od.POLARITY, 0), simulation.polarity),
            ((od.IDENTITY, 1), simulation.vendor_id),
            ((od.IDENTITY, 2), simulation.product_code),
            ((od.MOTOR_DATA, od.MOTOR_MAX_SPEED_SUB), simulation.max_motor_speed_rpm),
        ):
            if value is not None and self.has(*key):
                values[key] = value
        with self.lock:
            self._commissioned.update(values)
            for (index, subindex), value in values.items():
                self.store(index, subindex, value)

    def power_cycle(self) -> None:
        """Power off and on: the encoder counts from 0 again where the axis stands, not homed, boot-up."""
        with self.lock:
            self._reset_application()
            if self.node.has_network():
                self.boot()
            self.changed.notify_all()

    # --- network ------------------------------------------------------------------------------------
    @property
    def node_id(self) -> int:
        return self.node.id

    def attach(self, network: canopen.Network) -> None:
        """Join a network (not yet booted: call ``boot`` once the network is connected)."""
        subscribe(network, 0, self._note_nmt_state)  # before the node's own NMT handling: the state it leaves
        network.add_node(self.node)
        self.network = network
        if self.clock == WALL:
            with self.lock:
                self.motion_clock = MotionClock(self.quartz, float(self.time_us), time.monotonic())
        subscribe(network, od.SYNC_COB_ID, self._on_sync)
        subscribe(network, 0, self._on_nmt)
        self.consumer.attach(network)

    def detach(self) -> None:
        self.consumer.detach()  # joins its thread, which takes the lock: before taking it
        with self.lock:
            if not self.node.has_network():
                return
            self.node.nmt.stop_heartbeat()
            self.pdo.unsubscribe()
            unsubscribe(self.network, od.SYNC_COB_ID, self._on_sync)
            unsubscribe(self.network, 0, self._on_nmt)
            unsubscribe(self.network, 0, self._note_nmt_state)
            del self.network[self.node.id]
            self.network = canopen.network._UNINITIALIZED_NETWORK

    def boot(self) -> None:
        """Power on: boot-up message, then pre-operational with the heartbeat of 0x1017."""
        with self.lock:
            self.node.nmt.send_command(0x81)  # initialising: sends the boot-up frame
            self.node.nmt.send_command(0x80)  # pre-operational: starts the heartbeat
            if self._heartbeat_silenced:
                self.node.nmt.stop_heartbeat()
            self.pdo.reload()
            self._configure_consumer()

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    # --- fault injection --------------------------------------------------------------------------
    def stop_heartbeat(self) -> None:
        """The node goes quiet on 0x700 (as a node that lost power would); SDO/PDO still answer."""
        with self.lock:
            self._heartbeat_silenced = True
            self.node.nmt.stop_heartbeat()

    def resume_heartbeat(self) -> None:
        with self.lock:
            self._heartbeat_silenced = False
            period = self.read(od.PRODUCER_HEARTBEAT_TIME)
            if period:
                self.node.nmt.start_heartbeat(period)

    def inject_emcy(self, code: int, *, fault: bool = True, data: bytes = b"") -> None:
        """Raise an error as the drive would: EMCY with ``code`` and, by default, the fault state."""
        with self.lock:
            if fault:
                self.fault(code, "injected", data)
            else:
                self.send_emcy(code, data=data)
            self._refresh()

    # --- waiting (tests) --------------------------------------------------------------------------
    def wait_until(self, predicate: Callable[[], bool], timeout: float = 5.0) -> bool:
        """Wait (on the drive's own events, not by polling sleeps) until predicate() holds."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not predicate():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.changed.wait(remaining)
            return True

    def wait_sync(self, count: int, timeout: float = 5.0) -> bool:
        """Wait until the drive has processed its ``count``-th SYNC."""
        return self.wait_until(lambda: self.sync_count >= count, timeout)

    # --- EMCY and faults --------------------------------------------------------------------------
    def send_emcy(self, code: int, register: int | None = None, data: bytes = b"") -> None:
        if register is None:
            register = self.read_or(ERROR_REGISTER, 0, 0) | (0x01 if code else 0)
        payload = bytes(data[:5]).ljust(5, b"\0")
        self.emcy_sent.append((code, register, payload))
        if self.node.has_network() and self.node.nmt.state != "STOPPED":
            self.node.emcy.send(code, register, payload)

    def fault(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """Fault reaction: the drive stops its interpolation, sends EMCY and waits in FAULT for a reset."""
        if self.state == FAULT:
            return
        self.faults.append(FaultRecord(self.sync_count, self.sample_ms, code, check))
        self._abort_motion()
        self._interrupt_homing()
        self._stop_segment = None
        self.velocity = self.acceleration = 0.0
        self.demand = float(self.actual)  # the power stage is off: the demand follows the actual position
        self.state = FAULT
        self._signal_fault(code, data, register)

    def fault_braking(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        """A fault whose reaction brakes first, as 0x605E says (1: profile deceleration, 2: quick stop
        ramp; 0, or at rest: at once, as ``fault``): FAULT REACTION ACTIVE while braking, then FAULT."""
        if self.state in (FAULT, FAULT_REACTION_ACTIVE):
            return
        reaction = self.read_or(od.FAULT_REACTION_OPTION_CODE, 0, od.FaultReaction.QUICK_STOP)
        v = self.velocity
        moving = self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and abs(v) > 1e-12
        if reaction not in (od.FaultReaction.SLOW_DOWN, od.FaultReaction.QUICK_STOP) or not moving:
            self.fault(code, check, data, register)
            return
        self.faults.append(FaultRecord(self.sync_count, self.sample_ms, code, check))
        deceleration = self._deceleration(quick=reaction == od.FaultReaction.QUICK_STOP)
        self.state = FAULT_REACTION_ACTIVE  # before the abort: an EPOS2 empties its FIFO (app note 3.8)
        self._abort_motion()
        self._interrupt_homing()
        self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, v, deceleration)
        self._signal_fault(code, data, register)

    def _signal_fault(self, code: int, data: bytes, register: int) -> None:
        """0x603F, 0x1001, 0x1003 and the EMCY of a fault."""
        if self.has(ERROR_CODE):
            self.store(ERROR_CODE, 0, code)
        self.store(ERROR_REGISTER, 0, register)
        if self.has(ERROR_HISTORY, 1):
            n = min(self.read(ERROR_HISTORY, 0) + 1, 4) if self.has(ERROR_HISTORY, 4) else 1
            for k in range(n, 1, -1):
                self.store(ERROR_HISTORY, k, self.read(ERROR_HISTORY, k - 1))
            self.store(ERROR_HISTORY, 1, code)
            self.store(ERROR_HISTORY, 0, n)
        self.send_emcy(code, register, data)

    # --- master loss (0x1016, 0x6007) -------------------------------------------------------------
    def _configure_consumer(self) -> None:
        """0x1016 as it now is, to the consumer (after a write, and after every reset)."""
        entries: dict[int, int] = {}
        sub = 1
        while self.has(od.CONSUMER_HEARTBEAT_TIME, sub):
            value = self.read(od.CONSUMER_HEARTBEAT_TIME, sub)
            node, ms = (value >> od.CONSUMER_NODE_SHIFT) & 0xFF, value & 0xFFFF
            if node and ms:
                entries[node] = ms
            sub += 1
        self.consumer.configure(entries)

    def _check_consumer_entry(self, subindex: int, value: int) -> None:
        """CiA 301: one entry per watched node (another entry for the same node: abort 0x06040043)."""
        node = (value >> od.CONSUMER_NODE_SHIFT) & 0xFF
        if subindex == 0 or not node or not value & 0xFFFF:
            return
        sub = 1
        while self.has(od.CONSUMER_HEARTBEAT_TIME, sub):
            other = self.read(od.CONSUMER_HEARTBEAT_TIME, sub)
            if sub != subindex and (other >> od.CONSUMER_NODE_SHIFT) & 0xFF == node and other & 0xFFFF:
                raise SdoAbortedError(ABORT_PARAMETER_INCOMPATIBLE)
            sub += 1

    def _on_heartbeat_lost(self, node_id: int, silent_s: float) -> None:
        """The consumer's thread: a watched heartbeat stopped. EMCY 0x8130, then 0x6007's action."""

        def act() -> None:
            if not self.node.has_network():
                return
            now = time.monotonic()
            option = self.read_or(od.ABORT_CONNECTION_OPTION_CODE, 0, od.AbortConnectionOption.NO_ACTION)
            loss = MasterLoss(
                node_id,
                silent_s,
                now,
                self.consumer.last_heard.get(node_id),
                option,
                self.state.value,
                self.velocity * self._rpm_per_qc_ms,
            )
            self.master_losses.append(loss)
            register = REGISTER_GENERIC | REGISTER_COMMUNICATION
            check = f"heartbeat of node {node_id} lost ({silent_s * 1000:.0f} ms silent)"
            if option == od.AbortConnectionOption.FAULT_SIGNAL or (
                self.HEARTBEAT_ERROR_FAULTS and option != od.AbortConnectionOption.NO_ACTION
            ):
                self.fault_braking(od.EMCY_HEARTBEAT_ERROR, check, register=register)
            else:
                self.send_emcy(od.EMCY_HEARTBEAT_ERROR, register)
                if option == od.AbortConnectionOption.DISABLE_VOLTAGE:
                    self._on_controlword(0x0000)  # CiA 402: the disable voltage command
                elif option == od.AbortConnectionOption.QUICK_STOP:
                    self._on_controlword(0x0002)  # the quick stop command
            self._refresh()
            self._tick_at, self._tick_sync = now, self.sync_count
            if self._stop_segment is not None:
                if self.motion_clock is not None:
                    self._loss_braking = True  # the drive's own clock brakes it (run_to)
                else:
                    self.consumer.tick()  # brake on the wall clock: no SYNC may come any more
            elif option != od.AbortConnectionOption.NO_ACTION or abs(self.velocity) <= 1e-12:
                loss.standstill = now

        self._in_own_thread(act)

    def _brake_on_own_clock(self) -> None:
        """A quick stop brakes whether or not SYNC comes (a master that lost SYNC quick stops by SDO):
        the motion clock runs on the wall clock between SYNCs until the demand is at rest. A drive on
        its own clock (``clock="wall"``) brakes on it already (``run_to``)."""
        if self.motion_clock is not None:
            return
        self._tick_at, self._tick_sync = time.monotonic(), self.sync_count
        self.consumer.tick()

    def _on_nmt_stopped(self) -> None:
        """CiA 402: entering NMT STOPPED from OPERATIONAL is an abort connection event (0x6007)."""
        option = self.read_or(od.ABORT_CONNECTION_OPTION_CODE, 0, od.AbortConnectionOption.NO_ACTION)
        if option == od.AbortConnectionOption.FAULT_SIGNAL:
            self.fault_braking(EMCY_COMMUNICATION, "NMT stopped while operational")
            if self._stop_segment is not None:
                self._brake_on_own_clock()
        elif option == od.AbortConnectionOption.DISABLE_VOLTAGE:
            self._on_controlword(0x0000)  # CiA 402: the disable voltage command
        elif option == od.AbortConnectionOption.QUICK_STOP:
            self._on_controlword(0x0002)  # the quick stop command

    def _wall_clock_tick(self) -> bool:
        """The consumer's thread, every ms while the drive brakes after a lost master: the motion
        clock runs by the wall clock's elapsed time unless a SYNC came since the last tick (then
        SYNC runs it). False once the demand is at rest."""
        result = False

        def act() -> None:
            nonlocal result
            now = time.monotonic()
            if self._stop_segment is not None:
                if self.sync_count != self._tick_sync:
                    self._tick_sync = self.sync_count
                elif (elapsed_us := round((now - self._tick_at) * 1e6)) > 0:
                    new_time = self.time_us + elapsed_us
                    self._advance(new_time)
                    self.time_us = new_time
                    self.sample_ms = new_time / 1000.0
                    self._refresh()
            self._tick_at = now
            if self._stop_segment is None:
                for loss in self.master_losses:
                    if loss.standstill is None:
                        loss.standstill = now
                return
            result = True

        self._in_own_thread(act)
        return result

    def run_to(self, mono: float) -> None:
        """Wall clock (the cell's ``Ticker``): sample every whole ms of the drive's own time up to
        ``mono`` (a ``time.monotonic()``), whatever the SYNCs do; send event TPDOs on change."""

        def act() -> None:
            clock = self.motion_clock
            if clock is None or not self.node.has_network():
                return
            new_time = math.floor(clock.at(mono) / 1000.0) * 1000
            if new_time <= self.time_us:
                return
            self._advance(new_time)
            self.time_us = new_time
            self.sample_ms = new_time / 1000.0
            if self._loss_braking and self._stop_segment is None:
                self._loss_braking = False
                for loss in self.master_losses:
                    if loss.standstill is None:
                        loss.standstill = time.monotonic()
            self._refresh()

        self._in_own_thread(act)

    def _in_own_thread(self, action: Callable[[], None]) -> None:
        """Run ``action`` under the lock from a thread of the drive's own (no SDO to abort)."""
        with contextlib.suppress(SdoAbortedError):
            self._guard(action)

    def _fault_reset(self) -> None:
        self.state = SWITCH_ON_DISABLED
        self.store(ERROR_REGISTER, 0, 0)
        if self.has(ERROR_CODE):
            self.store(ERROR_CODE, 0, 0)
        self._on_fault_reset()
        self.send_emcy(od.EMCY_NO_ERROR, 0)

    # --- bus callbacks ----------------------------------------------------------------------------
    def _guard(self, action: Callable[[], None]) -> None:
        with self.lock:
            try:
                action()
            except SdoAbortedError:
                raise
            except Exception as exc:  # a simulator bug must show in the tests, not vanish in a log
                self.internal_errors.append(exc)
                raise SdoAbortedError(ABORT_GENERAL) from exc
            finally:
                self.changed.notify_all()

    def _note_nmt_state(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) >= 2 and data[1] in (0, self.node.id):
            self._nmt_left = self.node.nmt.state

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node.id):
            return

        def act() -> None:
            if self._nmt_left == "OPERATIONAL" and self.node.nmt.state == "STOPPED":
                self._on_nmt_stopped()
            if self.node.nmt.state == "INITIALISING":  # reset node / reset communication
                if data[0] == 0x81:
                    self._reset_application()
                else:
                    self._reset_communication()
                self.boot()
            self.pdo.reload()
            if self.operational:
                self.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def on_rpdo_frame(self, can_id: int, data: bytes) -> None:
        # what an RPDO changes it changes by writing objects, and every write refreshes the state
        def act() -> None:
            if self.operational:
                self.pdo.receive(can_id, data)

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        def act() -> None:
            self.sync_count += 1
            clock = self.motion_clock
            behind = 0
            if clock is None:  # lockstep: one SYNC period per SYNC
                new_time = self.time_us + self.sync_period_us
            else:  # the SYNC instant on the drive's own clock, in order
                mono = arrival(timestamp)
                latched = clock.at(mono)
                new_time = max(self.sync_time_us, math.floor(latched))
                behind = max(self.time_us - new_time, 0)
            if not behind:
                self._advance(new_time)
                self.time_us = new_time
                self.sample_ms = new_time / 1000.0
            self.sync_time_us = new_time
            if self.operational:
                self.pdo.apply_synchronous()
            self._on_sync_validated()
            if clock is not None:
                self._on_sync_clock(latched, mono)
            self._refresh(events=False)
            self.history.append(
                SyncSample(
                    self.sync_count, new_time / 1000.0, self.demand, self.actual, self.ip_active, self.state, behind
                )
            )
            if self.operational:
                self.pdo.transmit_on_sync()
                self.pdo.transmit_events()

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def _on_write(self, index: int, subindex: int, variable: objectdictionary.ODVariable, data: bytes) -> None:
        def act() -> None:
            value = variable.decode_raw(data)
            if is_pdo_object(index):
                self.pdo.check_write(index, subindex, value)
            if index == od.CONSUMER_HEARTBEAT_TIME:
                self._check_consumer_entry(subindex, value)
            if index == od.ABORT_CONNECTION_OPTION_CODE and value not in set(od.AbortConnectionOption):
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # no manufacturer-specific options here
            if index == od.HOMING_METHOD and value not in self.HOMING_METHODS:
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # a method this drive does not have
            self._check_write(index, subindex, value)
            if index == od.MODES_OF_OPERATION and not self.MODES.accepts(value):
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # a mode 0x6502 does not list
            self.node.data_store.setdefault(index, {})[subindex] = bytes(data)  # visible to the actions
            if is_pdo_object(index):
                self.pdo.reload()
            elif index == od.CONSUMER_HEARTBEAT_TIME:
                self._configure_consumer()
            elif index == od.PRODUCER_HEARTBEAT_TIME:
                if value == 0 or self._heartbeat_silenced:
                    self.node.nmt.stop_heartbeat()
                else:
                    self.node.nmt.start_heartbeat(value)
            elif index == od.HIGH_RESOLUTION_TIME_STAMP:
                self.time_stamps.append(value)
            elif index == od.CONTROLWORD:
                self._on_controlword(value)
            elif index == od.MODES_OF_OPERATION:
                old = self.read(od.MODES_OF_OPERATION_DISPLAY)
                self.store(od.MODES_OF_OPERATION_DISPLAY, 0, value)
                self.mode_display = value
                if old != value:
                    if old == od.HOMING_MODE and self._homing is not None:
                        self._interrupt_homing()
                        self._begin_stop(self._deceleration(quick=False))
                    self._on_mode_change(old, value)
            else:
                self._on_object_write(index, subindex, value)
            self._refresh()

        self._guard(act)

    # --- DS402 power state machine ----------------------------------------------------------------
    def _on_controlword(self, cw: int) -> None:
        previous, self._controlword = self._controlword, cw
        state = self.state
        if state == FAULT:
            if cw & CW_FAULT_RESET and not previous & CW_FAULT_RESET:
                self._fault_reset()
            return
        if state == FAULT_REACTION_ACTIVE:
            return
        new = state
        if cw & 0x0002 == 0:  # disable voltage: 7, 9, 10, 12
            if state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
                new = SWITCH_ON_DISABLED
        elif cw & 0x0006 == 0x0002:  # quick stop: 7, 10, 11
            if state in (READY_TO_SWITCH_ON, SWITCHED_ON):
                new = SWITCH_ON_DISABLED
            elif state == OPERATION_ENABLED:
                new = QUICK_STOP_ACTIVE
        elif cw & 0x0007 == 0x0006:  # shutdown: 2, 6, 8
            if state in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                new = READY_TO_SWITCH_ON
        elif cw & 0x000F == 0x0007:  # switch on / disable operation: 3, 5
            if state in (READY_TO_SWITCH_ON, OPERATION_ENABLED):
                new = SWITCHED_ON
        elif cw & 0x000F == 0x000F and state in (READY_TO_SWITCH_ON, SWITCHED_ON, QUICK_STOP_ACTIVE):
            new = OPERATION_ENABLED  # 4, 16 (and 3 + 4 at once, as the EPOS2 accepts)
        if new != state:
            if state == OPERATION_ENABLED:
                self._interrupt_homing()
                if new == QUICK_STOP_ACTIVE:
                    self._begin_stop(self._deceleration(quick=True))
                else:
                    self._abort_motion()
                    self._stop_segment = None
                    self.velocity = self.acceleration = 0.0
            if state == QUICK_STOP_ACTIVE:
                self._stop_segment = None
                self.velocity = self.acceleration = 0.0
            self.state = new
            if new == QUICK_STOP_ACTIVE and self._stop_segment is None:
                self.state = SWITCH_ON_DISABLED  # already at rest: quick stop option code 2
            elif new == QUICK_STOP_ACTIVE:
                self._brake_on_own_clock()
            if new == OPERATION_ENABLED:
                self._enter_operation()
        if self.state == OPERATION_ENABLED:
            if cw & CW_HALT and not previous & CW_HALT:
                self.halts.append(self.sync_count)
                self._begin_stop(self._deceleration(quick=False))
            self._on_mode_bits(previous, cw)

    def _deceleration(self, quick: bool) -> float:
        """Halt: profile deceleration 0x6084; quick stop: 0x6085 where the drive has it. In qc/ms^2."""
        quick_stop = od.QUICK_STOP_DECELERATION_CIA402
        index = quick_stop if quick and self.has(quick_stop) else od.QUICK_STOP_DECELERATION
        rpm_s = max(self.read_or(index, 0, 10000), 1)
        return rpm_s / self._rpm_s_per_qc_ms2

    def _begin_stop(self, deceleration: float) -> None:
        v = self.velocity
        self._abort_motion()
        if abs(v) > 1e-12:
            self._stop_segment = Segment.braking(self.time_us / 1000.0, self.demand, v, deceleration)
        else:  # at rest: the demand settles on its whole count (see Segment.braking)
            self._stop_segment = None
            self.velocity = self.acceleration = 0.0
            self.demand = float(round(self.demand))

    @property
    def halted(self) -> bool:
        """Halt is set now (the master clears it again when it readies the drive for the next run:
        ``halts`` tells whether a run was halted)."""
        return bool(self._controlword & CW_HALT)

    def statusword(self) -> int:
        _mask, value = State402.SW_MASK[self.state]
        word = value
        if self.state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            word |= VOLTAGE_ENABLED
        if self._warning():
            word |= WARNING
        if self.mode_display == od.HOMING_MODE:
            word |= self._homing_status()
        else:
            if self.state == OPERATION_ENABLED and self._stop_segment is None and self._target_reached():
                word |= TARGET_REACHED
            if self.ip_active:
                word |= IP_MODE_ACTIVE
        if self.referenced:
            word |= self.REFERENCED_BIT
        return word

    # --- motion clock -----------------------------------------------------------------------------
    def _advance(self, new_time_us: int) -> None:
        """Run the interpolation from the last SYNC to this one: every whole ms, then the SYNC instant."""
        t = (self.time_us // 1000 + 1) * 1000
        while t <= new_time_us:
            self._sample(t / 1000.0, True)
            t += 1000
        if new_time_us % 1000:
            self._sample(new_time_us / 1000.0, False)

    def _sample(self, t: float, full: bool) -> None:
        self.sample_ms = t
        if self._stop_segment is not None:
            seg = self._stop_segment
            p, v, a = seg.at(t)
            if not self._check_position(p):
                return
            self.demand, self.velocity, self.acceleration = p, v, a
            if t >= seg.end:
                self._stop_segment = None
                self.velocity = self.acceleration = 0.0
                if self.state == QUICK_STOP_ACTIVE:
                    self.state = SWITCH_ON_DISABLED
                elif self.state == FAULT_REACTION_ACTIVE:
                    self.state = FAULT  # braked to rest: the power stage goes off
            return
        if self._homing_moves():
            self._homing_sample(t)
            return
        pva = self._motion_at(t) if self.state == OPERATION_ENABLED else None
        if pva is None or self.state != OPERATION_ENABLED:
            self.velocity = self.acceleration = 0.0
            return
        if not self._check_position(pva[0]) or not self._check_machine(pva[0]):
            return
        self.demand, self.velocity, self.acceleration = pva
        if full:
            self._check_dynamics(self.velocity, self.acceleration)

    def _check_position(self, p: float) -> bool:
        """0x607D bounds every position demand: one outside faults the drive and is not taken."""
        lo = self.read_or(od.SOFTWARE_POSITION_LIMIT, 1, INT32_MIN)
        hi = self.read_or(od.SOFTWARE_POSITION_LIMIT, 2, INT32_MAX)
        if lo <= round(p) <= hi:
            return True
        self.fault(self.EMCY_POSITION_LIMIT, "software position limit 0x607D")
        return False

    def _check_dynamics(self, v: float, a: float) -> None:
        """Default sanity check: 0x607F bounds the demand velocity (fault)."""
        if abs(v) * self._units_per_qc_ms > self.read_or(od.MAX_PROFILE_VELOCITY, 0, 2**32 - 1):
            self.fault(self.EMCY_VELOCITY, "max profile velocity 0x607F")

    @property
    def actual(self) -> int:
        """Position actual value: the simulated axis follows its demand exactly (rounded to qc)."""
        return round(self.demand)

    def _refresh(self, events: bool = True) -> None:
        """Publish the drive's state in its object dictionary (and send event TPDOs on change)."""
        self.publish(od.STATUSWORD, 0, self.statusword())
        demand = min(max(round(self.demand), INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_DEMAND_VALUE, 0, demand)
        actual = min(max(self.actual, INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_ACTUAL_VALUE, 0, actual)
        if self._internal_position:  # no factor group: the same increments
            self.publish(od.POSITION_ACTUAL_INTERNAL_VALUE, 0, actual)
        self._publish()
        if events and self.operational:
            self.pdo.transmit_events()

    # --- resets -----------------------------------------------------------------------------------
    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
            del self.node.data_store[index]

    def _reset_application(self) -> None:
        """Power-on state: defaults from the EDS, switch on disabled (transition 1 is automatic); the
        encoder counts from 0 where the axis stands, not homed."""
        self.origin += getattr(self, "demand", 0.0)
        self.referenced = False
        self._homing = None
        self.node.data_store.clear()
        for (index, subindex), value in getattr(self, "_commissioned", {}).items():
            self.store(index, subindex, value)
        self.state = SWITCH_ON_DISABLED
        self._controlword = 0
        self._stop_segment: Segment | None = None
        self.demand = 0.0
        self.velocity = 0.0
        self.acceleration = 0.0
        self.ip_active = False
        self._reset_profile()
        for index, value in (
            (od.CONTROLWORD, 0),
            (od.MODES_OF_OPERATION_DISPLAY, self.read_or(od.MODES_OF_OPERATION, 0, 0)),
            (ERROR_REGISTER, 0),
        ):
            if self.has(index):
                self.store(index, 0, value)
        self.mode_display = self.read_or(od.MODES_OF_OPERATION_DISPLAY, 0, 0)
        self._refresh(events=False)

    # --- hooks for the profiles -------------------------------------------------------------------
    def _own_values(self) -> dict[tuple[int, int], Value]:
        """The drive's own values of objects its EDS may leave without a default (axes/sim/device.py)."""
        return {}

    def _reset_profile(self) -> None:
        """Clear the profile's own state (power-on)."""

    def _check_write(self, index: int, subindex: int, value: int) -> None:
        """Refuse a write (raise SdoAbortedError) before it is stored."""

    def _on_object_write(self, index: int, subindex: int, value: int) -> None:
        """An object other than the common ones was written (already stored)."""

    def _on_mode_change(self, old: int, new: int) -> None:
        """0x6060 changed."""

    def _ip_mode_selected(self) -> bool:
        """Interpolated position mode is what 0x6061 shows (the Parker selects it through Pr31)."""
        return self.read(od.MODES_OF_OPERATION_DISPLAY) == od.INTERPOLATED_POSITION_MODE

    def _on_mode_bits(self, previous: int, controlword: int) -> None:
        """Controlword bit 4 while operation is enabled: a rising edge asks for ip mode on the next
        SYNC, a falling one brings a running interpolation to a stop; halt (bit 8) holds both. In
        homing mode a rising bit 4 starts homing; halt or bit 4 low interrupts it."""
        if self.mode_display == od.HOMING_MODE and self.MODES.accepts(od.HOMING_MODE):
            running = self._homing is not None and self._homing.state is HomingState.RUNNING
            if controlword & CW_HALT or not controlword & CW_HOMING_START:
                if running:
                    self._interrupt_homing()
                    if not controlword & CW_HALT:  # bit 4 low: brake as a halt would (halt already does)
                        self._begin_stop(self._deceleration(quick=False))
            elif not previous & CW_HOMING_START:
                self._start_homing()
            return
        if not self._ip_mode_selected() or controlword & CW_HALT:
            return
        if controlword & CW_ENABLE_IP and not previous & CW_ENABLE_IP:
            self._ip_requested = True
        elif previous & CW_ENABLE_IP and not controlword & CW_ENABLE_IP and (self.ip_active or self._ip_requested):
            self._begin_stop(self._deceleration(quick=False))

    def _enter_operation(self) -> None:
        """Operation enabled was entered: hold the present position (the demand takes the actual
        position, a whole count, as a drive's position loop does when it is enabled)."""
        self.demand = float(self.actual)
        self.velocity = self.acceleration = 0.0

    def _abort_motion(self) -> None:
        """Stop interpolating at once (fault, disable, halt, quick stop): ip mode inactive."""
        self.ip_active = False

    def _on_fault_reset(self) -> None:
        """A fault was reset."""

    def _on_sync_validated(self) -> None:
        """After a SYNC's synchronous RPDOs were applied: activations and setpoints take effect."""

    def _on_sync_clock(self, instant_us: float, mono: float) -> None:
        """Wall clock: a SYNC arrived at ``mono`` (a ``time.monotonic()``), ``instant_us`` on the motion
        clock (called after ``_on_sync_validated``)."""

    def _motion_at(self, t: float) -> tuple[float, float, float] | None:
        """The interpolation's (position, velocity, acceleration) at motion time t; None: hold."""
        return None

    def _target_reached(self) -> bool:
        return not self.ip_active

    def _warning(self) -> bool:
        return False

    def _publish(self) -> None:
        """Write the profile's status objects."""
