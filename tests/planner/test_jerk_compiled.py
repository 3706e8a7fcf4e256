"""The program's functions compiled (planner/jerk/compiled.py): the interpreted program's answer, built once
per machine into the user's cache folder, and the interpreted program with one warning where no compiler
builds it."""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import pvtflow.planner.jerk as jerk_module
from pvtflow.planner.jerk import compiled
from pvtflow.planner.jerk.nlp import build_nlp
from pvtflow.planner.jerk.solve import Program, Solution, _solve_now
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
MAX_JERK = 10.0 * LIMITS.acceleration
INTERVALS = 48  # the coarsest program: cheap to build and solve
SHAPE = (INTERVALS, jerk_module.ROW_JOINTS, False)  # the screened program a deadline solves on arm6's joint limits
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def compiling(monkeypatch: pytest.MonkeyPatch) -> None:
    """The suite keeps programs interpreted (tests/conftest.py); these tests compile."""
    monkeypatch.setenv("PVTFLOW_JERK_COMPILE", "on")


def test_compiling_can_be_turned_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PVTFLOW_JERK_COMPILE", "off")
    monkeypatch.setattr(compiled, "compile_library", lambda *_: pytest.fail("compiled although off"))
    program = Program(*SHAPE, *build_nlp(*SHAPE))
    assert not program.use_compiled() and not program.compiled


@pytest.fixture(scope="module")
def request_args() -> tuple[dict[str, Any], np.ndarray]:
    """The screened program's arguments for a plan with a deadline (8 waypoints, as a request's)."""
    captured: list[tuple[dict[str, Any], np.ndarray]] = []
    solve_in_time = jerk_module.solve_in_time

    def spy(program: Program, args: dict[str, Any], scale: np.ndarray, *rest: Any) -> Any:
        captured.append((args, scale))
        return solve_in_time(program, args, scale, *rest)

    rng = np.random.default_rng(3)
    waypoints = LIMITS.lower + (LIMITS.upper - LIMITS.lower) * (0.1 + 0.8 * rng.random((8, LIMITS.dof)))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(jerk_module, "solve_in_time", spy)
        Planner(LIMITS).plan(PlanInput(waypoints, max_jerk=MAX_JERK, jerk_intervals=INTERVALS, budget_ms=60_000.0))
    assert captured
    return captured[0]


def solve(program: Program, args: tuple[dict[str, Any], np.ndarray]) -> Solution:
    solution, status, _ = _solve_now(program, args[0], args[1], float("inf"))
    assert solution is not None, status
    return solution


def test_the_compiled_program_gives_the_interpreted_programs_answer_and_is_built_once(
    request_args: tuple[dict[str, Any], np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    interpreted = Program(*SHAPE, *build_nlp(*SHAPE))
    fast = Program(*SHAPE, *build_nlp(*SHAPE))
    assert fast.use_compiled()  # built here, or loaded where a warm-up built it (the session's cache)
    assert fast.compiled and not interpreted.compiled
    library = compiled.library_path(*SHAPE)
    assert library.is_file() and not library.is_relative_to(REPO)  # the user's cache folder, never the repository
    n, dof, torque = SHAPE
    assert list(library.parent.glob(f"jerk_{n}_{dof}_{int(torque)}_*.so")) == [library]  # no older code's kept
    a, b = solve(interpreted, request_args), solve(fast, request_args)
    assert abs(np.sum(b.h) / np.sum(a.h) - 1.0) < 1e-9  # the same duration
    for x, y in ((a.sd, b.sd), (a.sdd, b.sdd), (a.h, b.h)):
        np.testing.assert_allclose(y, x, rtol=1e-7, atol=1e-9 * float(np.max(np.abs(x))))
    # kept on disk: a program of the same shape in a later process loads it, no compiler run
    monkeypatch.setattr(compiled, "compile_library", lambda *_: pytest.fail("compiled again"))
    later = Program(*SHAPE, *build_nlp(*SHAPE))
    assert later.use_compiled(build=False)
    np.testing.assert_array_equal(solve(later, request_args).h, b.h)


@pytest.mark.parametrize("cc", ["/nonexistent/cc", "false"])
def test_without_a_working_compiler_the_interpreted_program_solves_after_one_warning(
    cc: str,
    request_args: tuple[dict[str, Any], np.ndarray],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    monkeypatch.setenv("PVTFLOW_CACHE_DIR", str(tmp_path))  # nothing built yet
    monkeypatch.setenv("CC", cc)  # missing, or one that fails
    monkeypatch.setattr(compiled, "_warned", threading.Event())  # a fresh process
    programs = [Program(*SHAPE, *build_nlp(*SHAPE)) for _ in range(2)]
    with caplog.at_level(logging.WARNING, logger="pvtflow.planner"):
        assert not any(program.use_compiled() for program in programs)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "not compiled" in warnings[0].getMessage()
    assert not any(tmp_path.rglob("*.so"))  # no half-written library left for the next process to load
    assert not programs[0].compiled
    assert solve(programs[0], request_args).solver == "fatrop"
