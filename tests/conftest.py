"""Session set-up shared by every test package."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hypothesis import settings

# The suite is a gate: the property tests draw the same examples on every run (a new failing draw
# would otherwise fail an unrelated change). ``--hypothesis-profile=explore`` draws new ones.
settings.register_profile("default", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("default")

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
    from service.cell_planner import CellPlanner
    from service.config import load_cell_config

    CellPlanner(load_cell_config()).warm_up()
