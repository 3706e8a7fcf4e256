"""Fewer rows per stage within a deadline (planner/jerk/screen.py): the same answer where the joints
left out do not bind, and where one does, an answer within every limit that does not claim the optimum."""

from __future__ import annotations

import numpy as np
import pytest

import pvtflow.planner.jerk as jerk_module
from pvtflow.planner.jerk.solve import PROGRAMS
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
MAX_JERK = 10.0 * LIMITS.acceleration
INTERVALS = 48  # the coarsest program: cheap to build and solve


def path(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return LIMITS.lower + (LIMITS.upper - LIMITS.lower) * (0.1 + 0.8 * rng.random((8, LIMITS.dof)))


def dense_ratio(traj) -> float:
    t = traj.check_times(64)
    return max(
        float(np.max(np.abs(traj.velocity(t)) / LIMITS.velocity)),
        float(np.max(np.abs(traj.acceleration(t)) / LIMITS.acceleration)),
        float(np.max(np.abs(traj.jerk(t)) / MAX_JERK)),
    )


@pytest.mark.parametrize("seed", [5, 9])
def test_within_a_deadline_the_screened_program_gives_the_whole_programs_answer(seed: int) -> None:
    planner = Planner(LIMITS)
    whole = planner.plan(PlanInput(path(seed), max_jerk=MAX_JERK, jerk_intervals=INTERVALS))
    row_dof = jerk_module.ROW_JOINTS
    assert row_dof < LIMITS.dof
    PROGRAMS.get(INTERVALS, row_dof, False)  # built: the deadline below solves it
    solves = len(PROGRAMS.ready(INTERVALS, row_dof, False).fatrop_s)
    screened = planner.plan(PlanInput(path(seed), max_jerk=MAX_JERK, jerk_intervals=INTERVALS, budget_ms=60000.0))
    assert len(PROGRAMS.ready(INTERVALS, row_dof, False).fatrop_s) == solves + 1  # the screened program solved it
    assert whole.details["optimal"] is True and screened.details["optimal"] is True
    # each solved to fatrop's tolerance (1e-6 of the duration); a program's answer also moves by about that with
    # the solve before it (casadi's fatrop keeps state: path 5 after path 14 on the same program, 1.3e-6)
    assert screened.trajectory.duration == pytest.approx(whole.trajectory.duration, rel=5e-6)
    assert dense_ratio(screened.trajectory) <= 1.001


def test_a_joint_left_out_that_binds_is_caught_the_limits_held_and_no_optimum_claimed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """One joint's rows per stage: others bind in the solver's answer; the check after the solve sees
    it (``optimal`` False) and the dense check slows the motion until every joint holds its limits."""
    planner = Planner(LIMITS)
    whole = planner.plan(PlanInput(path(5), max_jerk=MAX_JERK, jerk_intervals=INTERVALS))
    monkeypatch.setattr(jerk_module, "ROW_JOINTS", 1)
    PROGRAMS.get(INTERVALS, 1, False)
    one = planner.plan(PlanInput(path(5), max_jerk=MAX_JERK, jerk_intervals=INTERVALS, budget_ms=60000.0))
    assert one.ok and one.details["solver"] == "fatrop" and one.details["optimal"] is False
    assert dense_ratio(one.trajectory) <= 1.001
    assert one.trajectory.duration > whole.trajectory.duration
