"""``pvtflow home`` and ``pvtflow execute --home`` on the simulated gantry (incremental encoders):
homed in the cell's order; without ``--home`` the gantry refuses a program (not_homed), nothing sent."""

from __future__ import annotations

from pathlib import Path

import pytest

from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import plan_cell_program
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"


@pytest.fixture(scope="module")
def gantry3() -> CellConfig:
    return load_cell_config(GANTRY)


@pytest.fixture(scope="module")
def from_home(gantry3: CellConfig, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A program that starts where the gantry's axes stand once homed (each reads its home offset)."""
    home = [float(a.scaling.qc_to_position(a.homing.offset_qc)) for a in gantry3.ordered_axes() if a.homing is not None]
    result = plan_cell_program(gantry3, PlanInput([home, [0.1, 0.08, -0.05]]))
    assert result.ok and result.program is not None, result.message
    path = tmp_path_factory.mktemp("gantry") / "from-home.json"
    path.write_text(result.program.dumps())
    return path


def test_pvtflow_home_homes_the_gantry_in_its_order(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["home", "--config", str(GANTRY)]) == 0
    out = capsys.readouterr().out
    assert out.index("homing z") < out.index("homing x, y")  # homing_order: [z, [x, y]]
    assert "homed: homed z, x + y" in out
    for line in ("x (node 11, method 1): homed", "y (node 12, method 1): homed", "z (node 13, method 2): homed"):
        assert line in out
    assert "position 1500 qc" in out and "position 900 qc" in out and "position -1200 qc" in out


def test_pvtflow_home_refuses_what_the_cell_does_not_have(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["home", "--config", str(GANTRY), "--joints", "x,w"]) == 2
    assert "unknown axis 'w'" in capsys.readouterr().err
    assert main(["home"]) == 1  # arm6: absolute encoders
    assert "has no axis to home" in capsys.readouterr().err


def test_execute_refuses_an_unhomed_gantry_and_homes_it_with_home(
    from_home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["execute", str(from_home), "--config", str(GANTRY), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "not_homed: cell gantry3 must home first" in err and "nothing was sent" in err
    assert main(["execute", str(from_home), "--config", str(GANTRY), "--quiet", "--home"]) == 0
    out = capsys.readouterr().out
    assert "homed: homed z, x + y" in out
    assert "finished: every axis reached its end record" in out


def test_the_gantry_demo_homes_first_and_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plot = tmp_path / "demo.png"
    assert main(["demo", "--config", str(GANTRY), "--plot", str(plot), "--tour-points", "1"]) == 0
    out = capsys.readouterr().out
    assert "homing first: cell gantry3 requires it" in out
    assert "homed z then x + y" in out and out.index("homed z then x + y") < out.index("outcome: finished")
