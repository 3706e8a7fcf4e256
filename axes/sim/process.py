"""A cell's simulated drives in a process of their own, on the simulated wire that process serves.

The user-facing commands (``pvtflow serve``, ``execute``, ``home``, ``commission``) with simulated
drives on ``simwire`` run the drives here, not in the master's interpreter: the drives' threads
(a canopen Notifier per drive, the wall-clock ticker, SDO servers) then take no GIL from the
master's SYNC thread, and the master's planning, zenoh and recording take none from the drives'
clocks and heartbeats. So a drive's heartbeat consumer can watch the master at the real bus's
3 periods, and the master sees the drives as it sees real ones: frames on a bus, nothing shared.
The in-process ``SimulatedCell`` stays for unit-test rigs that read a drive's state directly.

``DrivesProcess(wiring, clock).start()`` runs ``python -m pvtflow.axes.sim.process``: the child reads the
cell's wiring (``axes.drive.config.Wiring``, pickled, one base64 line on its stdin), starts its
``SimulatedCell`` on the wire's channel, serves the wire on 127.0.0.1 (a free port) and prints
``wire served at NAME@127.0.0.1:PORT``; the master opens that channel (``DrivesProcess.bus``: the
cell's bus with the served channel). The child ends when its stdin closes: ``stop()`` closes it
(then SIGTERM, then SIGKILL, each after a bound), and so does the kernel when the master dies by
any means (SIGKILL included), so no drives outlive their master. The child runs in a session of its
own and ignores SIGINT: a Ctrl-C at the terminal reaches the master, which halts the motion on
drives that are still there, then stops them.
"""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import os
import pickle
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import TextIO

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import ask_drives_priority, hand_the_gil_on_often
from pvtflow.axes.drive.config import SIMULATED_WIRE, BusConfig, CellWiring, Wiring, wire_options

WIRE_SERVED_AT = "wire served at"  # the line the master reads the channel from
START_TIMEOUT_S = 60.0  # a loaded host imports canopen and numpy slowly
STOP_TIMEOUT_S = 5.0
EXIT_OK, EXIT_SIMULATOR_ERROR, EXIT_CANNOT_START = 0, 1, 2
DRIVES_NICE = -10  # the drives' process's share of the CPU where SCHED_FIFO is not theirs (``raise_drives_share``)
# where this code's top-level package is imported from (a clone, or site-packages): the child imports the same code
ROOT = Path(sys.modules[__name__.partition(".")[0]].__file__ or "").resolve().parent.parent


class DrivesProcessError(RuntimeError):
    """The drives' process did not come up (one line: what it said)."""


class DrivesProcess:
    """The child process of a cell's simulated drives; ``bus`` is what the master opens."""

    def __init__(self, wiring: CellWiring, clock: str) -> None:
        if wiring.bus.interface != SIMULATED_WIRE:
            raise ValueError(
                f"simulated drives in their own process need the simulated wire, not {wiring.bus.interface}"
            )
        self.wiring = Wiring(bus=wiring.bus, axes=tuple(wiring.axes))
        self.clock = clock
        self.process: subprocess.Popen[str] | None = None
        self.address: str | None = None

    @property
    def bus(self) -> BusConfig:
        """The cell's bus as the master opens it: the channel the child serves."""
        if self.address is None:
            raise RuntimeError("the drives' process is not started")
        return dataclasses.replace(self.wiring.bus, channel=self.address)

    def start(self) -> DrivesProcess:
        payload = base64.b64encode(pickle.dumps(self.wiring)).decode()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "pvtflow.axes.sim.process", self.clock],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            start_new_session=True,
        )
        try:
            assert self.process.stdin is not None and self.process.stdout is not None
            self.process.stdin.write(payload + "\n")
            self.process.stdin.flush()
            self.address = self._read_address(self.process.stdout)
        except BaseException:
            self.stop()
            raise
        return self

    def _read_address(self, stdout: TextIO) -> str:
        said: list[str] = []
        found: list[str] = []

        def read() -> None:
            for line in stdout:
                if WIRE_SERVED_AT in line:
                    found.append(line.split(WIRE_SERVED_AT, 1)[1].split()[0])
                    return
                said.append(line.strip())

        reader = threading.Thread(target=read, name="sim-drives-banner", daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        if found:
            return found[0]
        code = self.process.poll() if self.process is not None else None
        why = "; ".join(s for s in said if s) or (
            f"it exited with {code}" if code is not None else f"no answer within {START_TIMEOUT_S:g} s"
        )
        raise DrivesProcessError(f"the simulated drives did not start: {why}")

    def stop(self) -> int | None:
        """End the child and reap it (stdin closed, then SIGTERM, then SIGKILL); its exit code."""
        process = self.process
        if process is None:
            return None
        with contextlib.suppress(OSError, ValueError):
            process.stdin.close()
        for escalate in (None, process.terminate, process.kill):
            if escalate is not None:
                with contextlib.suppress(OSError):
                    escalate()
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
                break
            except subprocess.TimeoutExpired:
                continue
        with contextlib.suppress(OSError, ValueError):
            process.stdout.close()
        self.process = None
        return process.returncode

    def __enter__(self) -> DrivesProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class LocalDrives:
    """The drives in this process (``SimulatedCell``): on an interface that reaches one process only
    (python-can's ``virtual``); ``.bus`` has the heartbeat window of drives that share the master's
    interpreter (``sharing_the_interpreter``)."""

    def __init__(self, wiring: CellWiring, clock: str) -> None:
        from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter

        wiring = sharing_the_interpreter(wiring)
        self.bus = wiring.bus
        self.cell = SimulatedCell(wiring, clock=clock)

    def start(self) -> LocalDrives:
        self.cell.start()
        return self

    def stop(self) -> None:
        self.cell.stop()


def start_simulated_drives(wiring: CellWiring, clock: str) -> DrivesProcess | LocalDrives:
    """A cell's simulated drives, started: in their own process on the simulated wire, in this
    one on an interface that reaches no other process. ``.bus`` is the bus the master opens,
    ``.stop()`` ends them."""
    if wiring.bus.interface == SIMULATED_WIRE:
        return DrivesProcess(wiring, clock).start()
    return LocalDrives(wiring, clock).start()


def serve(wiring: CellWiring, clock: str, stop: threading.Event, out: TextIO) -> int:
    """The child: the drives on the served wire until ``stop``; the exit code."""
    from pvtflow.axes.canbus.collector import FullCollectionBetweenMotions
    from pvtflow.axes.sim.cell import SimulatedCell
    from pvtflow.axes.sim.wire import serve_wire

    bus = wiring.bus
    sim = SimulatedCell(wiring, clock=clock)
    server = None
    try:
        server = serve_wire(bus.channel, 0, **wire_options(bus, clock=sim.clock))  # type: ignore[arg-type]
        sim.start()
    except (OSError, ValueError, ImportError) as exc:
        sim.stop()
        if server is not None:
            server.close()
        print(f"cannot start the simulated drives on {bus.channel}: {exc}", file=out, flush=True)
        return EXIT_CANNOT_START
    # wall clock: no full collection while SYNC runs (it stopped the wire and the drives 14-65 ms)
    collection = None if sim.clock.lockstep else FullCollectionBetweenMotions(sim.network)
    try:
        print(f"{WIRE_SERVED_AT} {server.address}", file=out, flush=True)
        while not stop.wait(0.5):  # a timed wait: SIGTERM's handler runs between waits
            if collection is not None:
                collection.tick()
    finally:
        if collection is not None:
            collection.close()
        sim.stop()
        server.close()
    for exc in sim.internal_errors:
        print(f"a simulated drive raised internally: {exc!r}", file=sys.stderr, flush=True)
    return EXIT_SIMULATOR_ERROR if sim.internal_errors else EXIT_OK


def raise_drives_share(clock: str) -> bool:
    """The drives' share of the CPU, for this thread before it starts any other, so that every thread of
    the drives inherits it (Linux threads inherit their creator's policy and nice value). The drives
    stand in for hardware with a CPU of its own, which no other work on the host ever delays: on the
    wall clock they run at SCHED_FIFO ``DRIVES_PRIORITY`` (``axes.canbus.threads``: below the master's
    SYNC and cyclic threads, above every thread of normal priority). At nice -10 (``DRIVES_NICE``,
    what they get where SCHED_FIFO is not permitted, and in lockstep, where no one waits for them) two
    CPU-bound processes still held them 20 ms and more now and then, and the medium they serve with
    them: the master heard no SYNC, and echoes came late enough to count its transmit queue full
    (bench/RESULTS.md, issue 34). False: neither was permitted."""
    if clock == Clock.WALL and ask_drives_priority():
        return True
    try:
        os.setpriority(os.PRIO_PROCESS, 0, DRIVES_NICE)
    except (AttributeError, OSError):
        return False
    return True


def main() -> int:
    # the drives' threads (ticker, Notifiers) hand the GIL on as often as the master's do, so the
    # wire's threads (its driver, its server) are not held up for CPython's default 5 ms
    hand_the_gil_on_often()
    clock = sys.argv[1] if len(sys.argv) > 1 else Clock.LOCKSTEP
    raise_drives_share(clock)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the master stops the drives after it halted them
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    try:
        wiring = pickle.loads(base64.b64decode(sys.stdin.readline()))
    except (ValueError, pickle.UnpicklingError, EOFError) as exc:
        print(f"cannot read the cell's wiring: {exc}", flush=True)
        return EXIT_CANNOT_START

    def watch_stdin() -> None:
        """The master closed our stdin, or died: either way the drives go."""
        while sys.stdin.readline():
            pass
        stop.set()

    threading.Thread(target=watch_stdin, name="sim-drives-stdin", daemon=True).start()
    return serve(wiring, clock, stop, sys.stdout)


if __name__ == "__main__":
    sys.exit(main())
