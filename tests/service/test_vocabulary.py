"""One vocabulary: the same condition gets the same error code and the same words from the command line
(``pvtflow plan``, ``pvtflow execute``, without a service) and from the service (service/api/refusals.py)."""

from __future__ import annotations

import json
from pathlib import Path

from svc_helpers import CONFIGS

from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.service.cli import main
from pvtflow.service.config import CellConfig

GANTRY = CONFIGS / "cells" / "gantry3.yaml"


def shifted_program(cell: CellConfig, tmp_path: Path) -> tuple[Path, PvtProgram]:
    """A valid arm6 program whose first axis starts 5000 qc from where a fresh cell stands."""
    from axes_programs import program

    prog = program(cell.ordered_axes(), 300, spacing_ms=10, cell=cell.name)
    a = prog.axes[0]
    records = a.records.copy()
    records[:, 0] += 5000
    axes = list(prog.axes)
    axes[0] = AxisProgram.of(a, records)
    shifted = PvtProgram(prog.cell, tuple(axes))
    path = tmp_path / "shifted.json"
    path.write_text(shifted.dumps())
    return path, shifted


def test_a_start_elsewhere_is_start_mismatch_in_both(serve, arm6, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    path, shifted = shifted_program(arm6, tmp_path)
    assert main(["execute", str(path), "--quiet"]) == 1
    err = capsys.readouterr().err
    words = "axis joint_1 is at 0 qc, the program starts at 5000 qc"
    assert f"start_mismatch: {words}" in err, err
    assert "rejected" not in err
    reply = serve(arm6).request("execute", {"program": json.loads(shifted.dumps())})
    assert not reply.ok and reply.error_code == "start_mismatch", reply.data
    assert reply.data["error"]["message"].startswith(words)


def test_a_waypoint_out_of_limits_is_out_of_limits_in_both(serve, arm6, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    rows = [[0.0] * 6, [0.1, 99.0, 0.0, 0.0, 0.0, 0.0]]
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": rows}))
    assert main(["plan", "--waypoints", str(wp), "-o", str(tmp_path / "p.json")]) == 1
    err = capsys.readouterr().err
    reply = serve(arm6).request("plan", {"waypoints": rows, "start": "first"})
    assert not reply.ok and reply.error_code == "out_of_limits", reply.data
    assert f"out_of_limits: {wp}: {reply.data['error']['message']}" in err, err
    assert not (tmp_path / "p.json").exists()


def test_a_speed_override_of_zero_has_the_same_words_in_both(serve, arm6, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": [[0.0] * 6, [0.1] * 6]}))
    assert main(["plan", "--waypoints", str(wp), "-o", str(tmp_path / "p.json"), "--velocity-scale", "0"]) == 2
    err = capsys.readouterr().err
    assert "invalid_request: --velocity-scale must be in (0, 1], got 0" in err, err
    reply = serve(arm6).request("plan", {"target": [0.1] * 6, "velocity_scale": 0})
    assert not reply.ok and reply.error_code == "invalid_request"
    assert reply.data["error"]["message"] == "$.velocity_scale: velocity_scale must be in (0, 1], got 0"


def test_an_unhomed_cell_is_not_homed_in_both(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from pvtflow.service.api import refusals

    program = tmp_path / "g.json"
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": [[0.05, 0.05, -0.05], [0.06, 0.045, -0.05]]}))
    assert main(["plan", "--config", str(GANTRY), "--waypoints", str(wp), "-o", str(program)]) == 0
    capsys.readouterr()
    assert main(["execute", str(program), "--config", str(GANTRY), "--quiet"]) == 1
    err = capsys.readouterr().err
    service_words = refusals.not_homed("gantry3", ["x", "y", "z"]).message.removesuffix("call home")
    assert f"not_homed: {service_words}" in err, err
