"""What every simulated drive shares: a canopen ``LocalNode`` that behaves as a CiA 402 drive.

``SimulatedDrive`` is a node holding its parts, as python-canopen's nodes hold ``.sdo``, ``.nmt`` and
``.pdo``; each owns its state and gets what it needs from the drive in its constructor (the drive's
one lock among them):

* ``dictionary``: its object dictionary as the drive reads and writes it, the commissioned values
  (``axes/sim/node/dictionary.py``);
* ``emcy``: the error objects and the EMCY producer (``axes/sim/node/emcy.py``);
* ``nmt``: the network it is on, boot-up, the NMT commands and the heartbeat producer
  (``axes/sim/node/nmt.py``);
* ``pdo``: its PDOs (``axes/sim/node/pdo.py``);
* ``master_loss``: the heartbeat consumer per 0x1016 and the reaction to a lost master per 0x6007
  (``axes/sim/node/master_loss.py``; the heartbeats are the only wall-clock parts in lockstep);
* ``homing``: the machine around the axis (power-up anywhere, limit switches, hard stops) and homing
  mode 6 on it (``axes/sim/cia402/homing_mode.py``), for drives whose 0x6502 has mode 6;
* ``power``: the DS402 power state machine driven by the controlword, the statusword and the fault
  reaction (``axes/sim/cia402/power_states.py``: the power state, the faults, the halts);
* ``motion``: the SYNC-driven motion clock with 1 kHz interpolation samples, 0x607D on every demand
  sample (``axes/sim/cia402/sampling.py``: the demand, its velocity and acceleration, the braking
  segment, the motion time, the SYNC history).

Here: the SDO writes the drive dispatches, its resets, its face for tests and the master-side code
(``state``, ``demand``, ``faults``, ``read``, ... read through the parts), and the hooks through
which the profile modules (epos2, ip_linear, sync_setpoint, parker) add their interpolation on top.

Threads: every bus callback runs in the simulated network's notifier thread; test code may call in
from other threads, so all state is guarded by one lock (the drive's), and ``changed`` is notified
after each SYNC, write or frame (``wait_until`` waits on it).
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
from canopen.sdo import SdoAbortedError

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import Controlword, PowerState
from pvtflow.axes.drive.config import AxisSimulation
from pvtflow.axes.drive.scaling import INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from pvtflow.axes.sim.cia402.homing_mode import Homing
from pvtflow.axes.sim.cia402.power_states import PowerStateMachine
from pvtflow.axes.sim.cia402.records import FaultRecord, SyncSample
from pvtflow.axes.sim.cia402.sampling import Motion
from pvtflow.axes.sim.clock import MotionClock, Quartz, check_clock
from pvtflow.axes.sim.node.device import (
    SIMULATED_MODE,
    SUPPORTED_DRIVE_MODES,
    DriveModes,
    Value,
    complete_object_dictionary,
    identity_values,
)
from pvtflow.axes.sim.node.dictionary import ABORT_GENERAL, ABORT_VALUE_RANGE, DriveDictionary
from pvtflow.axes.sim.node.emcy import ERROR_REGISTER, REGISTER_GENERIC, Emcy
from pvtflow.axes.sim.node.master_loss import MasterLossReaction
from pvtflow.axes.sim.node.nmt import Nmt
from pvtflow.axes.sim.node.pdo import PdoEngine, is_pdo_object
from pvtflow.configs import EDS_DIR

# maxon's own published EPOS2 70/10 EDS, kept unchanged as a vendor data file (configs/eds/vendor/README.md)
MAXON_EPOS2_EDS = EDS_DIR / "vendor" / "maxon-epos2-70-10.eds"


def eds_file(name: str) -> Path:
    """An EDS the project ships, by its name under configs/eds (``vendor/maxon-epos2-70-10.eds``):
    the dictionary a cell's ``simulation.eds`` gives its simulated drive (ValueError: none such)."""
    path = (EDS_DIR / name).resolve()
    if EDS_DIR.resolve() not in path.parents or path.suffix.lower() != ".eds" or not path.is_file():
        raise ValueError(f"no EDS {name!r} among the shipped ones (configs/eds)")
    return path


class SimulatedDrive:
    """A CiA 402 drive on a canopen network, simulated. Subclasses add one interpolation behaviour."""

    PROFILE: ClassVar[str] = ""
    EDS: ClassVar[str] = ""
    EMCY_POSITION_LIMIT: ClassVar[int] = od.EMCY_SOFTWARE_POSITION_LIMIT
    EMCY_VELOCITY: ClassVar[int] = od.EMCY_VELOCITY_LIMIT
    MODES: ClassVar[DriveModes] = DriveModes((SIMULATED_MODE,))  # 0x6502 / 0x6060 (axes/sim/node/device.py)
    # a lost master's heartbeat is one of the drive's own errors: its fault reaction (0x605E), then FAULT
    HEARTBEAT_ERROR_FAULTS: ClassVar[bool] = False
    HOMING_METHODS: ClassVar[frozenset[int]] = (
        frozenset()
    )  # 0x6098 values it runs in mode 6 (axes/sim/cia402/homing_mode.py)
    REFERENCED_BIT: ClassVar[int] = 0  # a manufacturer statusword bit that says "homed since power-on"
    HOMING: ClassVar[type[Homing]] = Homing  # where the drive places home (the EPOS2's own: epos2.py)
    # the profiles' (epos2.py, fixed_period.py), read here: ip mode active, asked for, since which SYNC
    ip_active: bool = False
    _ip_requested: bool = False
    ip_active_sync: int | None = None

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
        clock: Clock | str = Clock.LOCKSTEP,
        drift_ppm: float = 0.0,
        bitrate: int = 1_000_000,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} is outside 1..127")
        if not (math.isfinite(sync_period_ms) and sync_period_ms > 0):
            raise ValueError(f"sync_period_ms must be positive, got {sync_period_ms!r}")
        self.clock = check_clock(clock, drift_ppm)
        self.quartz = Quartz(drift_ppm)  # the drive's own time on the wall clock (axes/sim/clock.py)
        self.motion_clock: MotionClock | None = None  # wall clock: set when the drive joins a network
        self.eds_path = Path(eds_path) if eds_path is not None else EDS_DIR / self.EDS
        self.node = canopen.LocalNode(node_id, str(self.eds_path))
        own = {**identity_values(self.node.object_dictionary, self.MODES), **self._own_values()}
        complete_object_dictionary(self.node.object_dictionary, own, frozenset({(SUPPORTED_DRIVE_MODES, 0)}))
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.dictionary = DriveDictionary(self.node, self.lock)
        self.emcy = Emcy(self.node, self.dictionary)
        self.scaling = scaling if scaling is not None else AxisScaling(2000.0, 1.0)
        if simulation is not None and simulation.qc_per_motor_rev is not None:  # its own encoder, not the cell's
            self.scaling = replace(self.scaling, qc_per_motor_rev=float(simulation.qc_per_motor_rev))
        self.sync_period_us = round(sync_period_ms * 1000.0)
        if not bitrate > 0:
            raise ValueError(f"bitrate must be positive, got {bitrate!r}")
        self.bitrate = bitrate  # the bus's: how long a SYNC can wait for a frame on the wire
        self.pdo = PdoEngine(self)
        self._internal_position = self.has(od.POSITION_ACTUAL_INTERNAL_VALUE)  # 0x6063 (the Parker's)
        # what tests look at
        self.rejected_writes: list[tuple[int, int, int]] = []
        self.internal_errors: list[BaseException] = []
        self.time_stamps: deque[int] = deque(maxlen=history_length)  # 0x1013 values (us): ``_on_time_stamp``
        self.motion = Motion(self, sync_period_us=self.sync_period_us, history_length=history_length)
        # the factor of DESIGN section 4 and the rpm / rpm/s conversions, from axes.drive.scaling
        self.velocity_factor = self.scaling.qc_per_ms_per_velocity_unit  # record velocity unit -> qc/ms
        self._rpm_per_qc_ms = float(self.scaling.qc_per_ms_to_rpm(1.0))
        # velocity objects (0x607F, 0x6081, 0x6099) in the drive's velocity unit, as the master writes them
        self._units_per_qc_ms = self._rpm_per_qc_ms / self.scaling.velocity_unit_rpm
        self._rpm_s_per_qc_ms2 = float(self.scaling.qc_per_ms2_to_rpm_s(1.0))
        # the machine: where the encoder's 0 is (the machine position = demand + origin; an incremental
        # encoder counts from 0 wherever the axis stands at power-on), switches, index pulse, hard stops
        self.power = PowerStateMachine(self, rpm_s_per_qc_ms2=self._rpm_s_per_qc_ms2)
        self.master_loss = MasterLossReaction(
            self, heartbeat_error_faults=self.HEARTBEAT_ERROR_FAULTS, rpm_per_qc_ms=self._rpm_per_qc_ms
        )
        self.nmt = Nmt(self)
        self.homing = self.HOMING(
            node_id,
            simulation,
            limits,
            self.dictionary,
            units_per_qc_ms=self._units_per_qc_ms,
            rpm_s_per_qc_ms2=self._rpm_s_per_qc_ms2,
        )
        self.node._write_callbacks.remove(self.node.nmt.on_write)  # 0x1017 is handled here
        # canopen passes the written entry as the keyword ``od``, which is this module's name for axes.drive.objects
        self.node.add_write_callback(lambda index, subindex, od, data: self._on_write(index, subindex, od, data))
        self._reset_application()
        if limits is not None:
            self.apply_limits(limits)
        self.dictionary.commission(self.dictionary.drive_fact_values(simulation or AxisSimulation(), self.scaling))
        if network is not None:
            self.attach(network)

    # --- the object dictionary, as the drive itself reads and writes it (``dictionary``) ------------
    def has(self, index: int, subindex: int = 0) -> bool:
        return self.dictionary.has(index, subindex)

    def read(self, index: int, subindex: int = 0) -> int:
        return self.dictionary.read(index, subindex)

    def read_or(self, index: int, subindex: int, default: int) -> int:
        return self.dictionary.read_or(index, subindex, default)

    def store(self, index: int, subindex: int, value: int) -> None:
        self.dictionary.store(index, subindex, value)

    def publish(self, index: int, subindex: int, value: int) -> None:
        self.dictionary.publish(index, subindex, value)

    def send_emcy(self, code: int, register: int | None = None, data: bytes = b"") -> None:
        self.emcy.send(code, register, data)

    def apply_limits(self, limits: DriveLimits) -> None:
        """Commission the drive's own limit objects (facts about the drive, DESIGN section 3)."""
        self.dictionary.commission(self.dictionary.limit_values(limits, self.scaling))

    # --- on a network (NMT: ``nmt``) ---------------------------------------------------------------
    @property
    def node_id(self) -> int:
        return self.node.id

    @property
    def network(self) -> canopen.Network:
        return self.nmt.network

    def attach(self, network: canopen.Network) -> None:
        """Join a network (not yet booted: call ``boot`` once the network is connected)."""
        self.nmt.join(network)
        if self.clock is Clock.WALL:
            with self.lock:
                self.motion_clock = MotionClock(self.quartz, float(self.time_us), time.monotonic())
        subscribe(network, od.SYNC_COB_ID, self.motion.on_sync)
        self.master_loss.consumer.attach(network)

    def detach(self) -> None:
        self.master_loss.consumer.detach()  # joins its thread, which takes the lock: before taking it
        with self.lock:
            if not self.node.has_network():
                return
            self.node.nmt.stop_heartbeat()
            self.pdo.unsubscribe()
            unsubscribe(self.network, od.SYNC_COB_ID, self.motion.on_sync)
            self.nmt.leave()

    def boot(self) -> None:
        """Power on: boot-up message, then pre-operational with the heartbeat of 0x1017."""
        self.nmt.boot()

    @property
    def nmt_state(self) -> str:
        return self.nmt.state

    @property
    def operational(self) -> bool:
        return self.nmt.operational

    # --- the motion (``motion``) ----------------------------------------------------------------------
    @property
    def demand(self) -> float:
        return self.motion.demand

    @demand.setter
    def demand(self, value: float) -> None:
        """The axis moved by hand (a test pushes it): the demand takes ``value`` at once."""
        self.motion.jump_to(value)

    @property
    def velocity(self) -> float:
        return self.motion.velocity

    @property
    def acceleration(self) -> float:
        return self.motion.acceleration

    @property
    def actual(self) -> int:
        return self.motion.actual

    @property
    def time_us(self) -> int:
        return self.motion.time_us

    @property
    def sync_time_us(self) -> int:
        return self.motion.sync_time_us

    @property
    def sample_ms(self) -> float:
        return self.motion.sample_ms

    @property
    def sync_count(self) -> int:
        return self.motion.sync_count

    @property
    def history(self) -> deque[SyncSample]:
        return self.motion.history

    def run_to(self, mono: float) -> None:
        """Wall clock (the cell's ``Ticker``): sample the drive's own time up to ``mono`` (``Motion.run_to``)."""
        self.motion.run_to(mono)

    def _refresh(self, events: bool = True) -> None:
        """Publish the drive's state in its object dictionary (and send event TPDOs on change)."""
        self.publish(od.STATUSWORD, 0, self.power.statusword())
        demand = min(max(round(self.motion.demand), INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_DEMAND_VALUE, 0, demand)
        actual = min(max(self.motion.actual, INT32_MIN), INT32_MAX)
        self.publish(od.POSITION_ACTUAL_VALUE, 0, actual)
        if self._internal_position:  # no factor group: the same increments
            self.publish(od.POSITION_ACTUAL_INTERNAL_VALUE, 0, actual)
        self._publish()
        if events and self.operational:
            self.pdo.transmit_events()

    # --- the power state machine and the fault reaction (``power``) ---------------------------------
    @property
    def state(self) -> PowerState:
        return self.power.state

    @property
    def faults(self) -> list[FaultRecord]:
        return self.power.faults

    @property
    def halts(self) -> list[int]:
        return self.power.halts

    @property
    def halted(self) -> bool:
        return self.power.halted

    def statusword(self) -> int:
        return self.power.statusword()

    def fault(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        self.power.fault(code, check, data, register)

    def fault_braking(self, code: int, check: str, data: bytes = b"", register: int = REGISTER_GENERIC) -> None:
        self.power.fault_braking(code, check, data, register)

    def _on_controlword(self, cw: int) -> None:
        self.power.on_controlword(cw)

    def inject_emcy(self, code: int, *, fault: bool = True, data: bytes = b"") -> None:
        """Raise an error as the drive would: EMCY with ``code`` and, by default, the fault state."""
        with self.lock:
            if fault:
                self.power.fault(code, "injected", data)
            else:
                self.emcy.send(code, data=data)
            self._refresh()

    def power_cycle(self) -> None:
        """Power off and on: the encoder counts from 0 again where the axis stands, not homed, boot-up."""
        with self.lock:
            self._reset_application()
            if self.node.has_network():
                self.boot()
            self.changed.notify_all()

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

    def _in_own_thread(self, action: Callable[[], None]) -> None:
        """Run ``action`` under the lock from a thread of the drive's own (no SDO to abort)."""
        with contextlib.suppress(SdoAbortedError):
            self._guard(action)

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

    def on_rpdo_frame(self, can_id: int, data: bytes) -> None:
        # what an RPDO changes it changes by writing objects, and every write refreshes the state
        def act() -> None:
            if self.operational:
                self.pdo.receive(can_id, data)

        with contextlib.suppress(SdoAbortedError):
            self._guard(act)

    def _on_write(self, index: int, subindex: int, variable: objectdictionary.ODVariable, data: bytes) -> None:
        def act() -> None:
            value = variable.decode_raw(data)
            if is_pdo_object(index):
                self.pdo.check_write(index, subindex, value)
            if index == od.CONSUMER_HEARTBEAT_TIME:
                self.master_loss.check_consumer_entry(subindex, value)
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
                self.master_loss.configure_consumer()
            elif index == od.PRODUCER_HEARTBEAT_TIME:
                self.nmt.heartbeat_time_written(value)
            elif index == od.HIGH_RESOLUTION_TIME_STAMP:
                self.time_stamps.append(value)
                self._on_time_stamp(value)
            elif index == od.CONTROLWORD:
                self.power.on_controlword(value)
            elif index == od.MODES_OF_OPERATION:
                old = self.read(od.MODES_OF_OPERATION_DISPLAY)
                self.store(od.MODES_OF_OPERATION_DISPLAY, 0, value)
                self.mode_display = value
                if old != value:
                    if old == od.HOMING_MODE and self.homing.run is not None:
                        self.homing.interrupt()
                        self.motion.begin_stop(self.power.deceleration(quick=False))
                    self._on_mode_change(old, value)
            else:
                self._on_object_write(index, subindex, value)
            self._refresh()

        self._guard(act)

    def _reset_application(self) -> None:
        """Power-on state: defaults from the EDS, switch on disabled (transition 1 is automatic); the
        encoder counts from 0 where the axis stands, not homed."""
        self.homing.power_on(getattr(self, "demand", 0.0))
        self.dictionary.power_on()
        self.power.power_on()
        self.motion.reset()
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

    def _own_values(self) -> dict[tuple[int, int], Value]:
        """The drive's own values of objects its EDS may leave without a default (axes/sim/node/device.py)."""
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
            running = self.homing.running
            if controlword & Controlword.HALT or not controlword & Controlword.HOMING_START:
                if running:
                    self.homing.interrupt()
                    if not controlword & Controlword.HALT:  # bit 4 low: brake as a halt would (halt already does)
                        self.motion.begin_stop(self.power.deceleration(quick=False))
            elif not previous & Controlword.HOMING_START:
                self._start_homing()
            return
        if not self._ip_mode_selected() or controlword & Controlword.HALT:
            return
        if controlword & Controlword.ENABLE_IP_MODE and not previous & Controlword.ENABLE_IP_MODE:
            self._request_ip()
        elif (
            previous & Controlword.ENABLE_IP_MODE
            and not controlword & Controlword.ENABLE_IP_MODE
            and (self.ip_active or self._ip_requested)
        ):
            self.motion.begin_stop(self.power.deceleration(quick=False))

    def _start_homing(self) -> None:
        """Controlword bit 4 rose in mode 6 (``homing``); a run that attained home at once stands there."""
        attained = self.homing.start(self.demand, self.time_us / 1000.0)
        if attained is not None:
            self.motion.stand_at(attained)

    @property
    def machine_position(self) -> float:
        """Where the axis really is (qc of the machine): what its position reads once correctly homed."""
        return self.homing.machine_position(self.demand)

    def _enter_operation(self) -> None:
        """Operation enabled was entered: hold the present position (the demand takes the actual
        position, a whole count, as a drive's position loop does when it is enabled)."""
        self.motion.hold_actual()

    def _abort_motion(self) -> None:
        """Stop interpolating at once (fault, disable, halt, quick stop): ip mode inactive (the profiles')."""

    def _request_ip(self) -> None:
        """Bit 4 rose: ip mode starts on the next SYNC (the profiles')."""

    def _on_fault_reset(self) -> None:
        """A fault was reset."""

    def _on_time_stamp(self, stamp_us: int) -> None:
        """The master's 0x1013 (us) arrived: a drive that synchronizes its clock by it does so (the EPOS2)."""

    def _on_sync_validated(self) -> None:
        """After a SYNC's synchronous RPDOs were applied: activations and setpoints take effect."""

    def _on_sync_clock(self, instant_us: float, mono: float) -> None:
        """Wall clock: a SYNC arrived at ``mono`` (a ``time.monotonic()``), ``instant_us`` on the motion
        clock (called after ``_on_sync_validated``)."""

    def _sync_instant(self, latched_us: float, mono: float) -> float:
        """Wall clock: the motion time at which a SYNC latched at ``latched_us`` takes effect (the
        fixed-period drives: their locked cycle, axes/sim/profiles/sync_lock.py)."""
        return latched_us

    def _sample_horizon(self, new_time_us: int, now_us: float) -> int:
        """Wall clock: the sample time the ticker may advance to at motion time ``now_us``."""
        return new_time_us

    def _check_dynamics(self, v: float, a: float) -> None:
        """Default sanity check on every whole-ms sample: 0x607F bounds the demand velocity (fault)."""
        if abs(v) * self._units_per_qc_ms > self.read_or(od.MAX_PROFILE_VELOCITY, 0, 2**32 - 1):
            self.power.fault(self.EMCY_VELOCITY, "max profile velocity 0x607F")

    def _motion_at(self, t: float) -> tuple[float, float, float] | None:
        """The interpolation's (position, velocity, acceleration) at motion time t; None: hold."""
        return None

    def _target_reached(self) -> bool:
        return not self.ip_active

    def _warning(self) -> bool:
        return False

    def _publish(self) -> None:
        """Write the profile's status objects."""
