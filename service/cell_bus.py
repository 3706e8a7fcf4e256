"""The cell's bus for a command that runs without the service (``pvtflow execute``, ``pvtflow home``).

Both take the same options and open the bus the same way: the simulated drives first where the
cell is simulated (in a process of their own on the simulated wire: ``axes.sim.process``), SYNC
in lockstep with them unless ``--real-time``, every frame recorded with ``--can-log``; and both
close it the same way, whatever happened in between (SIGTERM included: it counts as Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import threading
from collections.abc import Iterator

from axes.bus import BusError, CellBus
from service.config import CellConfig


class CellBusError(Exception):
    """The bus cannot be opened (one line for the user); nothing was sent."""


def add_bus_options(p: argparse.ArgumentParser) -> None:
    """--config, --can-log, --record, --quiet, --real-time: what every command that drives a cell alone takes."""
    p.add_argument("--config", metavar="FILE", help="cell configuration YAML (default: the arm6 demo cell)")
    p.add_argument("--can-log", metavar="FILE", help="record every CAN frame (.log candump, .asc or .blf)")
    p.add_argument(
        "--record",
        metavar="FILE.mcap",
        help="record the run (planned and actual per axis, buffers, SYNC, events, every frame) as MCAP "
        "(pvtflow report FILE.mcap; Foxglove)",
    )
    p.add_argument("--quiet", action="store_true", help="print the outcome only")
    p.add_argument(
        "--real-time",
        action="store_true",
        help="a simulated cell runs SYNC on the wall clock, as a real cell does (default there: lockstep, "
        "faster than real time)",
    )


@contextlib.contextmanager
def open_cell_bus(cell: CellConfig, real_time: bool, can_log: str | None) -> Iterator[CellBus]:
    """The cell's bus, open (its simulated drives started first where the cell is simulated: in a
    process of their own on the simulated wire, ``axes.sim.process``); on exit the bus closed and
    the simulated drives stopped, their process reaped. CellBusError where it cannot open."""
    with _terminate_as_interrupt():
        yield from _open(cell, real_time, can_log)


def _open(cell: CellConfig, real_time: bool, can_log: str | None) -> Iterator[CellBus]:
    drives = None
    bus_config = cell.bus
    if cell.simulated:
        from axes.sim.process import DrivesProcessError, start_simulated_drives

        try:
            drives = start_simulated_drives(cell, "wall" if real_time else "lockstep")
        except (DrivesProcessError, OSError, ValueError) as exc:
            raise CellBusError(str(exc)) from None
        bus_config = drives.bus
    try:
        try:
            bus = CellBus(bus_config, lockstep=cell.simulated and not real_time, can_log=can_log)
        except (ValueError, OSError) as exc:
            raise CellBusError(f"cannot write the CAN log {can_log}: {exc}") from None
        try:
            bus.open()
        except (BusError, OSError) as exc:
            bus.recorder.stop()
            raise CellBusError(str(exc)) from None
        try:
            yield bus
        finally:
            bus.close()
    finally:
        if drives is not None:
            drives.stop()


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM while the bus is open counts as Ctrl-C: the motion halts, the bus closes and the
    simulated drives' process is reaped, where the default action would end the master at once."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        yield
        return

    def on_terminate(signum: int, frame: object) -> None:
        del signum, frame
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def record_problem(path: str) -> str | None:
    """Why ``--record FILE`` cannot be written (one line), before anything is sent; None when it can."""
    from pathlib import Path

    target = Path(path)
    if target.suffix.lower() != ".mcap":
        return f"--record {path}: the recording is an MCAP file: name it FILE.mcap"
    if target.is_dir():
        return f"--record {path}: is a directory"
    if not target.parent.is_dir():
        return f"--record {path}: no directory {target.parent}"
    existed = target.exists()
    try:
        target.open("ab").close()  # writable (a file that exists is left as it is until the run)
    except OSError as exc:
        return f"--record {path}: cannot write: {exc.strerror or exc}"
    if not existed:
        target.unlink()
    return None
