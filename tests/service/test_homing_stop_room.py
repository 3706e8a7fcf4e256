"""A cell whose axis cannot stop between the limit switch its homing seeks and the end of travel is
refused when it loads (the room: ``homing.overtravel_qc``, or the simulated hard stop beyond the switch)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pvtflow.axes.drive.config import homing_stop_room
from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"
X_HOMING = "acceleration_rpm_s: 20000, offset_qc: 1500, timeout_s: 10"
X_SIMULATION = "negative_limit_switch_qc: -2000,"
SHIPPED_OVERTRAVEL = " overtravel_qc: 12000,"


def gantry(tmp_path: Path, homing: str = "", simulation: str = "") -> Path:
    text = GANTRY.read_text().replace("urdf: ../robots/gantry3.urdf", "name: gantry3")
    if homing or simulation:  # the shipped overtravel makes way for the room under test
        text = text.replace(SHIPPED_OVERTRAVEL, "")
    assert X_HOMING in text and X_SIMULATION in text
    text = text.replace(X_HOMING, X_HOMING + homing, 1).replace(X_SIMULATION, X_SIMULATION + simulation, 1)
    path = tmp_path / "gantry3.yaml"
    path.write_text(text)
    return path


def test_a_hard_stop_too_close_behind_the_switch_is_refused(tmp_path: Path) -> None:
    # 2400 rpm braked at 20000 rpm/s: 2.4 motor turns of 4096 qc, 9830 qc past the switch
    with pytest.raises(ConfigError) as refused:
        load_cell_config(gantry(tmp_path, simulation=" negative_hard_stop_qc: -8000,"))
    message = str(refused.value)
    assert "axes[0].homing" in message and "needs 9830 qc to stop past the negative limit switch" in message
    assert "the simulated hard stop beyond the switch leaves 6000 qc" in message
    load_cell_config(gantry(tmp_path, simulation=" negative_hard_stop_qc: -12000,"))


def test_a_real_machines_overtravel_is_the_cells_setting(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as refused:
        load_cell_config(gantry(tmp_path, homing=", overtravel_qc: 5000"))
    assert "homing.overtravel_qc leaves 5000 qc" in str(refused.value)
    cell = load_cell_config(gantry(tmp_path, homing=", overtravel_qc: 10000"))
    assert cell.axis_for_joint("x").homing.overtravel_qc == 10000


def test_the_shipped_gantry_is_checked_and_stops_within_its_overtravel(tmp_path: Path) -> None:
    """gantry3.yaml names its machine's overtravel on every homing axis, so the check runs on the
    shipped cell (and passes); the same cell with a switch speed it cannot stop from is refused."""
    cell = load_cell_config(GANTRY)
    for axis in cell.axes:
        assert axis.homing is not None and axis.homing.overtravel_qc == 12000
        assert homing_stop_room(axis.homing, axis.scaling, axis.simulation) is None
    fast = tmp_path / "gantry3.yaml"
    text = GANTRY.read_text().replace("urdf: ../robots/gantry3.urdf", "name: gantry3")
    fast.write_text(text.replace("switch_speed_rpm: 2400", "switch_speed_rpm: 2700", 1))
    with pytest.raises(ConfigError) as refused:  # 2700 rpm: 12442 qc to stop
        load_cell_config(fast)
    assert "axes[0].homing" in str(refused.value) and "homing.overtravel_qc leaves 12000 qc" in str(refused.value)
