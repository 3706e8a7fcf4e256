"""Session set-up shared by every test package."""

from __future__ import annotations

import pytest


def pytest_sessionstart(session: pytest.Session) -> None:
    """Load (on a new machine: compile, once) the planner's numba kernels before the tests start,
    in the main process only: test workers then load them from numba's cache instead of each
    compiling them, and no test's timeout includes a compilation."""
    if hasattr(session.config, "workerinput"):  # a pytest-xdist worker
        return
    from service.config import load_cell_config
    from service.plan_cmd import CellPlanner

    CellPlanner(load_cell_config()).warm_up()
