"""A cell's planner in its own process, so that planning and the bus never share an interpreter.

In one process a plan (tens of ms of Python and numpy) and the bus threads (SYNC, PDOs, simulated
drives) take turns on the GIL: a motion runs slower while a plan is computed and the plan takes
longer (bench/service_latency.py ``--during``), and on a real cell the SYNC producer would wait up to
the interpreter's switch interval. :class:`PlanningProcess` keeps one :class:`CellPlanner` in a
spawned child (spawn, not fork: the parent runs zenoh and CAN threads) built once at start; a plan
costs one pipe round trip of a few kB of pickles. Same ``plan()`` as CellPlanner.
``MotionService(planner_process=True)``; ``pvtflow serve`` uses it wherever SYNC runs on the wall
clock (a real cell, ``--real-time``: there a GIL held by a plan would delay SYNC, records and a
bufferless drive's setpoints by up to the switch interval) and not for lockstep simulations
(``--planner-process on|off`` overrides). It costs a second interpreter (its start-up and memory)
and a pipe round trip per plan (bench/service_latency.py), and pays off while motions run.
As with any spawned process, the program's main module must be importable without side effects
(``if __name__ == "__main__":``).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import threading
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CellPlan, CellPlanner
from pvtflow.service.config import CellConfig, PlanningConfig, load_cell_config

READY = "ready"


def _child(conn: Connection, source: Path, name: str, axes: tuple[AxisConfig, ...], planning: PlanningConfig) -> None:
    """The child: the cell as the parent has it (the robot model is reloaded, not pickled), then one
    ``(PlanInput, tolerance_qc, metadata)`` in (CellPlanner.plan's arguments), one CellPlan (or an
    error text) out, until EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it closes the pipe, we end on EOF
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        cell = dataclasses.replace(load_cell_config(source), name=name, axes=axes, planning=planning)
        planner = CellPlanner(cell)
        planner.warm_up()
        freeze_startup_objects()
    except Exception:
        conn.send(traceback.format_exc())
        return
    conn.send(READY)
    while True:
        try:
            args = conn.recv()
        except (EOFError, OSError):  # the parent closed the pipe (or went away)
            return
        try:
            result = planner.plan(*args)
            conn.send(dataclasses.replace(result, plan=None))  # the TOPP-RA trajectory stays: the program is the output
        except Exception:  # a bug in the planner: the parent reports it, the child keeps serving
            conn.send(traceback.format_exc())


class PlanningError(RuntimeError):
    """The planning process failed (a bug in the planner, or the child died: it is restarted)."""


class PlanningProcess:
    """CellPlanner.plan() answered by a child process over a pipe; a dead child is replaced."""

    def __init__(self, cell: CellConfig, start_timeout: float = 120.0) -> None:
        self.cell = cell
        self.limits = cell.joint_limits()
        self.start_timeout = start_timeout
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._process: Any = None
        self._ready = False
        self._start()

    def _start(self) -> None:
        """Spawn the child now; it imports and builds its planner while the service starts."""
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe()
        c = self.cell
        self._process = ctx.Process(
            target=_child, args=(child, c.source, c.name, c.axes, c.planning), name=f"pvtflow-planner-{c.name}"
        )
        self._process.daemon = True
        self._process.start()
        child.close()
        self._conn, self._ready = parent, False

    def _wait_ready(self) -> None:
        assert self._conn is not None
        if self._ready:
            return
        try:
            if not self._conn.poll(self.start_timeout):
                raise PlanningError(f"the planning process did not start within {self.start_timeout:g} s")
            answer = self._conn.recv()
        except (EOFError, OSError):  # e.g. a main module that starts a service when imported (spawn imports it)
            self._process.join(timeout=5.0)
            code = self._process.exitcode
            self._stop()
            self._start()
            raise PlanningError(f"the planning process exited while starting (exit code {code})") from None
        if answer != READY:
            raise PlanningError(f"the planning process cannot start: {answer}")
        self._ready = True

    @property
    def ready(self) -> bool:
        """Whether the child has said it is warmed up (``wait_ready``)."""
        return self._ready

    def wait_ready(self) -> None:
        with self._lock:
            self._wait_ready()

    def plan(
        self,
        inp: PlanInput,
        tolerance_qc: float | None = None,
        metadata: dict[str, Any] | None = None,
        budget_ms: float | None = None,
    ) -> CellPlan:
        """Like CellPlanner.plan, in the child; PlanningError for a planner bug or a dead child (then
        restarted)."""
        return self._ask((inp, tolerance_qc, metadata, budget_ms))

    def _ask(self, args: tuple[Any, ...]) -> CellPlan:
        with self._lock:
            try:
                self._wait_ready()
                assert self._conn is not None
                self._conn.send(args)
                answer = self._conn.recv()
            except (EOFError, OSError, BrokenPipeError):
                self._stop()
                self._start()
                raise PlanningError("the planning process died; it was restarted") from None
        if isinstance(answer, str):
            raise PlanningError(f"the planner failed: {answer.strip().splitlines()[-1]}")
        return answer  # type: ignore[no-any-return]

    def _stop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._process is not None:
            self._process.join(timeout=5.0)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(timeout=5.0)
            self._process = None

    def close(self) -> None:
        with self._lock:
            self._stop()
