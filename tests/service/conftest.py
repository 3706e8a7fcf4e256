"""Fixtures of the service tests (helpers in svc_helpers.py): real zenoh sessions on loopback, simulated drives."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
from svc_helpers import CONFIGS, Served, served_cell

from service.config import CellConfig, load_cell_config


@pytest.fixture(scope="session")
def arm6() -> CellConfig:
    return load_cell_config(None)


@pytest.fixture(scope="session")
def gantry3() -> CellConfig:
    return load_cell_config(CONFIGS / "cells" / "gantry3.yaml")


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Callable[..., Served]]:
    """serve(cell, journal_dir=None, zconfig=None, client=None, port=None) -> Served, closed after the test."""
    with ExitStack() as stack:

        def make(cell: CellConfig, *, journal_dir: Path | None = None, **kwargs: object) -> Served:
            jdir = journal_dir or (tmp_path / f"journal-{cell.name}-{uuid.uuid4().hex[:6]}")
            return stack.enter_context(served_cell(cell, jdir, **kwargs))  # type: ignore[arg-type]

        yield make
