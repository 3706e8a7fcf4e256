"""Session set-up and fixtures shared by every test package (tests/axes, planner, service, e2e).

Helper modules beside this file (axes_rig, axes_programs, hand_programs, svc_helpers, frame_log) are
importable from every test package: pytest puts this directory on sys.path with this conftest."""

from __future__ import annotations

import gc
import os
import sys
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from hypothesis import settings

from pvtflow.axes.canbus.collector import full_collections_by_hand
from pvtflow.service.config import CellConfig, load_cell_config

if TYPE_CHECKING:
    from svc_helpers import Served

    from pvtflow.service.motion import MotionService

# The suite is a gate: the property tests draw the same examples on every run (a new failing draw
# would otherwise fail an unrelated change). ``--hypothesis-profile=explore`` draws new ones.
settings.register_profile("default", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("default")

# the jerk-limited programs stay interpreted (the same answers): a fresh CI machine would otherwise spend 15-25 s
# of gcc on the program shapes the services' warm-ups meet; tests/planner/test_jerk_compiled.py compiles
os.environ.setdefault("PVTFLOW_JERK_COMPILE", "off")

REPO = Path(__file__).resolve().parents[1]
_OUTSIDE = str(REPO.parent / "shared")  # the team's folder beside a checkout: a user's clone has none


def _refuse_outside(event: str, args: tuple[object, ...]) -> None:
    """The suite must pass on a clone alone: any file opened or listed in ../shared fails the test
    that does it (CI runs with ../shared beside the clone, where such a read would pass unseen)."""
    if event not in ("open", "os.listdir", "os.scandir") or not args:
        return
    path = args[0]
    if isinstance(path, int) or path is None:
        return
    text = os.fsdecode(path) if isinstance(path, str | bytes | os.PathLike) else ""
    if text and os.path.abspath(text).startswith(_OUTSIDE):
        raise PermissionError(f"the project reads {text}, outside the repository: keep what it needs inside it")


sys.addaudithook(_refuse_outside)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Load (on a new machine: compile, once) the planner's numba kernels before the tests start,
    in the main process only: test workers then load them from numba's cache instead of each
    compiling them, and no test's timeout includes a compilation."""
    if hasattr(session.config, "workerinput"):  # a pytest-xdist worker
        return
    from pvtflow.service.cell_planner import CellPlanner

    CellPlanner(load_cell_config()).warm_up()
    full_collections_by_hand()


# The master and the simulated drives share this process in most tests. CPython's full collection
# over what the tests before have left (services, object dictionaries, plans) took 50-250 ms in the
# suite (bench/RESULTS.md, "Full collections in the test process"): a pause no drive and no
# heartbeat watch sees on a machine, where the service freezes its start-up objects
# (``axes/canbus/collector.py``) and the drives' process collects between motions
# (``axes/canbus/collector.py``). This process does as the drives' process does: what the session
# start loaded is frozen, and the full collection runs between tests, never by allocation count.
FULL_COLLECTION_EVERY_TESTS = 10
_tests_since_full_collection = 0


def pytest_runtest_logfinish(nodeid: str, location: tuple[str, int | None, str]) -> None:
    """After a test and its fixtures' teardown: the full collection, every few tests."""
    global _tests_since_full_collection
    _tests_since_full_collection += 1
    if _tests_since_full_collection >= FULL_COLLECTION_EVERY_TESTS:
        _tests_since_full_collection = 0
        gc.collect()


@pytest.fixture(scope="session")
def arm6() -> CellConfig:
    return load_cell_config(None)


@pytest.fixture(scope="session")
def gantry3() -> CellConfig:
    return load_cell_config(REPO / "configs" / "cells" / "gantry3.yaml")


@pytest.fixture(scope="session")
def arm6_planning(arm6: CellConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[MotionService]:
    """arm6's service planning in a process of its own (as real cells plan), not opened (no bus): one
    child for the tests that compare its plans with this process's (its start-up and warm-up are seconds)."""
    from pvtflow.service.motion import MotionService
    from pvtflow.service.planning import PlanningProcess

    service = MotionService(arm6, journal_dir=tmp_path_factory.mktemp("planning"), planner_process=True)
    try:
        assert isinstance(service.planner, PlanningProcess)
        yield service
    finally:
        service.close()


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Callable[..., Served]]:
    """serve(cell, journal_dir=None, zconfig=None, client=None, port=None) -> Served (svc_helpers: real
    zenoh sessions on loopback, simulated drives), closed after the test."""
    from svc_helpers import served_cell  # zenoh and the service: loaded by the tests that serve a cell

    with ExitStack() as stack:

        def make(cell: CellConfig, *, journal_dir: Path | None = None, **kwargs: object) -> Served:
            jdir = journal_dir or (tmp_path / f"journal-{cell.name}-{uuid.uuid4().hex[:6]}")
            return stack.enter_context(served_cell(cell, jdir, **kwargs))  # type: ignore[arg-type]

        yield make
