"""A cell file names its robot by a shipped name (``robot: {name: gantry3}``), so a copy of it keeps
working wherever it goes; a copied file whose relative URDF path breaks says which file to copy along."""

from __future__ import annotations

from pathlib import Path

import pytest

from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config

SHIPPED = (CONFIG_DIR / "cells" / "gantry3.yaml").read_text()


def copied(tmp_path: Path, text: str = SHIPPED) -> Path:
    path = tmp_path / "mycell.yaml"
    path.write_text(text)
    return path


def test_a_copy_that_names_the_shipped_robot_loads(tmp_path: Path) -> None:
    cell = load_cell_config(copied(tmp_path, SHIPPED.replace("urdf: ../robots/gantry3.urdf", "name: gantry3")))
    assert cell.urdf == (CONFIG_DIR / "robots" / "gantry3.urdf").resolve()
    assert cell.joint_names == load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml").joint_names


def test_a_plain_copy_says_which_file_to_copy_along(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = copied(tmp_path)
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    message = str(err.value)
    assert "robot.urdf: URDF file not found" in message
    assert "write `robot: {name: gantry3}` instead" in message
    assert f"copy {CONFIG_DIR / 'robots' / 'gantry3.urdf'} along" in message
    wp = tmp_path / "wp.json"
    wp.write_text('{"waypoints": [[0.05, 0.05, -0.05], [0.06, 0.045, -0.05]]}')
    assert main(["plan", "--config", str(path), "--waypoints", str(wp), "-o", str(tmp_path / "p.json")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "robot: {name: gantry3}" in lines[0], lines


@pytest.mark.parametrize(
    ("robot", "words"),
    [
        ("robot: {name: scara, tcp_frame: tool0}", "robot.name: no shipped robot 'scara' (shipped: arm6, gantry3)"),
        ("robot: {name: gantry3, urdf: x.urdf}", "robot.name: give the robot's name (a shipped robot) or its urdf"),
        ("robot: {tcp_frame: tool0}", "robot.name: give the robot's name"),
    ],
)
def test_a_robot_named_wrongly_is_one_clear_error(tmp_path: Path, robot: str, words: str) -> None:
    text = SHIPPED.replace("robot:\n  urdf: ../robots/gantry3.urdf\n  tcp_frame: tool0", robot)
    assert text != SHIPPED
    with pytest.raises(ConfigError) as err:
        load_cell_config(copied(tmp_path, text))
    assert words in str(err.value), str(err.value)
