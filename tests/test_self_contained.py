"""A clone alone installs, runs and passes: nothing reads the team's ../shared folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from pvtflow.axes.sim.drive import MAXON_EPOS2_EDS

REPO = Path(__file__).resolve().parents[1]


def test_a_read_outside_the_repository_fails_the_test() -> None:
    """The guard of tests/conftest.py is live: a read of ../shared raises."""
    with pytest.raises(PermissionError, match="outside the repository"):
        (REPO.parent / "shared" / "DESIGN.md").read_text()


def test_the_vendor_eds_is_inside_the_repository() -> None:
    assert MAXON_EPOS2_EDS.is_file()
    assert REPO in MAXON_EPOS2_EDS.resolve().parents
    assert (MAXON_EPOS2_EDS.parent / "README.md").read_text().count("maxon") >= 1
