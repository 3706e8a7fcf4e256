"""The shipped data: found through pvtflow.configs alone, installed whole, and its cells named on the command line."""

from __future__ import annotations

import re
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import pytest

from pvtflow.configs import CELLS_DIR, CONFIG_DIR, shipped_cell, shipped_cells
from pvtflow.service.config import ConfigError, load_cell_config

ROOT = Path(__file__).resolve().parents[2]
CODE = ("axes", "planner", "service")


def test_the_data_is_the_clones_configs_folder_here() -> None:
    assert CONFIG_DIR == ROOT / "configs"
    assert {"arm6", "gantry3", "gantry3-mixed"} <= set(shipped_cells())
    assert shipped_cell("gantry3") == CELLS_DIR / "gantry3.yaml"
    assert shipped_cell("gantry4") is None


def test_every_shipped_file_is_package_data() -> None:
    """A file in configs/ that pyproject's package-data does not name would be missing from the wheel."""
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    data = globs["pvtflow.configs"]
    files = [
        p.relative_to(CONFIG_DIR).as_posix()
        for p in CONFIG_DIR.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.name != "__init__.py"
    ]
    assert len(files) > 15
    assert [f for f in files if not any(fnmatch(f, g) for g in data)] == []


def test_no_module_builds_a_path_to_the_data_from_its_own_file() -> None:
    """pvtflow.configs is the one module that knows where the data lives: an installed tree has no ../../configs."""
    offenders = [
        str(p.relative_to(ROOT))
        for package in CODE
        for p in sorted((ROOT / package).rglob("*.py"))
        if re.search(r"""["']configs["']""", p.read_text(encoding="utf-8"))
    ]
    assert offenders == []


def test_a_shipped_cell_is_named_by_its_name_from_any_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    cell = load_cell_config("gantry3-mixed")
    assert cell.source == CELLS_DIR / "gantry3-mixed.yaml"
    assert cell.name == load_cell_config(CELLS_DIR / "gantry3-mixed.yaml").name


def test_a_file_of_that_name_is_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "arm6").write_text("name: [not, a, cell]\n")
    with pytest.raises(ConfigError) as caught:
        load_cell_config("arm6")
    assert str(caught.value).startswith("arm6: name:")


def test_an_unknown_name_says_which_cells_are_shipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError) as caught:
        load_cell_config("arm7")
    assert str(caught.value) == f"arm7: file not found (nor a shipped cell: {', '.join(shipped_cells())})"
