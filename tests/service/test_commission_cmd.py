"""``pvtflow commission``: per axis what the drive is against the cell; exit 0 agree, 1 mismatch
(named: object, expected, found), 2 cannot start; ``--json`` the same as one object. ``home``
refuses a cell whose drive differs, with the mismatch named, nothing moved."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"
Y_SIMULATION = "index_spacing_qc: 4096, index_offset_qc: 900}"


def gantry_with_y(tmp_path: Path, drive: str) -> Path:
    """gantry3 whose y drive is ``drive`` (simulation keys) instead of what the cell says."""
    text = GANTRY.read_text().replace("urdf: ../robots/gantry3.urdf", "name: gantry3")
    assert Y_SIMULATION in text
    path = tmp_path / "gantry3.yaml"
    path.write_text(text.replace(Y_SIMULATION, Y_SIMULATION[:-1] + f", {drive}}}"))
    return path


def test_a_cell_that_agrees_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["commission", "--config", str(GANTRY)]) == 0
    out = capsys.readouterr().out
    assert "cell gantry3: 3 drives, every one as the cell expects" in out
    assert "x (node 11, epos2_pvt): ok" in out and "MISMATCH" not in out


def test_a_mismatch_exits_1_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["commission", "--config", str(gantry_with_y(tmp_path, "polarity: 128"))]) == 1
    captured = capsys.readouterr()
    assert "y (node 12, epos2_pvt): FAILED: 1 mismatch" in captured.out
    assert "y (node 12): 0x607E polarity: expected 0x00 (not inverted), found 0x80" in captured.err


def test_json_is_one_object_with_a_list_of_checks_per_axis(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = gantry_with_y(tmp_path, "qc_per_motor_rev: 2048")
    assert main(["commission", "--config", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["cell"] == "gantry3" and report["ok"] is False and report["sdo_transfers"] > 0
    assert [a["joint"] for a in report["axes"]] == ["x", "y", "z"]
    for axis in report["axes"]:
        assert set(axis) == {"joint", "node_id", "profile", "ok", "not_checked", "checks"}
        for check in axis["checks"]:
            assert set(check) == {"object", "name", "expected", "found", "agrees", "kind", "required", "status"}
            assert check["kind"] in ("fact", "setting", "info")
            assert check["status"] in ("ok", "mismatch", "not_checked")
    checks = [(a["joint"], c) for a in report["axes"] for c in a["checks"]]
    wrong = [(joint, c["object"], c["expected"], c["found"]) for joint, c in checks if c["status"] != "ok"]
    assert wrong == [("y", "0x2210:01", "4096 qc/rev", "2048 qc/rev (512 pulses)")]


def test_cannot_start_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["commission", "--config", str(tmp_path / "missing.yaml")]) == 2
    assert "pvtflow commission:" in capsys.readouterr().err


def test_home_refuses_a_drive_that_is_not_what_the_cell_says(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = gantry_with_y(tmp_path, "vendor_id: 0x1234")
    assert main(["home", "--config", str(path), "--quiet"]) == 1
    out = capsys.readouterr().out
    assert "configuration_error: node 12: axis y is not the drive the cell expects: 0x1018:01-02 identity" in out
    assert "found vendor 0x00001234 product 0x00000001" in out
    assert "not homed" in out


def test_the_cell_names_the_identity_of_a_drive_pvtflow_does_not_know(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = gantry_with_y(tmp_path, "vendor_id: 0x1234")
    identity = "    identity: {vendor_id: 0x1234, product_code: 1}\n"
    text = path.read_text().replace("  - joint: y\n", "  - joint: y\n" + identity)
    path.write_text(text)
    assert main(["commission", "--config", str(path)]) == 0
    assert "found vendor 0x00001234 product 0x00000001 (the cell's identity)" in capsys.readouterr().out
    path.write_text(text.replace("product_code: 1}", "product_code: -1}"))
    assert main(["commission", "--config", str(path)]) == 2
    assert "axes[1].identity.product_code: -1 is outside [0, 4294967295]" in capsys.readouterr().err
