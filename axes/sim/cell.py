"""A cell of simulated drives: one per axis of a ``CellConfig``, on their own canopen Network.

The simulated network is a second python-can bus on the same channel as the master's (on the
``virtual`` interface every bus of a channel sees the others' frames), so the master talks to the
drives exactly as it would to real ones. Each drive is commissioned with its axis's drive limits
(0x607F, 0x60C5, 0x607D, 0x6081/0x6083: facts about the drive, DESIGN section 3) and runs its
motion clock at the bus's SYNC period; everything else (modes, periods, PDOs, heartbeat) is left
to the master to configure.

``clock="lockstep"`` (default): each SYNC advances every drive by one SYNC period, for deterministic
tests and runs faster than real time. ``clock="wall"``: each drive keeps its own time and one
``Ticker`` thread for the whole cell samples every drive every ms of it (axes/sim/clock.py), for a
master that runs SYNC on the wall clock.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from pathlib import Path
from types import TracebackType
from typing import TypeVar

import canopen

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import SIMULATED_WIRE, AxisConfig, CellWiring, wire_options
from pvtflow.axes.sim.clock import Ticker, check_clock
from pvtflow.axes.sim.drive import SimulatedDrive, eds_file
from pvtflow.axes.sim.profiles.epos2 import Epos2Drive
from pvtflow.axes.sim.profiles.ip_linear import IpLinearDrive
from pvtflow.axes.sim.profiles.parker import ParkerDrive
from pvtflow.axes.sim.profiles.sync_setpoint import SyncSetpointDrive
from pvtflow.axes.sim.wire import Medium, SimWireBus

# Drives in the master's own interpreter share its pauses (a compile, a long replay, the host's load),
# so a heartbeat window of about 3 periods (the shipped cells, for drives in a process of their own:
# axes.sim.process) would take those pauses for lost nodes, and their answers to an SDO quick stop
# wait for the master's threads to hand over the GIL. In one interpreter both windows are widened,
# and the master's bus threads stay at normal priority (BusConfig.lift_bus_threads): lifted, they take
# the GIL from the drives, whose quick stop answers then came later (bench/stop_paths.py).
SHARED_INTERPRETER_HEARTBEAT_FACTOR = 10.0
SHARED_INTERPRETER_QUICK_STOP_CONFIRM_MS = 50.0

W = TypeVar("W", bound=CellWiring)


def sharing_the_interpreter(wiring: W) -> W:
    """``wiring`` as run with its simulated drives in the master's interpreter: heartbeat window at
    least ``SHARED_INTERPRETER_HEARTBEAT_FACTOR`` periods (either way: drives and master), SDO quick
    stop confirmations awaited at least ``SHARED_INTERPRETER_QUICK_STOP_CONFIRM_MS``, the master's bus
    threads not lifted to SYNC's priority."""
    bus = wiring.bus
    factor = max(bus.heartbeat_timeout_factor, SHARED_INTERPRETER_HEARTBEAT_FACTOR)
    confirm_ms = max(bus.quick_stop_confirm_ms, SHARED_INTERPRETER_QUICK_STOP_CONFIRM_MS)
    if (factor, confirm_ms, False) == (bus.heartbeat_timeout_factor, bus.quick_stop_confirm_ms, bus.lift_bus_threads):
        return wiring
    bus = replace(bus, heartbeat_timeout_factor=factor, quick_stop_confirm_ms=confirm_ms, lift_bus_threads=False)
    return replace(wiring, bus=bus)  # type: ignore[type-var]


DRIVE_CLASSES: dict[str, type[SimulatedDrive]] = {
    cls.PROFILE: cls for cls in (Epos2Drive, IpLinearDrive, SyncSetpointDrive, ParkerDrive)
}


def make_drive(
    axis: AxisConfig,
    sync_period_ms: float,
    network: canopen.Network | None = None,
    eds_path: str | Path | None = None,
    history_length: int = 20_000,
    clock: Clock | str = Clock.LOCKSTEP,
    bitrate: int = 1_000_000,
) -> SimulatedDrive:
    """The simulated drive for one configured axis (its profile's class, its scaling and limits)."""
    cls = DRIVE_CLASSES[axis.profile]
    if eds_path is None and axis.simulation is not None and axis.simulation.eds is not None:
        eds_path = eds_file(axis.simulation.eds)
    return cls(
        axis.node_id,
        network,
        eds_path,
        scaling=axis.scaling,
        limits=axis.limits,
        sync_period_ms=sync_period_ms,
        history_length=history_length,
        simulation=axis.simulation,
        clock=clock,
        bitrate=bitrate,
    )


def accept_subscribed(network: canopen.Network) -> None:
    """The drive's controller passes only the identifiers its network subscribes to (what canopen's
    ``Network.notify`` would hand to anyone; the drives do not use its node scanner): on the
    simulated wire every frame of every node otherwise woke every drive's receive thread, three to
    six GIL hand-overs per frame in the drives' process for frames each drive then drops."""
    subscribers = network.subscribers
    network.bus.accept_only(lambda can_id: can_id in subscribers)


class SimulatedCell:
    """Simulated drives for every axis of a cell. ``start()`` connects and boots them; ``stop()`` ends."""

    def __init__(
        self,
        cell: CellWiring,
        *,
        channel: str | None = None,
        interface: str | None = None,
        eds_paths: Mapping[int, str | Path] | None = None,
        history_length: int = 20_000,
        clock: Clock | str = Clock.LOCKSTEP,
    ) -> None:
        self.cell = cell
        self.clock = check_clock(clock)
        self.interface = interface or cell.bus.interface
        self.channel = channel or cell.bus.channel
        self.drives: dict[int, SimulatedDrive] = {}
        eds_paths = eds_paths or {}
        for axis in cell.axes:
            self.drives[axis.node_id] = make_drive(
                axis,
                cell.bus.sync_period_ms,
                None,
                eds_paths.get(axis.node_id),
                history_length,
                self.clock,
                cell.bus.bitrate,
            )
        # one network, so one CAN controller and transmit queue, per drive, as on a machine: on the
        # simulated wire six drives behind one controller would queue each other's answers
        self.networks: dict[int, canopen.Network] = {}
        for node_id in self.drives:
            network = self.networks[node_id] = canopen.Network()
            network.NOTIFIER_CYCLE = 0.05  # the notifier thread notices a stop this quickly
        self._joint_to_node = {a.joint: a.node_id for a in cell.axes}
        self.ticker = None if self.clock.lockstep else Ticker(self.drives.values(), name="sim-ticker")
        self.running = False

    def start(self) -> SimulatedCell:
        """Connect to the bus and power the drives on (boot-up frames, then pre-operational)."""
        if self.running:
            return self
        bus = replace(self.cell.bus, interface=self.interface, channel=self.channel)
        options = wire_options(bus, clock=self.clock)
        try:
            for node_id, network in self.networks.items():
                named = {"node_name": f"drive {node_id}"} if self.interface == SIMULATED_WIRE else {}
                network.connect(
                    interface=self.interface, channel=self.channel, receive_own_messages=False, **options, **named
                )
        except BaseException:
            self._disconnect()
            raise
        for node_id, drive in self.drives.items():
            drive.attach(self.networks[node_id])
        if self.interface == SIMULATED_WIRE:
            for network in self.networks.values():
                accept_subscribed(network)
            if self.ticker is not None:
                self.ticker.horizon = self._heard_until()
        for drive in self.drives.values():
            drive.boot()
        if self.ticker is not None:
            self.ticker.start()
        self.running = True
        return self

    def _heard_until(self) -> Callable[[], float] | None:
        """The ``time.monotonic()`` up to which every drive has heard the wire (``Ticker``'s horizon): the
        in-process medium's deliveries, less what a drive's reader has not handled yet; None: a medium
        elsewhere (its frames reach the drives as a real bus's would, stamped on arrival)."""
        buses = [network.bus for network in self.networks.values()]
        if not buses or not all(isinstance(bus, SimWireBus) and isinstance(bus.medium, Medium) for bus in buses):
            return None
        media = {id(bus.medium): bus.medium for bus in buses}
        if len(media) != 1:
            return None
        (medium,) = media.values()

        def heard_until() -> float:
            delivered = medium.delivered_until()
            return min(bus.taken_until(delivered) for bus in buses) - medium.epoch

        return heard_until

    def stop(self) -> None:
        """Power off: heartbeats stop, the drives leave the bus."""
        if not self.running:
            return
        if self.ticker is not None:
            self.ticker.stop()
        for drive in self.drives.values():
            drive.detach()
        self._disconnect()
        self.running = False

    def _disconnect(self) -> None:
        for network in self.networks.values():
            if network.bus is not None:
                network.disconnect()

    @property
    def network(self) -> canopen.Network:
        """A network on the cell's bus (the first drive's): what a listener of every frame needs."""
        return next(iter(self.networks.values()))

    def __enter__(self) -> SimulatedCell:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def drive(self, key: int | str) -> SimulatedDrive:
        """A drive by node id or by joint name."""
        node_id = self._joint_to_node[key] if isinstance(key, str) else key
        return self.drives[node_id]

    def __iter__(self) -> Iterator[SimulatedDrive]:
        return iter(self.drives.values())

    def wait_sync(self, count: int, timeout: float = 5.0) -> bool:
        """Wait until every drive has processed its ``count``-th SYNC."""
        return all(d.wait_sync(count, timeout) for d in self.drives.values())

    @property
    def internal_errors(self) -> list[BaseException]:
        """Exceptions raised inside any drive's bus callbacks (empty when the simulation is sound)."""
        return [e for d in self.drives.values() for e in d.internal_errors]
