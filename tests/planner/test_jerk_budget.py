"""A jerk-limited plan within its deadline (planner/jerk/solve.py, planner/scurve.py, service/cell_planner.py).

The timing is anytime: a deadline that comes before the solvers finish gives a valid, slower motion
(``optimal`` False), never a refusal; a plan past its budget for another reason is ``timeout``.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import pvtflow.service.cell_planner as cell_planner_module
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import TIMEOUT, CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
GANTRY = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")


def random_paths(cell, count: int, seed: int) -> list[np.ndarray]:
    lim = cell.joint_limits()
    rng = np.random.default_rng(seed)
    return [lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof))) for _ in range(count)]


def dense_ratios(traj, limits, max_jerk) -> tuple[float, float, float]:
    t = traj.check_times(64)
    return (
        float(np.max(np.abs(traj.velocity(t)) / limits.velocity)),
        float(np.max(np.abs(traj.acceleration(t)) / limits.acceleration)),
        float(np.max(np.abs(traj.jerk(t)) / max_jerk)),
    )


@pytest.mark.parametrize("cell", [ARM, GANTRY], ids=["arm6", "gantry3"])
def test_a_deadline_before_the_solve_gives_a_valid_slower_motion_not_a_refusal(cell) -> None:
    limits = cell.joint_limits()
    max_jerk = 10.0 * limits.acceleration
    planner = Planner(limits)
    for wp in random_paths(cell, 3, seed=5):
        late = planner.plan(PlanInput(wp, max_jerk=max_jerk, budget_ms=0.0))
        assert late.ok, late.message
        assert late.details["optimal"] is False and late.details["solver"] == "scurve"
        traj = late.trajectory
        assert max(dense_ratios(traj, limits, max_jerk)) <= 1.001
        np.testing.assert_allclose(traj.position(traj.waypoint_times), wp, atol=1e-9)  # through every waypoint
        best = planner.plan(PlanInput(wp, max_jerk=max_jerk))
        assert best.details["optimal"] is True
        assert late.details["lower_bound_s"] == pytest.approx(best.details["lower_bound_s"])
        assert best.details["lower_bound_s"] <= best.trajectory.duration <= traj.duration


def test_a_solve_the_deadline_interrupts_leaves_the_next_plan_whole() -> None:
    """45 ms for a solve that takes longer (ipopt, stopped at the deadline): answered in time (whatever
    it had), and the next plan of the same program waits for the interrupted solve and is optimal."""
    limits = ARM.joint_limits()
    max_jerk = 4.0 * limits.acceleration
    planner = Planner(limits)
    wp = random_paths(ARM, 1, seed=11)[0]
    quick = planner.plan(PlanInput(wp, max_jerk=max_jerk, budget_ms=45.0))
    assert quick.ok and isinstance(quick.details["optimal"], bool)
    assert max(dense_ratios(quick.trajectory, limits, max_jerk)) <= 1.001
    full = planner.plan(PlanInput(wp, max_jerk=max_jerk))
    assert full.ok and full.details["optimal"] is True
    assert full.trajectory.duration <= quick.trajectory.duration * (1.0 + 1e-9)


def test_no_solve_starts_that_cannot_answer_in_time() -> None:
    """Less time than any solver needs (planner/jerk/solve.py, ``_solvers_for``): the floor at once, no solve
    left running in a thread (it would take CPU from the plan and the next solve of its program)."""
    import threading

    import pvtflow.planner.jerk.solve as jerk_solve

    limits = ARM.joint_limits()
    planner = Planner(limits)
    wp = random_paths(ARM, 1, seed=12)[0]
    for earlier in [t for t in threading.enumerate() if t.name == "jerk-solve"]:
        earlier.join(60.0)  # an earlier test's solve, past its deadline
    budget_ms = 0.5 * 1000.0 * jerk_solve._IPOPT_TIME_S
    res = planner.plan(PlanInput(wp, max_jerk=10.0 * limits.acceleration, budget_ms=budget_ms))
    assert res.ok and res.details["optimal"] is False and res.details["solver"] == "scurve"
    assert not any(t.name == "jerk-solve" for t in threading.enumerate())


def test_a_solver_left_out_for_lack_of_time_is_the_floor_not_a_refusal(monkeypatch: pytest.MonkeyPatch) -> None:
    """The time left shrinks between choosing the solvers and starting them (the program's lock, a
    loaded host): none left, or only some of them failing, proves nothing about the path; the answer
    is the floor, never INFEASIBLE (time alone never refuses a plan)."""
    import pvtflow.planner.jerk.solve as jerk_solve

    chosen = jerk_solve._solvers_for
    calls: list[int] = []

    def fewer_the_second_time(program, time_left):  # type: ignore[no-untyped-def]
        calls.append(1)
        return chosen(program, time_left) if len(calls) == 1 else ()

    monkeypatch.setattr(jerk_solve, "_solvers_for", fewer_the_second_time)
    limits = ARM.joint_limits()
    wp = random_paths(ARM, 1, seed=13)[0]
    res = Planner(limits).plan(PlanInput(wp, max_jerk=10.0 * limits.acceleration, budget_ms=5000.0))
    assert len(calls) == 2
    assert res.ok, res.message
    assert res.details["optimal"] is False and res.details["solver"] == "scurve"


def test_the_cell_plan_says_not_optimal_and_its_program_is_valid(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole budget kept back from the solve: the answer is the floor, and it is a valid program."""
    monkeypatch.setattr(cell_planner_module, "knots_reserve_ms", lambda budget_ms, floor_beside=False: budget_ms)
    planner = CellPlanner(ARM)
    limits = ARM.joint_limits()
    res = planner.plan(
        PlanInput(random_paths(ARM, 1, seed=3)[0], max_jerk=10.0 * limits.acceleration), None, None, 60000.0
    )
    assert res.ok, res.message
    assert res.optimal is False
    assert res.gap["lower_bound_s"] < res.gap["duration_s"]
    assert validate_program(res.program).ok


def test_a_plan_past_its_budget_is_timeout_with_nothing_kept() -> None:
    res = CellPlanner(ARM).plan(PlanInput(random_paths(ARM, 1, seed=4)[0]), None, None, 1e-3)
    assert res.code == TIMEOUT and not res.ok and res.program is None
    assert "past its budget of 0.001 ms" in res.message


def test_a_generous_budget_is_the_optimal_plan() -> None:
    limits = ARM.joint_limits()
    res = CellPlanner(ARM).plan(
        PlanInput(random_paths(ARM, 1, seed=6)[0], max_jerk=10.0 * limits.acceleration), None, None, 60000.0
    )
    assert res.ok and res.optimal is True
    assert res.gap["lower_bound_s"] <= res.gap["duration_s"]


def test_the_cells_budget_defaults_to_200_ms() -> None:
    assert ARM.planning.budget_ms == 200.0


def test_a_program_not_built_is_not_built_within_a_deadline_too_short_for_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """A shape no plan built yet, asked for with 0.1 s left (a build takes 0.3 s): the floor at once,
    and the program built in a thread for the plans after it, which solve it."""
    from pvtflow.planner.jerk import solve as jerk_solve

    monkeypatch.setattr(jerk_solve, "PROGRAMS", jerk_solve.ProgramCache())
    monkeypatch.setattr("pvtflow.planner.jerk.PROGRAMS", jerk_solve.PROGRAMS)
    limits = ARM.joint_limits()
    w, jerk = random_paths(ARM, 1, seed=6)[0], 10.0 * limits.acceleration
    floor = Planner(limits).plan(PlanInput(w, max_jerk=jerk, budget_ms=100.0))
    assert floor.ok and floor.details["solver"] == "scurve" and floor.details["optimal"] is False
    for thread in threading.enumerate():
        if thread.name == "jerk-build":
            thread.join()
    (shape,) = jerk_solve.PROGRAMS.shapes()
    assert sorted(jerk_solve.PROGRAMS.ready(*shape).solvers) == ["fatrop", "ipopt"]
    solved = Planner(limits).plan(PlanInput(w, max_jerk=jerk, budget_ms=60000.0))
    assert solved.ok and solved.details["optimal"] is True
    assert solved.trajectory.duration < floor.trajectory.duration


def join_solves() -> None:
    """Wait for the solves earlier plans left running in their own threads (a late one finishes after its answer)."""
    for thread in [t for t in threading.enumerate() if t.name == "jerk-solve"]:
        thread.join(60.0)


def solves_late(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Every jerk-limited solve from here finishes past its deadline (fatrop starts with any time left, whatever
    an earlier test's times per iteration say); the deadlines they were given, in order."""
    import pvtflow.planner.jerk.solve as jerk_solve

    solve_now = jerk_solve._solve_now
    deadlines: list[float] = []

    def late(program, args, scale, deadline, names=jerk_solve.SOLVERS):  # type: ignore[no-untyped-def]
        deadlines.append(deadline)
        while time.perf_counter() < deadline:  # the solve itself finishes past the deadline
            time.sleep(0.001)
        return solve_now(program, args, scale, deadline + 60.0, names)

    monkeypatch.setattr(jerk_solve, "_solve_now", late)
    monkeypatch.setattr(jerk_solve, "_FATROP_TIME_S", 0.0)
    monkeypatch.setattr(jerk_solve, "_FATROP_ITERATIONS", 0)
    return deadlines


def test_a_late_solve_answers_the_floor_computed_while_it_ran(monkeypatch: pytest.MonkeyPatch) -> None:
    """A solve started within its deadline that finishes past it: the answer is the S-curve floor,
    computed in the plan's thread while the solve ran in its own (planner/jerk/solve.py,
    ``solve_in_time``'s ``meanwhile``), the same motion as the floor with no time for any solver."""
    import pvtflow.planner.jerk as jerk_module

    limits = ARM.joint_limits()
    max_jerk = 10.0 * limits.acceleration
    planner = Planner(limits)
    wp = random_paths(ARM, 1, seed=14)[0]
    # the program a deadline solves built (planner/jerk/screen.py), in this test alone too
    assert planner.plan(PlanInput(wp, max_jerk=max_jerk, jerk_intervals=48, budget_ms=60000.0)).ok
    join_solves()
    floor = jerk_module._floor
    solving: list[bool] = []
    deadlines = solves_late(monkeypatch)

    def floor_seen(*args, **kwargs):  # type: ignore[no-untyped-def]
        solving.append(bool(deadlines) and time.perf_counter() < deadlines[0])
        return floor(*args, **kwargs)

    monkeypatch.setattr(jerk_module, "_floor", floor_seen)
    res = planner.plan(PlanInput(wp, max_jerk=max_jerk, jerk_intervals=48, budget_ms=30.0))
    join_solves()
    assert res.ok, res.message
    assert res.details["solver"] == "scurve" and res.details["optimal"] is False
    assert solving == [True]  # computed once, while the solve ran (before its deadline)
    alone = planner.plan(PlanInput(wp, max_jerk=max_jerk, jerk_intervals=48, budget_ms=0.0))
    assert alone.details["solver"] == "scurve"
    assert res.trajectory.duration == pytest.approx(alone.trajectory.duration, rel=1e-12)
    assert max(dense_ratios(res.trajectory, limits, max_jerk)) <= 1.001


def test_a_late_solve_answers_the_floors_program_placed_while_it_ran(monkeypatch: pytest.MonkeyPatch) -> None:
    """Through the cell's planner: the floor's knots are placed (and validated) while the solve runs too
    (service/cell_planner.py, ``FloorKnots``), so a late solve's answer is that program, with no knots
    after the deadline; the budget keeps back only the answer's knots (``knots_reserve_ms``)."""

    planner = CellPlanner(ARM)
    max_jerk = 10.0 * ARM.joint_limits().acceleration
    wp = random_paths(ARM, 1, seed=15)[0]
    assert planner.plan(PlanInput(wp, max_jerk=max_jerk, jerk_intervals=48), None, None, 60000.0).ok  # built
    join_solves()
    build = cell_planner_module.build_program
    deadlines = solves_late(monkeypatch)
    placed: list[bool] = []

    def build_seen(*args, **kwargs):  # type: ignore[no-untyped-def]
        placed.append(bool(deadlines) and time.perf_counter() < deadlines[0])
        return build(*args, **kwargs)

    monkeypatch.setattr(cell_planner_module, "build_program", build_seen)
    budget_ms = 400.0
    began = time.perf_counter()
    res = planner.plan(PlanInput(wp, max_jerk=max_jerk, jerk_intervals=48), None, None, budget_ms)
    join_solves()
    assert res.ok, res.message
    assert res.optimal is False and res.plan.details["solver"] == "scurve"
    assert placed == [True]  # placed once, while the solve ran, and not again after it
    assert deadlines[0] - began == pytest.approx(
        1e-3 * (budget_ms - cell_planner_module.knots_reserve_ms(budget_ms, True)), abs=0.02
    )
    assert validate_program(res.program).ok
