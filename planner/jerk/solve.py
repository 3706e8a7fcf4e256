"""Solving the jerk-limited timing's program within a deadline: which solver, when, and for how long.

The program is a discrete optimal control problem (state (sd, a), control (h, j)), which is the
structure fatrop's Riccati-based interior point exploits: its iteration solves the stages in
sequence, where ipopt's general sparse factorization (MUMPS) does not know them. Where fatrop does
not converge, ipopt is tried from the same start; where neither does, the plan is refused with the
solvers' statuses. The variables are scaled by their typical magnitudes (``nlp.variable_scales``:
fatrop does not scale a program) and the start is slowed down to well inside the jerk rows
(``warm.warm_start``): both cut the solve time's tail.

Anytime with a deadline (``solve_in_time``): the solve runs in a thread waited for until then; ipopt
stops there (``_Deadline``) with its last iterate whose equalities hold; without an answer in time
the motion is the S-curve floor of ``planner.scurve``. Either is checked and slowed down
(``planner.jerk``), ``optimal`` False.

The caller's thread meanwhile computes what it answers where the solve is late (``meanwhile``: the
S-curve floor and its dense check, ``planner.jerk``): fatrop's solve leaves the interpreter's lock
to other threads (bench/gil_stall.py: during a 130 ms solve another thread's longest wait was the
switch interval), so the floor is ready at the deadline instead of starting there, and a late solve
costs its CPU only, not the floor's time after the budget.

A solve is started only where it has a chance to finish (``_solvers_for``): fatrop has no time
limit nor iteration callback in casadi 3.8.2, and a late one runs on in its thread, its program
held (``Program.lock``). So fatrop runs only with at least its typical time left: the median of this
program shape's last ``_SOLVE_HISTORY`` fatrop solves (until ``_MIN_HISTORY`` are known, its least time per
iteration, the warm-up's included, times ``_FATROP_ITERATIONS``; ``_FATROP_TIME_S`` per 48 intervals
before any solve), a measured figure that follows the machine; ipopt (stopped at the deadline) only with at
least ``_IPOPT_TIME_S`` left, below which its iterates were never usable (bench/RESULTS.md); with
less than both, no solver, the floor at once. Which grid a deadline gets (``planner.jerk``) is judged
on the longest of the recent solves instead: there a late finer solve is the floor where a coarser
one would have answered.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.jerk.compiled import compiled_fatrop
from pvtflow.planner.jerk.nlp import CONTROL, STATE, build_nlp

_MAX_ITER = 300

_TOL = 1e-6  # optimality (relative duration)
_CONSTRAINT_TOL = 1e-9  # the residuals: positions along the path continuous to 1e-9 of an interval
_ITERATE_TOL = 1e-8  # an unfinished ipopt iterate is a motion where its residuals are this small
# fatrop's expected solve time per 48 intervals until _MIN_HISTORY solves of a program shape were timed
# (``_solvers_for``): twice its p50 on 8-waypoint arm6 paths, so that a fresh process (``pvtflow plan``)
# solves at 200 ms; its time grows with the intervals (bench/RESULTS.md, "Issue 39 item 2")
_FATROP_TIME_S = 0.06
_FATROP_INTERVALS = 48
_SOLVE_HISTORY = 50
_MIN_HISTORY = 10
# until then, where the program's time per iteration is known (the warm-up's solves: a program's
# iterations cost about the same on any path, their count is the path's): that times this many iterations,
# fatrop's p50 on arm6 8-waypoint paths on the screened programs being 18-21 at 48 intervals and 22 at 96
# (bench/RESULTS.md, "Issue 39 item 2 at `budget_ms: 50`: the floor's knots beside the solve")
_FATROP_ITERATIONS = 24
_IPOPT_TIME_S = 0.04  # with less time left ipopt's iterates were never usable: no solve, the floor
# building a program and its two solvers: 0.28 s for 48 intervals on the 2-core test host (casadi 3.8.2),
# about in proportion to them; twice that is the time a plan must have left to build one (``expected_build_s``)
_BUILD_S_PER_INTERVAL = 0.012


@dataclass
class Program:
    """The casadi program for n intervals and dof joints, built once and kept (``cached_program``).

    Variables, stage by stage: x_k = (sd_k, a_k), u_k = (h_k, j_k, sigma_mid_k, sd_mid_k), ..., x_n.
    Rows, stage by stage: x_(k+1) - F(x_k, u_k) (gap closing, the form fatrop's structure
    detection wants), the distance and middle residuals, then the stage's inequality rows.
    """

    n: int
    dof: int
    torque: bool
    nlp: dict[str, ca.SX]
    equality: list[bool]
    solvers: dict[str, ca.Function] = field(default_factory=dict)
    # one solve at a time: a solve past its plan's deadline runs on in its thread (fatrop cannot be stopped)
    lock: threading.Lock = field(default_factory=threading.Lock)
    stop: _Deadline | None = None
    fatrop_s: deque[float] = field(default_factory=lambda: deque(maxlen=_SOLVE_HISTORY))  # recent solve times
    # recent times per iteration, the warm-up's kept (``planner.jerk.warm_up`` forgets its ``fatrop_s``)
    iteration_s: deque[float] = field(default_factory=lambda: deque(maxlen=_SOLVE_HISTORY))
    solved: bool = False  # whether fatrop has solved this program once (``iteration_s`` from its second solve)
    compiled: bool = False  # whether fatrop evaluates the program's compiled functions (``use_compiled``)

    def typical_fatrop_s(self) -> float:
        """fatrop's typical wall time on this program: the median of its recent solves (before
        ``_MIN_HISTORY`` are known: ``expected_fatrop_s``)."""
        times = list(self.fatrop_s)
        return float(np.median(times)) if len(times) >= _MIN_HISTORY else self.expected_fatrop_s()

    def expected_fatrop_s(self) -> float:
        """fatrop's expected time on this program before its solves are known: the least of its times
        per iteration times ``_FATROP_ITERATIONS``, else ``expected_solve_s``. The least: the
        machine's own speed (a warm-up on a host loaded by others took twice a request's time per
        iteration on it), where a solve that turns out late costs its CPU only, the floor being
        ready (``planner.jerk``); after ``_MIN_HISTORY`` solves their median decides."""
        if not self.iteration_s:
            return expected_solve_s(self.n)
        return min(self.iteration_s) * _FATROP_ITERATIONS

    def measured_fatrop_s(self) -> float | None:
        """The longest of fatrop's recent solves of this program, None until ``_MIN_HISTORY`` are known."""
        times = list(self.fatrop_s)
        return max(times) if len(times) >= _MIN_HISTORY else None

    def use_compiled(self, build: bool = True) -> bool:
        """fatrop on the program's functions compiled (``planner.jerk.compiled``: the same iterates, in about
        0.7x the time) from now on, where they are on disk or ``build`` and the C compiler builds them; the
        times measured on the interpreted program forgotten. Whether fatrop now solves the compiled program."""
        if self.compiled:
            return True
        interpreted = self.solver("fatrop")
        options = _solver_options("fatrop", self.equality)
        solver = compiled_fatrop("jerk_fatrop_c", self.n, self.dof, self.torque, interpreted, options, build)
        if solver is None:
            return False
        with self.lock:  # not in the middle of a solve's bookkeeping
            self.solvers["fatrop"] = solver
            self.compiled, self.solved = True, False
            self.fatrop_s.clear()
            self.iteration_s.clear()
        return True

    def solver(self, name: str) -> ca.Function:
        if name not in self.solvers:
            options = _solver_options(name, self.equality)
            if name == "ipopt":  # ipopt asks after every iteration whether to go on; fatrop never does
                self.stop = _Deadline(self.nlp["x"].shape[0], np.asarray(self.equality))
                options["iteration_callback"] = self.stop
            self.solvers[name] = ca.nlpsol(f"jerk_{name}", name, self.nlp, options)
        return self.solvers[name]


class _Deadline(ca.Callback):
    """ipopt's iteration callback: stop once ``deadline`` (time.perf_counter) has passed, and keep
    the last iterate whose equalities hold (``best``: the motion is continuous along the path; its
    inequalities the dense check and slow-down make exact)."""

    def __init__(self, nx: int, equality: NDArray[np.bool_]) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.equality = nx, len(equality), equality
        self.deadline = float("inf")
        self.best: NDArray[np.float64] | None = None
        self.construct("jerk_deadline", {})

    def reset(self, deadline: float) -> None:
        self.deadline, self.best = deadline, None

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[int]:
        g = np.asarray(arg[2]).ravel()
        if np.max(np.abs(g[self.equality]), initial=0.0) <= _ITERATE_TOL:
            self.best = np.asarray(arg[0]).ravel().copy()
        return [1 if time.perf_counter() >= self.deadline else 0]


def _solver_options(name: str, equality: list[bool]) -> dict[str, Any]:
    base: dict[str, Any] = {"print_time": False, "error_on_fail": False}
    common = {"print_level": 0, "tol": _TOL, "constr_viol_tol": _CONSTRAINT_TOL, "max_iter": _MAX_ITER}
    if name == "fatrop":
        return base | {"structure_detection": "auto", "equality": equality, "fatrop": common}
    return base | {"ipopt": common | {"sb": "yes"}}


def expected_solve_s(n: int) -> float:
    """fatrop's expected time on a program of ``n`` intervals before its own solves are known."""
    return _FATROP_TIME_S * n / _FATROP_INTERVALS


def expected_build_s(n: int) -> float:
    """The time a plan needs left to build the program of ``n`` intervals and its solvers."""
    return _BUILD_S_PER_INTERVAL * n


class ProgramCache:
    """The programs built, by shape (n, dof, torque), the last ``size`` kept, each with every solver
    of ``SOLVERS`` built with it (0.13 s each for arm6's 48 intervals: ipopt built where fatrop did
    not converge would take a request's whole budget).

    A plan with a deadline never builds one (``ready``): where its shape is not built it answers the
    floor and the shape is built in a thread of its own (``build_later``) for the plans after it."""

    # 5 shapes per cell and joint count (48, 96, 192 with every joint's rows; 48, 96 screened, planner/jerk/screen.py)
    def __init__(self, size: int = 12) -> None:
        self.size = size
        self._programs: OrderedDict[tuple[int, int, bool], Program] = OrderedDict()
        self._lock = threading.Lock()  # one build at a time; a plan with a deadline never waits for it
        self._building: set[tuple[int, int, bool]] = set()

    def get(self, n: int, dof: int, torque: bool) -> Program:
        """The program of this shape, built now where it is not (and kept)."""
        key = (n, dof, torque)
        with self._lock:
            program = self._programs.get(key)
            if program is None:
                program = Program(n, dof, torque, *build_nlp(n, dof, torque))
                for name in SOLVERS:
                    program.solver(name)
                program.use_compiled(build=False)  # where a warm-up compiled this shape (``jerk.warm_up``)
                self._programs[key] = program
                while len(self._programs) > self.size:
                    self._programs.popitem(last=False)
            self._programs.move_to_end(key)
            return program

    def ready(self, n: int, dof: int, torque: bool) -> Program | None:
        """The program of this shape where it is built, else None (never waits for a build)."""
        return self._programs.get((n, dof, torque))

    def build_later(self, n: int, dof: int, torque: bool) -> None:
        """Build this shape's program in a thread (not a daemon: casadi is not torn down under it)."""
        key = (n, dof, torque)
        with self._lock:
            if key in self._programs or key in self._building:
                return
            self._building.add(key)

        def build() -> None:
            try:
                self.get(n, dof, torque)
            finally:
                self._building.discard(key)

        threading.Thread(target=build, name="jerk-build", daemon=False).start()

    def shapes(self) -> list[tuple[int, int, bool]]:
        """The shapes built, oldest first."""
        return list(self._programs)

    def clear(self) -> None:
        with self._lock:
            self._programs.clear()


PROGRAMS = ProgramCache()


def cached_program(n: int, dof: int, torque: bool) -> Program:
    """The program of this shape with its solvers, built once and kept (``PROGRAMS``)."""
    return PROGRAMS.get(n, dof, torque)


@dataclass(frozen=True)
class Solution:
    sd: NDArray[np.float64]  # (n + 1,)
    sdd: NDArray[np.float64]  # (n + 1,)
    h: NDArray[np.float64]  # (n,)
    j: NDArray[np.float64]  # (n,)
    solver: str
    iterations: int
    optimal: bool = True


SOLVERS = ("fatrop", "ipopt")  # in turn: ipopt from the same start where fatrop does not converge


def _solvers_for(program: Program, time_left: float) -> tuple[str, ...]:
    """The solvers worth starting with ``time_left`` (s) before the deadline (module docstring)."""
    names = ("fatrop",) if time_left >= program.typical_fatrop_s() else ()
    return (*names, "ipopt") if time_left >= _IPOPT_TIME_S else names


def _solve_now(
    program: Program,
    args: dict[str, Any],
    scale: NDArray[np.float64],
    deadline: float,
    names: tuple[str, ...] = SOLVERS,
) -> tuple[Solution | None, str, bool]:
    """``names`` in turn (fatrop, then ipopt from the same start where fatrop does not converge;
    ``args`` scaled by ``scale``, the solution is not). The third value: whether the deadline
    stopped it, which includes a solver left out of ``names`` for lack of time (``_solvers_for``):
    the ones tried all failing is then no proof that none would converge."""
    statuses = []
    width = len(STATE) + len(CONTROL)

    def solution(x: Any, name: str, iterations: int, optimal: bool = True) -> Solution:
        w = np.append(np.asarray(x).ravel(), np.zeros(len(CONTROL))).reshape(program.n + 1, width) * scale
        return Solution(w[:, 0], w[:, 1], w[:-1, 2], w[:-1, 3], name, iterations, optimal)

    for name in names:
        if time.perf_counter() >= deadline:
            return None, "; ".join(statuses), True
        solver = program.solver(name)
        if program.stop is not None:
            program.stop.reset(deadline)
        began = time.perf_counter()
        out = solver(**args)
        stats = solver.stats()
        if name == "fatrop":
            took = time.perf_counter() - began
            program.fatrop_s.append(took)
            if program.solved:  # a solver's first solve sets up its memory: twice the time per iteration
                program.iteration_s.append(took / max(1, int(stats.get("iter_count", 0))))
            program.solved = True
        if stats["success"]:
            return solution(out["x"], name, int(stats.get("iter_count", 0))), "", False
        status = stats.get("return_status", "")
        if status == "User_Requested_Stop":  # the deadline, through ``_Deadline``: its best iterate, if any
            best = program.stop.best if program.stop is not None else None
            iterations = int(stats.get("iter_count", 0))
            return (None if best is None else solution(best, name, iterations, False)), "; ".join(statuses), True
        statuses.append(f"{name}: {status}" if isinstance(status, str) else f"{name}: failed (return status {status})")
    return None, "; ".join(statuses), names != SOLVERS


def solve_in_time(
    program: Program,
    args: dict[str, Any],
    scale: NDArray[np.float64],
    deadline: float | None,
    meanwhile: Callable[[], None] | None = None,
) -> tuple[Solution | None, str, bool]:
    """``_solve_now`` within ``deadline`` (time.perf_counter; None: as long as it takes).

    With a deadline the solve runs in a thread (casadi releases the GIL while it solves) and is
    waited for until the deadline, ``meanwhile`` run in the caller's thread first (where a solve
    started): ipopt stops there itself (``_Deadline``), fatrop cannot be stopped and finishes in
    its thread, its answer unused; the next solve of the same program waits for it
    (``Program.lock``), within its own deadline."""
    if deadline is None:
        with program.lock:
            return _solve_now(program, args, scale, float("inf"))
    names = _solvers_for(program, deadline - time.perf_counter())
    if not names:  # no solver can answer in time: the floor at once, no thread holding the interpreter
        return None, "", True
    result: list[tuple[Solution | None, str, bool]] = []

    def work() -> None:
        if program.lock.acquire(timeout=max(0.0, deadline - time.perf_counter())):
            try:  # the time left again: a solve past its own deadline may have held the lock
                now_names = _solvers_for(program, deadline - time.perf_counter())
                result.append(_solve_now(program, args, scale, deadline, now_names))
            finally:
                program.lock.release()

    # not a daemon: an interpreter that exits waits for the solve instead of tearing casadi down under it
    thread = threading.Thread(target=work, name="jerk-solve", daemon=False)
    thread.start()
    if meanwhile is not None:
        meanwhile()
    thread.join(max(0.0, deadline - time.perf_counter()))
    return result[0] if result else (None, "", True)
