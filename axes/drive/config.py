"""What the axes layer needs to know about a cell: its bus and each axis (drive, scaling, limits).

The YAML reader that fills these lives with the service (``service.config``); the types live here,
below every layer that reads them, so that the axes never import the service or the planner.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.axis import DriveAxis
from pvtflow.axes.drive.scaling import AxisScaling

# python-can interfaces whose bus only simulated drives share: pvtflow's simulated wire (axes/sim/wire,
# a 1 Mbit/s bus with its bit timing) and python-can's own in-process ``virtual`` (frames in no time)
SIMULATED_WIRE = "simwire"
SIMULATION_INTERFACES = frozenset({SIMULATED_WIRE, "virtual"})


@dataclass(frozen=True)
class BusConfig:
    interface: str = "virtual"
    channel: str = "pvtflow"
    bitrate: int = 1_000_000
    sync_period_ms: float = 1.0
    time_stamp: bool = True  # send 0x1013 after every SYNC
    heartbeat_ms: int = 100  # producer time asked of every node (0x1017)
    heartbeat_timeout_factor: float = 3.0  # a node is lost after this many missed periods (either way)
    master_node_id: int = 127  # the master's own heartbeat (0x700 + id), which every drive watches (0x1016)
    master_heartbeat_ms: int = 100  # the master's heartbeat period
    # the longest time between two SYNCs the drives ride out, in SYNC periods (None: the profiles say,
    # axes.master.bus.sync's module docstring); a longer gap halts the motion (FaultKind.SYNC_GAP)
    max_sync_gap_periods: float | None = None
    sync_priority: int = 50  # SCHED_FIFO priority of the thread that sends SYNC (0: do not ask)
    # the bus's other threads run at SCHED_FIFO one below SYNC when SYNC has it (axes.master.bus.sync.lift); off
    # where the drives share the master's interpreter (axes.sim.cell.sharing_the_interpreter): there
    # those threads would take the GIL from the drives, whose answers the quick stop waits for
    lift_bus_threads: bool = True
    tx_retry_ms: float = 2.0  # how long a frame the interface refuses (queue full) is tried again
    quick_stop_confirm_ms: float = 10.0  # the SDO quick stop's answers are waited for this long, then NMT stop
    # EPOS2 records the master may send in one SYNC period, shared by every buffered axis (None: the
    # room the bus budget leaves, axes.master.budget)
    records_per_sync: int | None = None
    # the master's CAN transmit queue in frames (SocketCAN's txqueuelen, 10 by default): what it sends
    # right after one SYNC (SYNC, time stamp, setpoints, records) must fit in it (axes.master.budget)
    tx_queue_frames: int = 10
    # every drive's synchronous status TPDO (statusword and position) goes out on every n-th SYNC
    # (transmission type n, 1..240); the master counts an answer as good for n SYNCs (axes.master.tpdo_rates)
    status_every_syncs: int = 1
    # the event-driven status TPDO (the EPOS2's buffer status): inhibit time 0x1800:03 in ms (None:
    # one SYNC period) and event timer 0x1800:05 in ms (0: sent on a change only)
    status_inhibit_ms: float | None = None
    status_event_timer_ms: int = 0
    # the share of 0x607F / 0x60C5 a fixed-period drive's motion is planned below them
    # (``planning_share``; the EPOS2 plans at its full limits, its FIFO covers timing). 0.2 %: twice the
    # slew of a drive's cycle locked to SYNC (the simulated drives' bound, axes/sim/profiles/sync_lock.py MAX_SLEW,
    # 0.1 %: its speed over real time above the demand it judges); docs/cells.md says why no more
    fixed_period_headroom: float = 0.002
    # wall clock: SYNC, the time stamp, setpoints, records and the quick stop from a process of their own
    # (``axes.master.cyclic.process``), where nothing else of the master runs. None (``auto``): wherever the
    # interface can be opened by another process (socketcan, a served simwire channel) on the wall clock
    # (``axes.master.cyclic.process.runs_cyclic``); True there only (refused elsewhere); False: never
    cyclic_process: bool | None = None
    # with ``cyclic_process``: the interface sends SYNC (socketcan's broadcast manager on a kernel timer; a
    # served simwire: its medium) and the cyclic process paces the setpoints, records and time stamp on its
    # schedule, so that no process's wake times SYNC (axes.master.cyclic.loop, ``CyclicLoop._follow``).
    # None (``auto``): on socketcan and simwire, whose cyclic sends a kernel timer (a medium) times
    interface_sync: bool | None = None
    # the EPOS2 FIFO holds records at most this far beyond the drive's clock (and never fewer than
    # MIN_HELD, axes.master.group.feeder): what the drives hold is what a change of the motion (on-path
    # stop, pause, override: axes.master.splice) cannot take back, and also what rides out a stalled
    # master (the EPOS2's SYNC-gap ride-out is this less a period). 200 ms: the change's computation
    # (3-60 ms in the service, bench/onpath_stop.py) and the records' transfer fit in it, and a master
    # stalled by its host is ridden out as the full FIFO did before the bound (134 ms and more): at 100 ms
    # a master sharing a 2-core host with two CPU-bound processes (and its interpreter with the drives)
    # let every EPOS2 run dry (buffer underflow, EMCY 0xFF0C) in 2 of 12 wall-clock stops; at 50 ms its
    # SYNC gaps of 50-65 ms halted motions. A cell whose master never stalls that long may ask for less:
    # a path stop, a pause and an override begin that much sooner (bench/RESULTS.md, issue 37)
    max_lookahead_ms: float = 200.0

    def planning_share(self, fixed_period: bool) -> float:
        """The factor on an axis's 0x607F and 0x60C5 its plans are made with: ``1 - fixed_period_headroom``
        for a drive that takes one setpoint per SYNC (what is left of timing after its cycle locks to SYNC,
        axes/sim/profiles/sync_lock.py, is whole-count rounding and a period held after a missed setpoint), 1 for a
        buffered one."""
        return 1.0 - self.fixed_period_headroom if fixed_period else 1.0

    @property
    def master_consumer_time_ms(self) -> int:
        """The drives' 0x1016 time for the master's heartbeat: the same number of missed periods as
        the master allows a drive (``heartbeat_timeout_factor``), in whole ms."""
        return math.ceil(self.master_heartbeat_ms * self.heartbeat_timeout_factor)


def shared_interface(interface: str, channel: str) -> bool:
    """Whether another process can open this bus as a node of its own: socketcan (a second socket on
    the channel) and a simulated wire served to other processes (``NAME@127.0.0.1:PORT``). python-can's
    virtual bus and an in-process simwire channel reach this process only; PCAN-Basic gives a channel
    to one client."""
    return interface == "socketcan" or (interface == SIMULATED_WIRE and "@" in channel)


def runs_cyclic(config: BusConfig, clock: Clock) -> bool:
    """Whether the cyclic path runs in a process of its own (``BusConfig.cyclic_process``): never in
    lockstep; ``auto`` wherever another process can open the interface; True is refused elsewhere (by
    ``axes.master.cyclic.process``, with the reason)."""
    if clock is not Clock.WALL:
        return False
    if config.cyclic_process is None:
        return shared_interface(config.interface, config.channel)
    return config.cyclic_process


def interface_times_sync(config: BusConfig) -> bool:
    """Whether the cyclic process has the interface send SYNC (``BusConfig.interface_sync``); ``auto``:
    where a timer outside any Python process times it (socketcan's broadcast manager, a served medium)."""
    if config.interface_sync is None:
        return config.interface in ("socketcan", SIMULATED_WIRE)
    return config.interface_sync


def wire_options(config: BusConfig, *, clock: Clock) -> dict[str, object]:
    """The ``can.Bus`` keyword arguments of the cell's bus beyond interface and channel: the bit rate,
    and on the simulated wire its clock (``Clock.LOCKSTEP``: bus time advances with the SYNC period)."""
    if config.interface == "virtual":
        return {}
    options: dict[str, object] = {"bitrate": config.bitrate}
    if config.interface == SIMULATED_WIRE:
        options["clock"] = clock
        options["sync_period"] = config.sync_period_ms / 1000.0
    return options


@dataclass(frozen=True)
class BufferConfig:
    """EPOS2 0x20C4:02 / :03: the levels the feeder keeps the FIFO between."""

    underflow_warning: int = 4
    overflow_warning: int = 60


@dataclass(frozen=True)
class HomingConfig:
    """How one axis homes (CiA 402 mode 6), written at configuration: 0x6098, 0x6099:01/02, 0x609A,
    0x607C (and maxon's 0x2080 for the hard-stop methods). Speeds in motor rpm, acceleration in rpm/s."""

    method: int  # 0x6098 (axes.drive.objects.HomingMethod)
    switch_speed_rpm: float = 100.0  # 0x6099:01, the search for a switch or a hard stop
    zero_speed_rpm: float = 10.0  # 0x6099:02, the search for the edge or the index pulse
    acceleration_rpm_s: float = 1000.0  # 0x609A
    offset_qc: int = 0  # 0x607C: what the position reads at the home position
    current_threshold_ma: int | None = None  # 0x2080 (EPOS2 methods -1 to -4)
    timeout_s: float = 60.0  # of drive time (SYNC periods): a search that finds nothing ends here
    # qc beyond the limit switch the search runs to before the end of travel (a real machine's: the
    # cell file says; a simulated one's: its hard stop on that side, ``AxisSimulation``)
    overtravel_qc: int | None = None


# the limit switch each switch-seeking method (axes.drive.objects.HomingMethod) runs to at its switch speed
# (-1: the negative one); home-switch and index methods stay inside the travel, hard-stop ones run into it
LIMIT_SWITCH_SIDE = {1: -1, 17: -1, 2: 1, 18: 1}


def homing_stop_room(homing: HomingConfig, scaling: AxisScaling, simulation: AxisSimulation | None) -> str | None:
    """Why an axis cannot stop between the limit switch its homing seeks and the end of travel (None:
    it can, or nothing says where the end of travel is). The stopping distance is the switch speed
    braked at the homing acceleration, v^2 / 2a; the room is ``overtravel_qc``, else the simulated
    machine's hard stop beyond that switch."""
    side = LIMIT_SWITCH_SIDE.get(homing.method)
    if side is None:
        return None
    room, source = homing.overtravel_qc, "homing.overtravel_qc"
    if room is None and simulation is not None:
        switch = simulation.negative_limit_switch_qc if side < 0 else simulation.positive_limit_switch_qc
        stop = simulation.negative_hard_stop_qc if side < 0 else simulation.positive_hard_stop_qc
        if switch is not None and stop is not None:
            room, source = abs(switch - stop), "the simulated hard stop beyond the switch"
    if room is None:
        return None
    v = float(scaling.rpm_to_qc_per_ms(homing.switch_speed_rpm))
    a = float(scaling.rpm_s_to_qc_per_ms2(homing.acceleration_rpm_s))
    distance = v * v / (2.0 * a)
    if distance <= room:
        return None
    return (
        f"at switch_speed_rpm {homing.switch_speed_rpm:g} and acceleration_rpm_s {homing.acceleration_rpm_s:g} "
        f"the axis needs {distance:.0f} qc to stop past the {'negative' if side < 0 else 'positive'} limit "
        f"switch; {source} leaves {room} qc: lower the switch speed or raise the acceleration"
    )


@dataclass(frozen=True)
class AxisSimulation:
    """What a simulated axis's machine has around it (cell file ``simulation:``), in qc of the machine:
    the position the axis reads there once homed. None: not fitted. The axis powers up at
    ``power_up_qc`` or, when None, at a seeded random place between its limit switches / hard stops
    (its 0x607D range where it has neither), while its encoder counts from 0 (incremental)."""

    power_up_qc: int | None = None
    seed: int = 0
    negative_limit_switch_qc: int | None = None  # active at and below
    positive_limit_switch_qc: int | None = None  # active at and above
    home_switch_qc: int | None = None  # the edge of the home switch
    home_switch_active_above: bool = True  # a positive home switch (methods 19/20); False: negative (21/22)
    index_spacing_qc: int | None = None  # an index pulse every this many qc (one per motor revolution)
    index_offset_qc: int = 0  # where one of them is
    negative_hard_stop_qc: int | None = None
    positive_hard_stop_qc: int | None = None
    stall_current_ma: int = 2000  # the current against a hard stop
    moving_current_ma: int = 300  # the current of a free motion at homing speed
    # The drive itself, where it differs from what the cell expects (None: as the cell says), so that a
    # commissioning check can be shown to catch it (axes/master/commission.py): its real encoder (qc per motor
    # revolution; the drive interpolates with it), its polarity 0x607E, its identity 0x1018:01/:02 and
    # its motor's maximal speed (0x6410:04, where the drive has it)
    qc_per_motor_rev: int | None = None
    polarity: int | None = None
    vendor_id: int | None = None
    product_code: int | None = None
    max_motor_speed_rpm: int | None = None
    # maxon's 0x2210:02 position sensor type, 0x2210:04 position sensor polarity, 0x608B velocity
    # notation index, where the drive has them (None: as the cell expects: 1, 0, the cell's unit)
    sensor_type: int | None = None
    sensor_polarity: int | None = None
    velocity_notation_index: int | None = None
    # the simulated drive's dictionary, an EDS under configs/eds (None: its profile's generated one),
    # e.g. ``vendor/maxon-epos2-70-10.eds``: maxon's own EPOS2 70/10 file, objects as a real EPOS2 has
    eds: str | None = None


@dataclass(frozen=True)
class AxisConfig(DriveAxis):
    """A cell's axis: its description (``DriveAxis``) and how its drive is set up."""

    buffer: BufferConfig = field(default_factory=BufferConfig)
    homing: HomingConfig | None = None  # None: nothing to home (an absolute encoder)
    simulation: AxisSimulation | None = None  # the simulated machine around the axis (switches, stops)
    # 0x1018:01/:02 (vendor id, product code) of the axis's drive, accepted besides the profile's known
    # drives (``DriveProfile.identities``) by the commissioning check: a real drive pvtflow has no EDS of
    identity: tuple[int, int] | None = None
    # objects whose commissioning check must be made (axes/master/commission.py): a drive without one is
    # refused (``not_checked`` fails), e.g. a real EPOS2's 0x2210:02, 0x2210:04, 0x608B, 0x608C
    commission_requires: tuple[str, ...] = ()


@dataclass(frozen=True)
class Wiring:
    """A bus and its axes without a cell file (``service.config.CellConfig`` is the other kind)."""

    bus: BusConfig
    axes: tuple[AxisConfig, ...]


class CellWiring(Protocol):
    """The part of a cell description a bus of drives needs: the bus and its axes."""

    @property
    def bus(self) -> BusConfig: ...

    @property
    def axes(self) -> Sequence[AxisConfig]: ...
