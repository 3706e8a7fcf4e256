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


def test_every_package_of_the_tree_is_installed() -> None:
    """pyproject lists the packages by hand (package-dir maps the top-level folders below pvtflow): a folder
    with an ``__init__.py`` left out of the list would be missing from a regular install."""
    import tomllib

    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"pvtflow"} | {
        "pvtflow." + ".".join(init.parent.relative_to(REPO).parts)
        for top in ("axes", "planner", "service", "configs")
        for init in (REPO / top).rglob("__init__.py")
    }
    assert sorted(found - listed) == [] and sorted(listed - found) == []
