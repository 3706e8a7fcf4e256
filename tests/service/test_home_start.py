"""A homed gantry runs an offline program: plans start at the cell's home position (``--start home`` /
``start: "home"``), and an explicit approach move (``pvtflow execute --approach``, the execute request's
``approach: true``) takes the axes to a program's start; never implicitly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.service.cli import main

ROOT = Path(__file__).resolve().parents[2]
GANTRY = ROOT / "configs" / "cells" / "gantry3.yaml"
ROWS = [[0.05, 0.05, -0.05], [0.06, 0.045, -0.05]]
HOME_QC = [1500, 900, -1200]  # gantry3's homing offsets (0x607C) of x, y, z


@pytest.fixture
def wp(tmp_path: Path) -> Path:
    path = tmp_path / "wp.json"
    path.write_text(json.dumps({"waypoints": ROWS}))
    return path


def plan(wp: Path, out: Path, *extra: str) -> PvtProgram:
    assert main(["plan", "--config", str(GANTRY), "--waypoints", str(wp), "-o", str(out), *extra]) == 0
    return PvtProgram.loads(out.read_text())


def test_a_plan_from_home_runs_after_homing(wp: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    program = plan(wp, tmp_path / "home.json", "--start", "home")
    assert [int(a.records[0, 0]) for a in program.axes] == HOME_QC
    capsys.readouterr()
    assert main(["execute", str(tmp_path / "home.json"), "--config", str(GANTRY), "--home", "--quiet"]) == 0
    assert "finished: every axis reached its end record" in capsys.readouterr().out


def test_a_program_elsewhere_is_refused_unless_the_approach_is_asked_for(
    wp: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "first.json"
    plan(wp, path)
    capsys.readouterr()
    assert main(["execute", str(path), "--config", str(GANTRY), "--home", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "start_mismatch: axis x is at 1500 qc, the program starts at 10240 qc" in err and "--approach" in err
    assert main(["execute", str(path), "--config", str(GANTRY), "--home", "--approach"]) == 0
    out = capsys.readouterr().out
    assert "approach: a " in out and "s joint move to the program's start" in out
    assert "finished: every axis reached its end record" in out.split("approach:")[1]


def test_a_cell_without_a_home_says_so(wp: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arm = tmp_path / "arm.json"
    arm.write_text(json.dumps({"waypoints": [[0.1] * 6]}))
    assert main(["plan", "--waypoints", str(arm), "-o", str(tmp_path / "x.json"), "--start", "home"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--start home: cell arm6 has no home position" in err[0], err
    assert not (tmp_path / "x.json").exists()


def test_the_service_plans_from_home_and_approaches_on_request(serve, gantry3, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    served = serve(gantry3)
    assert served.request("home", {"wait": True}, timeout=120).ok
    home = served.request("plan", {"waypoints": ROWS, "start": "home"})
    assert home.ok, home.data
    assert home.data["waypoints"] == 3
    ran = served.request("execute", {"plan_id": home.data["plan_id"], "wait": True}, timeout=60)
    assert ran.ok and ran.data["outcome"]["result"] == "finished" and ran.data["approach"] is None, ran.data
    # now the axes stand at ROWS[-1]: a plan that starts at ROWS[0] starts elsewhere
    first = served.request("plan", {"waypoints": [ROWS[0], [0.07, 0.05, -0.05]], "start": "first"})
    assert first.ok, first.data
    refused = served.request("execute", {"plan_id": first.data["plan_id"]})
    assert refused.error_code == "start_mismatch", refused.data
    moved = served.request("execute", {"plan_id": first.data["plan_id"], "approach": True, "wait": True}, timeout=60)
    assert moved.ok, moved.data
    assert moved.data["approach"]["outcome"]["result"] == "finished"
    assert moved.data["outcome"]["result"] == "finished"
    labels = [m.label for m in served.service.journal.recent(10)]
    assert f"approach to {first.data['plan_id']}" in labels, labels


def test_start_home_on_a_cell_without_one_is_refused(serve, arm6) -> None:  # type: ignore[no-untyped-def]
    reply = serve(arm6).request("plan", {"target": [0.1] * 6, "start": "home"})
    assert reply.error_code == "not_allowed" and "cell arm6 has no home position" in reply.data["error"]["message"]
