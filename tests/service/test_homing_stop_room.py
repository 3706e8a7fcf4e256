"""A cell whose axis cannot stop between the limit switch its homing seeks and the end of travel is
refused when it loads (the room: ``homing.overtravel_qc``, or the simulated hard stop beyond the switch)."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.config import CONFIG_DIR, ConfigError, load_cell_config

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"
X_HOMING = "acceleration_rpm_s: 20000, offset_qc: 1500, timeout_s: 10"
X_SIMULATION = "negative_limit_switch_qc: -2000,"


def gantry(tmp_path: Path, homing: str = "", simulation: str = "") -> Path:
    text = GANTRY.read_text().replace("urdf: ../robots/gantry3.urdf", "name: gantry3")
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
