"""The cell's bus, opened in one place for the service (``MotionService``) and for the commands that
run without it (``pvtflow execute``, ``home``, ``commission``).

Every one opens it the same way: the simulated drives first where the cell is simulated (for the
commands and ``pvtflow serve`` in a process of their own on the simulated wire: ``axes.sim.process``),
SYNC in lockstep with them unless on the wall clock (``--real-time``), every frame recorded with
``--can-log``; the commands take the same options and close it the same way, whatever happened in
between (SIGTERM included: it counts as Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.service.cli_options import add_can_log, add_config, add_real_time
from pvtflow.service.config import CellConfig


class CellBusError(Exception):
    """The bus cannot be opened (one line for the user); nothing was sent."""


def add_bus_options(p: argparse.ArgumentParser) -> None:
    """--config, --can-log, --record, --quiet, --real-time: what every command that drives a cell alone takes."""
    add_config(p)
    add_can_log(p)
    p.add_argument(
        "--record",
        metavar="FILE.mcap",
        help="record the run (planned and actual per axis, buffers, SYNC, events, every frame) as MCAP "
        "(pvtflow report FILE.mcap; Foxglove)",
    )
    p.add_argument("--quiet", action="store_true", help="print the outcome only")
    add_real_time(p)


def open_bus(
    cell: CellConfig, *, simulate: bool, clock: Clock, can_log: str | Path | None, drives_process: bool = True
) -> tuple[CellBus, Any]:
    """The cell's bus, open, and its simulated drives (None unless ``simulate``), started first: SYNC
    on ``clock``, in lockstep with them or on the wall clock; with ``drives_process`` in a process of their own
    (``axes.sim.process``), else in this one (tests that read a drive directly). The service keeps
    both for its life, a command for one run (:func:`open_cell_bus`). CellBusError where the bus
    cannot open; nothing is left running then."""
    sim: Any = None
    bus_config = cell.bus
    if simulate:
        try:
            if drives_process:
                from pvtflow.axes.sim.process import DrivesProcessError, start_simulated_drives

                try:
                    sim = start_simulated_drives(cell, clock)
                except DrivesProcessError as exc:
                    raise CellBusError(str(exc)) from None
                bus_config = sim.bus
            else:
                from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter

                cell = sharing_the_interpreter(cell)
                bus_config = cell.bus
                sim = SimulatedCell(cell, clock=clock).start()
        except (OSError, ValueError) as exc:
            raise CellBusError(str(exc)) from None
    try:
        bus = CellBus(bus_config, clock=clock, can_log=can_log)
    except (ValueError, OSError) as exc:
        if sim is not None:
            sim.stop()
        raise CellBusError(f"cannot write the CAN log {can_log}: {exc}") from None
    try:
        bus.open()
    except (BusError, OSError) as exc:
        if sim is not None:
            sim.stop()
        bus.recorder.stop()
        raise CellBusError(str(exc)) from None
    return bus, sim


@contextlib.contextmanager
def open_cell_bus(cell: CellConfig, real_time: bool, can_log: str | None) -> Iterator[CellBus]:
    """The cell's bus, open (its simulated drives started first where the cell is simulated, in a
    process of their own); on exit the bus closed and the simulated drives stopped, their process
    reaped. CellBusError where it cannot open."""
    with _terminate_as_interrupt():
        clock = Clock.of(cell.simulated and not real_time)
        bus, sim = open_bus(cell, simulate=cell.simulated, clock=clock, can_log=can_log)
        try:
            yield bus
        finally:
            bus.close()
            if sim is not None:
                sim.stop()


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


@contextlib.contextmanager
def signals_stop(stop: Callable[[str], object]) -> Iterator[None]:
    """Ctrl-C or SIGTERM while a motion runs calls ``stop("interrupted")`` from a thread of its own.

    Raised as KeyboardInterrupt in the main thread, the signal lands between any two bytecodes of the
    start or the wait (a start half done, a lock's block left early); here the handler only notes it,
    and the group's ``stop``, which any thread may call and which a start in progress never loses,
    halts the motion (or the next start, which then moves nothing). A second signal is the same request."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    asked = threading.Event()
    done = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        del signum, frame
        asked.set()

    def stopper() -> None:  # asked again every 50 ms: a start that begins after the signal stops too
        while not done.wait(0.05):
            if asked.is_set():
                stop("interrupted")

    thread = threading.Thread(target=stopper, name="pvtflow-signal-stop", daemon=True)
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    thread.start()
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        done.set()
        thread.join()


def record_problem(path: str) -> str | None:
    """Why ``--record FILE`` cannot be written (one line), before anything is sent; None when it can."""
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
