"""The planning pipeline of one cell: waypoints (or tool poses) -> trajectory -> knots -> a
validated PVT program for the cell's drives.

:class:`CellPlanner` is built once per cell (the service keeps one; ``service/planning.py`` runs it
in a child process); :func:`plan_cell_program` is a one-off call of it (``pvtflow plan``). The
service and the command line both import it from here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner import timing
from pvtflow.planner.build import BuildError, BuildOutput, build_program
from pvtflow.planner.cartesian import placement_pose
from pvtflow.planner.knots import KnotOptions, jerk_smooth, quantize
from pvtflow.planner.path import PlanResult
from pvtflow.planner.plan import PlanInput, Planner, PlanOutput, jerk_details
from pvtflow.service.config import CellConfig
from pvtflow.service.record_feed import RecordFeed

if TYPE_CHECKING:  # planner.jerk loads casadi: only a plan with a jerk limit does
    from pvtflow.planner.jerk import JerkTrajectory


@dataclass(frozen=True)
class CellPlan:
    """The outcome of planning on a cell: a program, or the reason (``code``, ``message``)."""

    code: str  # "ok", a planner.plan.PlanOutcome value, or "program_error"
    message: str = ""
    program: PvtProgram | None = None
    plan: PlanOutput | None = None
    build: BuildOutput | None = None
    timing: dict[str, float] = field(default_factory=dict)  # s: plan (ik: its inverse kinematics), knots, total
    waypoints: NDArray[np.float64] | None = None  # the joint waypoints planned through (poses: the IK samples)
    details: dict[str, Any] = field(default_factory=dict)  # where it failed (PlanError details)
    # False where the jerk-limited timing's deadline came first, or torque between its rows slowed it > 0.1 %
    optimal: bool = True
    # a jerk-limited plan's duration and the TOPP-RA duration no jerk-limited timing beats (s)
    gap: dict[str, float] | None = None
    # motion time given for fewer records (planner.speed_band), None: none; "band", "reason" (the cell
    # file asked, or its bus needs it) and "cost_pct" (% of the time-optimal motion time)
    speed_band: dict[str, Any] | None = None

    @property
    def ok(self) -> bool:
        return self.program is not None


# the warm-up's plans within a deadline: far off, so that they are solved (the floor's knots placed beside)
_WARM_BUDGET_MS = 10_000.0

TIMEOUT = "timeout"  # CellPlan.code of a plan past its deadline for another reason than the timing's solve

# the speed bands tried, in turn, where the bus cannot feed the time-optimal plan's records (planner.speed_band;
# bench/RESULTS.md, "Issue 25 item 4": records and motion time of 0.01 .. 0.1)
FEED_BANDS = (0.01, 0.025, 0.05, 0.1)
CELL_FILE_REASON = "the cell file asks for it (planning.speed_band)"
INPUT_REASON = "the plan's input asks for it (PlanInput.speed_band)"


def knots_reserve_ms(budget_ms: float, floor_beside: bool = False) -> float:
    """What a plan's budget keeps back from the jerk-limited timing's solve: the answer's dense check,
    knot placement and validation, and where the floor's knots are not placed while the solver runs
    (``floor_beside`` False: a sequence), the floor's knots after a late solve too (they took 10-22 ms
    at p50-p99 on the 2-core host, the answer's 6-10: bench/budget_split.py, bench/RESULTS.md)."""
    return (10.0 if floor_beside else 25.0) + 0.1 * budget_ms


class FloorKnots:
    """The S-curve floor's program, placed while the jerk-limited solve runs (``Planner.plan``'s
    ``on_floor``, in the plan's thread: casadi leaves the interpreter's lock while it solves), so that a
    late solve's answer is ready at the deadline and the budget keeps back only the answer's knots."""

    def __init__(self, place: Callable[[JerkTrajectory, dict[str, object]], BuildOutput]) -> None:
        self._place = place
        self.trajectory: JerkTrajectory | None = None
        self.built: BuildOutput | None = None
        self.error: Exception | None = None
        self.seconds = 0.0  # the knots' time

    def __call__(self, trajectory: JerkTrajectory, details: dict[str, object]) -> None:
        began = time.perf_counter()
        self.trajectory = trajectory
        try:
            self.built = self._place(trajectory, details)
        except (BuildError, ValueError) as exc:  # the answer's error where the floor is the answer, as before
            self.error = exc
        self.seconds = time.perf_counter() - began

    def of(self, trajectory: object) -> bool:
        """Whether this is the floor placed here (the planner answers with that same object)."""
        return self.trajectory is not None and trajectory is self.trajectory

    def instead_of(self, out: PlanOutput) -> PlanOutput | None:
        """The floor's plan in place of ``out``, another answer than the floor, where the floor's program is
        placed already (None: ``out`` failed, is the floor, or the floor has no program)."""
        if self.built is None or not out.ok or self.of(out.trajectory):
            return None
        return replace(out, trajectory=self.trajectory, details=out.details | jerk_details(self.trajectory))


def planner_for_cell(cell: CellConfig, gridpoints: int | None = None) -> Planner:
    """The cell's Planner: its joint limits, robot model and planning options (ValueError where the
    planner refuses an option)."""
    return Planner(
        cell.joint_limits(),
        cell.model,
        cell.planning.tcp_frame,
        cell.planning.max_tcp_speed,
        cell.planning.torque_limits,
        gridpoints,
        cell.planning.max_tcp_angular_speed,
        cell.planning.max_jerk,
        speed_band=cell.planning.speed_band,
    )


class CellPlanner:
    """The planning pipeline of one cell, built once: its Planner (toppra constraints), drive axes
    and default tolerance. A service keeps one per cell, so a request pays for planning only.

    Not for concurrent use: the Planner's constraint objects are shared between calls (the service
    plans on one worker thread).
    """

    def __init__(self, cell: CellConfig, gridpoints: int | None = None) -> None:
        self.cell = cell
        self.limits = cell.joint_limits()
        self.axes = tuple(cell.ordered_axes())  # each an axes.drive.axis.DriveAxis: what knot placement takes
        self.tolerance_qc = cell.planning.position_tolerance_qc
        self.feed = RecordFeed(cell)
        self.planner: Planner | None = None
        self.setup_error = ""
        try:
            self.planner = planner_for_cell(cell, gridpoints)
        except ValueError as exc:  # a planning option the planner refuses: every plan says so
            self.setup_error = str(exc)

    def warm_up(self, jerk: bool = True) -> None:
        """Plan a short move in the middle of the joint ranges and drop it.

        The first plan of a process loads the planner's compiled loops (numba's cache; on a new
        machine it compiles them first, some seconds, once). A service pays that at start, not
        with its first request. ``jerk``: the same move jerk-limited too, which loads casadi and builds
        its program for paths of up to 8 waypoints: any request may set a jerk limit, and a program
        built inside a plan's budget would take most of it. That move spans 0.4-0.6 of the ranges:
        on arm6 the solvers converge on it in about 0.2 s once built, where on 0.45-0.55 ipopt iterates
        to its limit (seconds of CPU at every start). No deadline: a solve past one would run on in
        its thread, holding the program from the first request. Both of its solvers are built (ipopt
        where fatrop does not converge: 0.13 s inside a request otherwise, ``planner.jerk.solve.ProgramCache``),
        and the same move is planned again with no time left, for the S-curve floor a deadline answers
        with and its knots; the program of twice the intervals is built too (``planner.jerk.warm_up``).
        Then on each grid a deadline solves, within a deadline far off: the programs it solves (fewer rows
        per stage, ``planner.jerk.screen``) learn their time per iteration (once per process), which decides
        whether the first requests' solves start (``planner.jerk.solve``; the warm-up's solve times are
        forgotten).
        """
        if self.planner is None:
            return
        lo, hi = self.limits.lower, self.limits.upper
        a, b = lo + 0.45 * (hi - lo), lo + 0.55 * (hi - lo)
        self.plan(PlanInput(np.array([a, b])))
        timing.warm_up()  # the longer paths' spline and the torque check near a limit
        quantize.warm_up()  # the repair that may move knots, which a short move rarely needs
        if jerk:
            from pvtflow.planner.jerk import (  # casadi: loaded where plans may be jerk-limited
                WARM_INTERVALS,
                forget_solve_times,
                untimed_grids,
            )
            from pvtflow.planner.jerk import warm_up as jerk_warm_up

            ja, jb = lo + 0.4 * (hi - lo), lo + 0.6 * (hi - lo)
            jerky = PlanInput(
                np.array([ja, jb]), max_jerk=10.0 * self.limits.acceleration, jerk_intervals=WARM_INTERVALS
            )
            self.plan(jerky)
            self.plan(jerky, budget_ms=0.0)  # the floor: no solver has time (its answer, timeout, is dropped)
            jerk_warm_up()
            # the programs a deadline solves, for their time per iteration where it is not known yet, once every
            # build is done: on a path like a request's (on the short move above fatrop's iterations took twice
            # theirs), three times (a solver's first solve is slower, and other processes' load makes some slower)
            rng = np.random.default_rng(0)
            path = lo + (0.2 + 0.6 * rng.random((8, len(lo)))) * (hi - lo)
            for n in untimed_grids():
                for _ in range(3):
                    self.plan(replace(jerky, waypoints=path, jerk_intervals=n), budget_ms=_WARM_BUDGET_MS)
            forget_solve_times()
            jerk_smooth.warm_up()
        if self.planner.poses is not None:  # and the inverse kinematics' compiled steps
            self.plan(PlanInput(a, [placement_pose(self.planner.poses.ik.fk(b))]))

    def plan(
        self,
        inp: PlanInput,
        tolerance_qc: float | None = None,
        metadata: dict[str, Any] | None = None,
        budget_ms: float | None = None,
    ) -> CellPlan:
        """A plan (waypoints in the cell's joint order, or tool poses from a start: planner.plan)
        -> a validated PVT program for the cell's drives. ``tolerance_qc``: the knots' position
        tolerance (default: the cell's); ``metadata``: recorded in the program.

        The speed override (``velocity_scale``, ``acceleration_scale``) holds for the plan and for
        the knots (``build_program``); it is recorded in the program's metadata, as are the tool
        poses' ``motion`` and the jerk limit held (``max_jerk``, null for a joint without one).

        ``timing`` (s): ``plan`` the timing (``ik``: the inverse kinematics' part of it; with a jerk
        limit, ``topp`` and ``jerk`` its two parts), ``knots`` knot placement + validation, ``total``,
        and ``cpu`` the CPU time of this thread over the whole call (``total - cpu``: time the thread
        waited for the CPU or the GIL).

        ``budget_ms`` (None: no deadline; the service and ``pvtflow plan`` pass the request's or the
        cell's ``planning.budget_ms``): the jerk-limited timing gets the budget less
        ``knots_reserve_ms`` and answers by then (``CellPlan.optimal`` False where that was its best
        so far), the floor's knots placed while it solves (``FloorKnots``; not for a sequence); a plan
        that is still past the deadline at the end (inverse kinematics, TOPP-RA, a casadi program
        built for a new shape, knots) is ``timeout``, its program dropped.
        """
        start, cpu = time.perf_counter(), time.thread_time()
        if self.planner is None:
            return CellPlan(PlanResult.INVALID_INPUT.value, self.setup_error, None, None, None, {"plan": 0.0})
        if inp.sequence is not None and self.planner.sequences is not None:
            from pvtflow.service.sequence_chunks import chunks, plan_in_chunks  # it builds on this module

            if len(chunks(inp.sequence)) > 1:  # exact stops: planned rest to rest, joined
                return plan_in_chunks(self, inp, tolerance_qc, metadata, budget_ms)
        meta = dict(metadata or {})
        if inp.sequence is not None:
            meta = {"motion": "sequence", **meta}
        elif inp.poses is not None:
            meta = {"motion": str(inp.motion), **meta}
        # the floor's knots placed while the solve runs, but a sequence's (its items' times are the plan's)
        floor = None
        if budget_ms is not None and inp.sequence is None:
            floor = FloorKnots(lambda traj, details: self._knots(traj, details, inp, tolerance_qc, meta))
        if budget_ms is not None:
            inp = replace(inp, budget_ms=max(0.0, budget_ms - knots_reserve_ms(budget_ms, floor is not None)))
        out = self.planner.plan(inp, floor)
        reason = CELL_FILE_REASON if inp.speed_band is None else INPUT_REASON
        fallback = floor.instead_of(out) if floor is not None else None
        if fallback is not None:
            # the solver's answer, where its knots would not end within the budget (they take about the
            # floor's: a shorter motion on more intervals): the floor's program, placed already
            left = budget_ms - 1000.0 * (time.perf_counter() - start)  # type: ignore[operator]
            if left < 1000.0 * floor.seconds:  # type: ignore[union-attr]
                out = fallback
        result = self._build(out, start, cpu, inp, tolerance_qc, meta, reason, floor)
        if not result.ok and floor is not None and (fallback := floor.instead_of(out)) is not None:
            # the drives' cubics did not follow the solver's motion (below): within a deadline the floor's
            # program, placed already, where planning again would not end in time
            out = fallback
            result = self._build(out, start, cpu, inp, tolerance_qc, meta, reason, floor)
        elif not result.ok and out.ok and out.details.get("jerk_intervals", 0):
            from pvtflow.planner.jerk import GRID_UNIT  # casadi: loaded by the jerk-limited plan already

            if int(out.details["jerk_intervals"]) > GRID_UNIT:  # type: ignore[call-overload]
                # the drives' cubics did not follow the fine grid's motion within the limits and the
                # window-jerk allowance (its jerk switching within a few ms under a scaled-down jerk
                # limit): the coarsest grid's motion (planner.jerk.grid_sizes; bench/RESULTS.md, "Issue 39
                # item 2, the solver")
                out = self.planner.plan(replace(inp, jerk_intervals=GRID_UNIT))
                result = self._build(out, start, cpu, inp, tolerance_qc, meta, reason)
        if result.ok and "max_jerk" not in out.details and inp.speed_band is None:
            out, result = self._fed(out, result, start, cpu, inp, tolerance_qc, meta)
        elapsed_ms = (time.perf_counter() - start) * 1000.0
        if budget_ms is not None and elapsed_ms > budget_ms and result.ok:
            message = f"the plan took {elapsed_ms:.0f} ms, past its budget of {budget_ms:g} ms"
            return CellPlan(TIMEOUT, message, None, out, None, result.timing, details={"budget_ms": budget_ms})
        if result.ok and out.trajectory is not None and "lower_bound_s" in out.details:
            gap = {"duration_s": out.trajectory.duration, "lower_bound_s": float(out.details["lower_bound_s"])}  # type: ignore[arg-type]
            result = replace(result, optimal=bool(out.details["optimal"]), gap=gap)
        return result

    def _fed(
        self,
        out: PlanOutput,
        result: CellPlan,
        start: float,
        cpu: float,
        inp: PlanInput,
        tolerance_qc: float | None,
        metadata: dict[str, Any],
    ) -> tuple[PlanOutput, CellPlan]:
        """``result`` where the bus feeds its records in time (``service.record_feed``); else the plan
        flattened within the narrowest of the ``FEED_BANDS`` wider than the cell's own band whose
        records it does feed, saying why (the shortfall) and what it cost. Where none does, ``result``
        itself: fewer records that still run dry buy nothing, and the start refuses it with the reason."""
        assert result.program is not None and self.planner is not None
        shortfall = self.feed.shortfall(result.program)
        if shortfall is None:
            return out, result
        reason = f"the bus cannot feed the time-optimal plan's records: {shortfall}"
        for band in FEED_BANDS:
            if band <= self.planner.speed_band:
                continue
            banded = replace(inp, speed_band=band)
            out_b = self.planner.plan(banded)
            built = self._build(out_b, start, cpu, banded, tolerance_qc, metadata, reason)
            if built.ok and built.program is not None and self.feed.shortfall(built.program) is None:
                return out_b, built
        return out, result

    def _build(
        self,
        out: PlanOutput,
        start: float,
        cpu: float,
        inp: PlanInput,
        tolerance_qc: float | None,
        metadata: dict[str, Any],
        band_reason: str = CELL_FILE_REASON,
        floor: FloorKnots | None = None,
    ) -> CellPlan:
        """The program of a planned trajectory (or the planner's refusal as a CellPlan); a plan
        flattened within a speed band says so in the program's metadata, with ``band_reason``.
        ``floor``: the S-curve floor's program placed while the solver ran, this plan's where its
        trajectory is that floor (``timing["knots"]`` then the time they took there)."""
        t_plan = time.perf_counter() - start
        timing = {"plan": t_plan}
        for key, name in (("ik_s", "ik"), ("topp_s", "topp"), ("jerk_s", "jerk")):
            if key in out.details:
                timing[name] = float(out.details[key])  # type: ignore[arg-type]
        if not out.ok or out.trajectory is None:
            return CellPlan(out.result.value, out.message, None, out, None, timing, details=dict(out.details))
        points = out.trajectory.path.points
        band = None
        if "speed_band" in out.details:
            cost = 100.0 * float(out.details["speed_band_cost"])  # type: ignore[arg-type]
            band = {"band": out.details["speed_band"], "reason": band_reason, "cost_pct": round(cost, 3)}
        knots_s = None
        try:
            if floor is not None and floor.of(out.trajectory):
                if floor.error is not None:
                    raise floor.error
                assert floor.built is not None
                built, knots_s = floor.built, floor.seconds
            else:
                built = self._knots(out.trajectory, out.details, inp, tolerance_qc, metadata, band)
        except (BuildError, ValueError) as exc:
            return CellPlan("program_error", str(exc), None, out, None, timing, points)
        total = time.perf_counter() - start
        knots = total - t_plan if knots_s is None else knots_s
        timing.update({"knots": knots, "total": total, "cpu": time.thread_time() - cpu})
        return CellPlan("ok", "", built.program, out, built, timing, points, speed_band=band)

    def _knots(
        self,
        trajectory: Any,
        details: dict[str, object],
        inp: PlanInput,
        tolerance_qc: float | None,
        metadata: dict[str, Any],
        band: dict[str, Any] | None = None,
    ) -> BuildOutput:
        """Knots, program and validation of ``trajectory`` (BuildError, ValueError where they fail);
        the program's metadata: ``metadata``, the jerk limit held, a sequence's items, the speed band."""
        tol = self.tolerance_qc if tolerance_qc is None else tolerance_qc
        meta = dict(metadata)
        if "max_jerk" in details:
            meta["max_jerk"] = details["max_jerk"]
        if "items" in details:  # a sequence: its items' time spans (which item runs when)
            meta["items"] = details["items"]
        if band is not None:
            meta["speed_band"] = band
        return build_program(
            trajectory,
            self.axes,
            self.cell.name,
            KnotOptions(tolerance_qc=tol, max_jerk=details.get("max_jerk")),  # type: ignore[arg-type]
            meta,
            float(inp.velocity_scale),
            float(inp.acceleration_scale),
        )


def plan_cell_program(
    cell: CellConfig, inp: PlanInput, tolerance_qc: float | None = None, metadata: dict[str, Any] | None = None
) -> CellPlan:
    """One-off planning on ``cell`` (the CLI): a CellPlanner built for this call."""
    return CellPlanner(cell).plan(inp, tolerance_qc, metadata)
