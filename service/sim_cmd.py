"""``pvtflow sim [--config CELL] [--interface NAME --channel NAME]``: a cell's simulated drives on their own.

The cell's drives (``axes.sim.cell.SimulatedCell``: one per axis, its profile's simulated drive with
the axis's limits and scaling, on its EDS from configs/eds) go on the bus the cell file names, or the
one the flags name, and answer there until Ctrl-C / SIGTERM, with no master of pvtflow's beside them:
so that other tools (candump, a PLC's CANopen master, python-canopen scripts, or ``pvtflow serve`` /
``execute`` in another process with a cell file whose drives they are) run against them, e.g. on a
Linux vcan interface (docs/simulator.md).

The drives boot (boot-up frame, pre-operational) and then do what a master asks: NMT, SDO, PDOs,
SYNC. They send no SYNC: each SYNC a master sends advances their motion clock by the cell's SYNC
period, so the master's SYNC period must be the cell's. Heartbeats (once a master writes 0x1017)
run on the wall clock. A drive's faults are printed as they happen.

Refused: the ``udp_multicast`` interface (it sends to a multicast address; pvtflow only uses
loopback), and a cell whose drives are real (``simulated: false``) unless the flags name the bus:
simulated drives beside real ones with the same node ids would answer in their place.

Exit codes: 0 stopped by a signal, 1 a simulated drive raised internally (a simulator bug, printed),
2 cannot start (configuration, bus).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any, TextIO

import can

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import SIMULATED_WIRE, wire_options
from pvtflow.axes.sim.cell import SimulatedCell
from pvtflow.axes.sim.wire import serve_wire
from pvtflow.service.cli_options import add_config
from pvtflow.service.config import PYTHON_CAN_INTERFACES, CellConfig, ConfigError, load_cell_config

EXIT_OK, EXIT_SIMULATOR_ERROR, EXIT_CANNOT_START = 0, 1, 2
WIRE_SERVED_AT = "wire served at"  # the banner line another process reads the channel from
PROG = "pvtflow sim"
HOMING_MODE = 6  # CiA 402 0x6060: homing mode
REFUSED_INTERFACES = {"udp_multicast": "it sends to a multicast address; pvtflow only uses loopback"}


class SimError(ValueError):
    """Why the simulated drives cannot be put on the bus asked for."""


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "sim",
        help="run a cell's simulated drives on their own, for other CANopen masters and tools (until Ctrl-C)",
        description="Put the cell's simulated drives on its bus (or the one --interface/--channel name) and "
        "let any CiA 402 master, candump or python-canopen script talk to them until Ctrl-C / SIGTERM. "
        "The default configuration is the arm6 demo cell; the virtual interface reaches this process only, "
        "so other tools need a real interface such as a Linux vcan (socketcan).",
    )
    add_config(p)
    p.add_argument("--interface", metavar="NAME", help="python-can interface instead of the cell's (e.g. socketcan)")
    p.add_argument("--channel", metavar="NAME", help="channel instead of the cell's (e.g. vcan0)")
    p.add_argument(
        "--wall-clock",
        action="store_true",
        help="the drives keep their own time (1 ms samples), for a master that sends SYNC on the wall clock "
        "(default: lockstep, one SYNC period per SYNC)",
    )
    p.add_argument(
        "--wire-port",
        metavar="PORT",
        type=int,
        default=0,
        help="on the simulated wire (simwire): serve it on 127.0.0.1:PORT for masters in other processes "
        "(default 0: a free port; the banner names the channel to open)",
    )
    p.set_defaults(run=run)


def choose_bus(cell: CellConfig, interface: str | None, channel: str | None) -> tuple[str, str]:
    """The (interface, channel) the drives go on: the flags' where given, else the cell's."""
    if not cell.simulated and interface is None and channel is None:
        raise SimError(
            f"cell {cell.name} has real drives on {cell.bus.interface}:{cell.bus.channel} (simulated: false); "
            "simulated drives with their node ids would answer beside them: name the bus for the simulation "
            "with --interface and --channel"
        )
    chosen = interface or cell.bus.interface
    if chosen not in PYTHON_CAN_INTERFACES:
        raise SimError(f"unknown python-can interface {chosen!r}")
    if chosen in REFUSED_INTERFACES:
        raise SimError(f"interface {chosen} is refused: {REFUSED_INTERFACES[chosen]}")
    return chosen, channel or cell.bus.channel


def banner(sim: SimulatedCell, served_at: str | None = None) -> str:
    cell = sim.cell
    lines = [
        f"{PROG}: cell {cell.name}: {len(sim.drives)} simulated drives on {sim.interface}:{sim.channel}",
    ]
    if served_at is not None:
        lines.append(
            f"  {WIRE_SERVED_AT} {served_at} (a master in another process opens interface simwire, channel {served_at})"
        )
    homing = [a.node_id for a in cell.ordered_axes() if sim.drive(a.node_id).MODES.accepts(HOMING_MODE)]
    for axis in cell.ordered_axes():
        drive = sim.drive(axis.node_id)
        lines.append(
            f"  node {axis.node_id:3d}  {axis.joint:<10} {drive.PROFILE:<17} "
            f"0x6502=0x{drive.MODES.supported:08X}  {drive.eds_path}"
        )
    clock = (
        "each keeps its own time and samples every ms of it, SYNC latched at its arrival"
        if sim.clock == Clock.WALL
        else f"each SYNC advances their motion clock by {cell.bus.sync_period_ms:g} ms (the cell's SYNC period)"
    )
    lines += [
        f"  pre-operational, waiting for a master (NMT, SDO, PDOs); no SYNC of their own: {clock}",
        "  they move in interpolated position mode (7)"
        + (f", and home in homing mode (6): nodes {', '.join(map(str, homing))}" if homing else "")
        + "; their other supported modes are accepted and hold the position",
    ]
    if sim.interface == "virtual":
        lines.append(
            "  note: the virtual interface reaches this process only; for other tools use e.g. "
            "--interface socketcan --channel vcan0"
        )
    lines.append("  Ctrl-C stops them.")
    return "\n".join(lines)


def simulate(
    cell: CellConfig,
    interface: str,
    channel: str,
    stop: threading.Event,
    out: TextIO | None = None,
    clock: Clock = Clock.LOCKSTEP,
    wire_port: int = 0,
) -> int:
    """Run the cell's simulated drives on (interface, channel) until ``stop`` is set; the exit code.
    On the simulated wire the channel is served on 127.0.0.1:``wire_port`` (0: a free port)."""
    out = out if out is not None else sys.stdout
    sim = SimulatedCell(cell, interface=interface, channel=channel, clock=clock)
    server = None
    try:
        if interface == SIMULATED_WIRE:  # the wire itself lives here: served to the other processes
            options = wire_options(cell.bus, clock=clock)
            server = serve_wire(channel, wire_port, **options)  # type: ignore[arg-type]
        sim.start()
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        sim.stop()
        if server is not None:
            server.close()
        print(f"{PROG}: cannot open {interface}:{channel}: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    joints = {a.node_id: a.joint for a in cell.axes}
    seen = {node_id: 0 for node_id in sim.drives}
    try:
        print(banner(sim, server.address if server is not None else None), file=out, flush=True)
        stopped = False
        while not stopped:
            stopped = stop.wait(0.2)  # faults up to the stop are reported too
            for node_id, drive in sim.drives.items():
                with drive.lock:
                    new = drive.faults[seen[node_id] :]
                seen[node_id] += len(new)
                for f in new:
                    print(
                        f"{PROG}: node {node_id} ({joints[node_id]}): fault, EMCY 0x{f.code:04X}: {f.check} "
                        f"(SYNC {f.sync}, motion time {f.time_ms:g} ms)",
                        file=out,
                        flush=True,
                    )
    finally:
        print(f"{PROG}: stopping", file=out, flush=True)
        sim.stop()
        if server is not None:
            server.close()
    errors = sim.internal_errors
    for exc in errors:
        print(f"{PROG}: a simulated drive raised internally: {exc!r}", file=sys.stderr)
    return EXIT_SIMULATOR_ERROR if errors else EXIT_OK


def run(args: argparse.Namespace) -> int:
    try:
        cell = load_cell_config(args.config)
        interface, channel = choose_bus(cell, args.interface, args.channel)
    except (ConfigError, SimError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        del signum, frame
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        clock = Clock.WALL if args.wall_clock else Clock.LOCKSTEP
        return simulate(cell, interface, channel, stop, clock=clock, wire_port=args.wire_port)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
