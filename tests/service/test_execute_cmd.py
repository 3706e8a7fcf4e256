"""``pvtflow execute``: validated, matched to the cell, run on the simulated arm6 cell; clear exits."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import can
import numpy as np
import pytest
from axes_programs import program

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.service.cli import main


@pytest.fixture
def arm6_program(arm6) -> PvtProgram:
    return program(arm6.ordered_axes(), 300, spacing_ms=10, cell="arm6")


def write(tmp_path: Path, prog: PvtProgram, name: str = "program.json") -> Path:
    path = tmp_path / name
    path.write_text(prog.dumps())
    return path


def replace_axis(prog: PvtProgram, index: int, **changes) -> PvtProgram:
    a = prog.axes[index]
    axes = list(prog.axes)
    axes[index] = dataclasses.replace(a, **changes)
    return PvtProgram(prog.cell, tuple(axes))


def test_executes_on_the_simulated_demo_cell(tmp_path, arm6_program, arm6, capsys):
    log = tmp_path / "traffic.log"
    code = main(["execute", str(write(tmp_path, arm6_program)), "--can-log", str(log)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "finished: every axis reached its end record" in out
    assert "start skew 0 SYNC(s)" in out
    for axis in arm6_program.axes:
        assert f"({axis.records[-1, 0]} qc; program end {axis.records[-1, 0]} qc)" in out
    frames = list(can.LogReader(str(log)))
    assert sum(1 for m in frames if m.arbitration_id == 0x80) >= arm6_program.duration_ms / arm6.bus.sync_period_ms
    assert sum(1 for m in frames if m.arbitration_id == 0x201) == len(arm6_program.axes[0].records)


@pytest.mark.parametrize("content", [None, "not json", json.dumps({"format": "something else"}), "[]"])
def test_unreadable_program_exits_2(tmp_path, capsys, content):
    path = tmp_path / "p.json"
    if content is not None:
        path.write_text(content)
    assert main(["execute", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pvtflow execute: ")


def test_unreadable_config_exits_2(tmp_path, arm6_program, capsys):
    code = main(["execute", str(write(tmp_path, arm6_program)), "--config", str(tmp_path / "none.yaml")])
    assert code == 2
    assert "file not found" in capsys.readouterr().err


def test_program_breaking_a_limit_is_refused_before_the_bus(tmp_path, arm6_program, capsys):
    r = arm6_program.axes[2].records.copy()
    r[:, :2] *= 3
    bad = replace_axis(arm6_program, 2, records=r)
    log = tmp_path / "none.log"
    assert main(["execute", str(write(tmp_path, bad)), "--can-log", str(log)]) == 1
    err = capsys.readouterr().err
    assert "INVALID" in err and "nothing was sent" in err
    assert not log.exists()


def test_program_for_another_cell_is_refused(tmp_path, arm6_program, capsys):
    other = replace_axis(arm6_program, 0, node_id=9)
    assert main(["execute", str(write(tmp_path, other))]) == 1
    err = capsys.readouterr().err
    assert "node 9 is not in cell arm6" in err and "no axis for node 1" in err


def test_program_not_starting_where_the_axes_are_is_rejected(tmp_path, arm6_program, capsys):
    r = arm6_program.axes[0].records.copy()
    r[:, 0] += 5000
    shifted = replace_axis(arm6_program, 0, records=r)
    assert np.all(r[:, 0] < arm6_program.axes[0].limits.max_position_qc)
    assert main(["execute", str(write(tmp_path, shifted))]) == 1
    err = capsys.readouterr().err
    assert "start_mismatch: axis joint_1 is at 0 qc, the program starts at 5000 qc" in err


def test_record_out_of_range_is_a_violation(tmp_path, arm6_program, capsys):
    data = json.loads(arm6_program.dumps())
    data["axes"][1]["records"][3][1] = 2**23  # velocity beyond int24
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    assert main(["execute", str(path)]) == 1
    err = capsys.readouterr().err
    assert "record-range" in err and "nothing was sent" in err
