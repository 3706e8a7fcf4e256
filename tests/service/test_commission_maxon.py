"""A cell whose simulated EPOS2s are maxon's own EDS (``simulation: {eds: vendor/maxon-epos2-70-10.eds}``)
and that requires what maxon's objects give (``commission_requires``): ``pvtflow commission`` shows
what it could not check (never as ok, in text and JSON), exits 1 when a required check cannot be made,
and a drive set up wrong in its ``simulation:`` section is caught by ``commission`` and refused by
``home`` and ``execute`` before anything moves, with a clear error and no traceback."""

from __future__ import annotations

import dataclasses
import json
import uuid
from pathlib import Path

import pytest

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config
from pvtflow.service.motion import MotionService

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"
MAXON = "eds: vendor/maxon-epos2-70-10.eds"
REQUIRES = '    commission_requires: ["0x2210:01", "0x2210:02", "0x2210:04", "0x608B", "0x608C", "0x6410:04"]\n'


def maxon_gantry(tmp_path: Path, y_drive: str = "", requires: str = REQUIRES) -> Path:
    """gantry3 with maxon-EDS EPOS2s requiring maxon's objects, its y drive as ``y_drive`` says."""
    text = GANTRY.read_text().replace("urdf: ../robots/gantry3.urdf", "name: gantry3")
    lines = []
    for line in text.splitlines(keepends=True):
        if line.startswith("    simulation: {"):
            extra = f", {y_drive}" if y_drive and "index_offset_qc: 900" in line else ""
            line = line.replace("    simulation: {", "    simulation: {" + MAXON + extra + ", ")
            line = requires + line
        lines.append(line)
    path = tmp_path / "gantry3.yaml"
    path.write_text("".join(lines))
    return path


def test_a_maxon_cell_that_agrees_exits_0_and_shows_what_it_did_not_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = maxon_gantry(tmp_path)
    assert main(["commission", "--config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "every one as the cell expects" in out
    assert "y (node 12, epos2_pvt): ok: 1 not checked" in out
    assert "not checked 0x607E polarity: expected 0x00 (not inverted); found absent" in out
    assert "ok          0x2210:04 position sensor polarity" in out
    assert "ok          0x608B velocity notation index" in out
    assert "ok          0x6085:00 quick stop deceleration" in out
    assert main(["commission", "--config", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    for axis in report["axes"]:
        assert axis["not_checked"] == 1
        by_object = {c["object"]: c for c in axis["checks"]}
        assert by_object["0x607E"]["status"] == "not_checked" and by_object["0x607E"]["required"] is False
        assert by_object["0x2210:02"]["status"] == "ok" and by_object["0x2210:02"]["required"] is True


def test_a_required_check_that_cannot_be_made_exits_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = maxon_gantry(tmp_path, requires='    commission_requires: ["0x607E"]\n')
    assert main(["commission", "--config", str(path)]) == 1
    captured = capsys.readouterr()
    assert "NOT CHECKED 0x607E polarity" in captured.out
    assert "x (node 11): 0x607E polarity: not checked, the drive has no 0x607E (required by the cell)" in captured.err


@pytest.mark.parametrize(
    ("drive", "named"),
    [
        ("sensor_polarity: 1", "0x2210:04 position sensor polarity: expected 0x0000 (not inverted), found 0x0001"),
        ("sensor_type: 4", "0x2210:02 position sensor type: expected 1 or 2 (incremental encoder), found 4"),
        ("velocity_notation_index: -1", "0x608B velocity notation index: expected 0 (10^index rpm"),
    ],
)
def test_a_maxon_epos2_set_up_wrong_is_caught_and_refused_before_anything_moves(
    drive: str, named: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = maxon_gantry(tmp_path, drive)
    assert main(["commission", "--config", str(path)]) == 1
    assert f"y (node 12): {named}" in capsys.readouterr().err
    assert main(["home", "--config", str(path), "--quiet"]) == 1
    out = capsys.readouterr().out
    assert "configuration_error: node 12: axis y is not the drive the cell expects: " + named in out
    assert "not homed" in out and "Traceback" not in out
    program = tmp_path / "p.json"
    waypoints = tmp_path / "w.json"
    waypoints.write_text(json.dumps({"waypoints": [[0.05, 0.05, -0.05], [0.06, 0.045, -0.05]]}))
    assert main(["plan", "--config", str(path), "--waypoints", str(waypoints), "-o", str(program)]) == 0
    capsys.readouterr()
    assert main(["execute", str(program), "--config", str(path), "--home", "--quiet"]) == 1
    captured = capsys.readouterr()
    assert named in captured.out + captured.err and "Traceback" not in captured.out + captured.err


def test_the_cell_file_fields_are_checked(tmp_path: Path) -> None:
    path = maxon_gantry(tmp_path, requires='    commission_requires: ["0x9999"]\n')
    with pytest.raises(ConfigError, match=r"axes\[0\].commission_requires: 0x9999: not a commissioning check"):
        load_cell_config(path)
    path.write_text(path.read_text().replace('["0x9999"]', '["0x2210:02"]').replace("maxon-epos2-70-10", "nope"))
    with pytest.raises(ConfigError, match=r"axes\[0\].simulation.eds: no EDS 'vendor/nope.eds'"):
        load_cell_config(path)


def test_serve_refuses_a_maxon_epos2_set_up_wrong_with_nothing_left_running(tmp_path: Path) -> None:
    """``pvtflow serve`` opens its cell with ``MotionService.open`` (service/serve_cmd.py): a drive
    that is not what the cell says is one BusError naming it, and the bus and drives are closed."""
    cell = load_cell_config(maxon_gantry(tmp_path, "velocity_notation_index: -1"))
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=f"maxon-{uuid.uuid4().hex[:8]}"))
    service = MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP)
    with pytest.raises(BusError) as refused:
        service.open()
    message = str(refused.value)
    assert message.startswith("cell gantry3: node 12: axis y is not the drive the cell expects: ")
    assert "0x608B velocity notation index: expected 0 (10^index rpm = the cell's 1 rpm), found -1" in message
    assert service.bus is None and service.sim is None
