"""A program for another cell: ``pvtflow execute`` names the program's cell and the --config that fits,
one line per differing field; ``pvtflow validate PROGRAM --config CELL`` checks the fit offline."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from pvtflow.service.cli import main

ROOT = Path(__file__).resolve().parents[2]
GANTRY = ROOT / "configs" / "cells" / "gantry3.yaml"


@pytest.fixture(scope="module")
def gantry_program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("fit")
    wp = folder / "wp.json"
    wp.write_text(json.dumps({"waypoints": [[0.05, 0.05, -0.05], [0.06, 0.045, -0.05]]}))
    out = folder / "gantry3.json"
    assert main(["plan", "--config", str(GANTRY), "--waypoints", str(wp), "-o", str(out)]) == 0
    return out


def slower_gantry(tmp_path: Path) -> Path:
    """gantry3 with x's 0x607F lowered: the same cell name, one limit different."""
    data = yaml.safe_load(GANTRY.read_text())
    data["robot"]["urdf"] = str(ROOT / "configs" / "robots" / "gantry3.urdf")
    data["axes"][0]["limits"]["max_profile_velocity_rpm"] = 2500
    path = tmp_path / "slower.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_execute_on_another_cell_names_the_programs_cell_and_the_config_that_fits(
    gantry_program: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(ROOT)
    capsys.readouterr()
    assert main(["execute", str(gantry_program), "--quiet"]) == 1  # the default cell: arm6
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert "the program was made for cell gantry3, this is cell arm6" in err
    assert "it fits --config configs/cells/gantry3.yaml" in err
    assert "wrong_cell: the program was not made for cell arm6: it was made for cell gantry3" in lines[-1]
    assert err.count("no axis for node") <= 3 and "more differences" in err
    assert len(lines) <= 8, err


def test_one_changed_limit_is_one_line_naming_the_field(
    gantry_program: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    assert main(["execute", str(gantry_program), "--config", str(slower_gantry(tmp_path)), "--quiet", "--home"]) == 1
    err = capsys.readouterr().err
    assert "axis x (node 11): limits.max_profile_velocity_rpm 3000 in the program, 2500 in cell gantry3" in err
    assert "{" not in err, err


def test_validate_with_config_exits_0_when_it_fits_and_1_naming_what_differs(
    gantry_program: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    assert main(["validate", str(gantry_program), "--config", str(GANTRY)]) == 0
    assert "fits cell gantry3" in capsys.readouterr().out
    assert main(["validate", str(gantry_program), "--config", str(slower_gantry(tmp_path))]) == 1
    out = capsys.readouterr().out
    assert "does not fit cell gantry3" in out and "limits.max_profile_velocity_rpm 3000 in the program" in out
    assert main(["validate", str(gantry_program), "--config", str(ROOT / "configs" / "cells" / "arm6.yaml")]) == 1
    out = capsys.readouterr().out
    assert "made for cell gantry3" in out and "gantry3.yaml" in out
    assert main(["validate", str(gantry_program), "--config", str(GANTRY), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fits"] == {"cell": "gantry3", "ok": True, "problems": []}
    assert main(["validate", str(gantry_program), "--config", str(tmp_path / "none.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "file not found" in err[0]
