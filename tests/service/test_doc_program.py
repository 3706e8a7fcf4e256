"""The program printed in docs/pvt-program.md is a real one: valid, made for the cell it names, from the
waypoints its text gives, and as long as its metadata says (a reader copies it as the model of the format)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.planner.validate import validate_program
from pvtflow.service.config import CONFIG_DIR, load_cell_config

DOC = Path(__file__).resolve().parents[2] / "docs" / "pvt-program.md"


def documented() -> tuple[str, PvtProgram]:
    """The text of the section "File" up to its example, and the example (the first JSON block there)."""
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("## File") :]
    match = re.search(r"```json\n(.*?)```", section, re.S)
    assert match, "docs/pvt-program.md: no JSON example under ## File"
    return section[: match.start()], PvtProgram.loads(match.group(1))  # ranges checked too


def test_the_documented_program_is_valid_and_lasts_what_its_metadata_says() -> None:
    _, program = documented()
    report = validate_program(program, source="docs/pvt-program.md")
    assert report.ok and not report.errors and not report.warnings, report.format_text()
    for axis in program.axes:
        assert int(axis.records[:, 2].sum()) == program.metadata["duration_ms"], axis.joint
    assert program.metadata["time_scale"] >= 1.0
    assert max(program.metadata["deviation_qc"].values()) <= program.metadata["tolerance_qc"]


def test_the_documented_program_fits_its_cell_and_goes_where_the_text_says() -> None:
    prose, program = documented()
    cell = load_cell_config(CONFIG_DIR / "cells" / f"{program.cell}.yaml")
    assert program_mismatch(program, cell.ordered_axes(), cell.name) == []
    waypoints = json.loads(re.search(r'`(\{"waypoints": .*?\})`', prose).group(1))["waypoints"]
    for axis, start, end in zip(program.axes, *np.asarray(waypoints), strict=True):
        s = axis.scaling
        assert axis.records[0, 0] == round(start * s.motor_rev_per_joint_unit * s.qc_per_motor_rev), axis.joint
        assert axis.records[-1, 0] == round(end * s.motor_rev_per_joint_unit * s.qc_per_motor_rev), axis.joint
