"""The cell file's ``robot`` section (a shipped robot by name, or a URDF file) and its ``planning`` section.

A cell file that names its robot keeps working wherever it is copied; the planning settings that limit
the tool need the robot's ``tcp_frame``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pvtflow.configs import ROBOTS_DIR
from pvtflow.planner.model import RobotModel
from pvtflow.service.config.cell import PlanningConfig
from pvtflow.service.config.fields import Fields

# planning.speed_band: a motion up to twice as long is the most a cell should trade for fewer records
MAX_SPEED_BAND = 0.5


def shipped_robots() -> list[str]:
    """The robots pvtflow ships (configs/robots/NAME.urdf), by name."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.urdf"))


def robot_urdf(robot: Fields, file: Path) -> Path:
    """The cell's URDF: ``robot.name`` names a shipped robot (so a copied cell file keeps working
    wherever it goes); ``robot.urdf`` is a file, relative to the cell file. A URDF not found that
    has a shipped robot's name says which file to copy along, or the ``name`` to give instead."""
    if ("name" in robot.data) == ("urdf" in robot.data):
        raise robot.error("name", "give the robot's name (a shipped robot) or its urdf (a file), one of them")
    if "name" in robot.data:
        name = robot.get("name", robot.string)
        urdf = ROBOTS_DIR / f"{name}.urdf"
        if not urdf.is_file():
            raise robot.error("name", f"no shipped robot {name!r} (shipped: {', '.join(shipped_robots())})")
        return urdf.resolve()
    urdf = (file.parent / robot.get("urdf", robot.string)).resolve()
    if urdf.is_file():
        return urdf
    hint = ""
    if urdf.stem in shipped_robots():
        hint = (
            f"; it is a shipped robot: write `robot: {{name: {urdf.stem}}}` instead, or copy "
            f"{ROBOTS_DIR / urdf.name} along (the path is relative to the cell file)"
        )
    raise robot.error("urdf", f"URDF file not found: {urdf}{hint}")


def parse_planning(file: Path, data: Any, tcp_frame: str | None, model: RobotModel) -> PlanningConfig:
    f = Fields(
        file,
        "planning",
        data,
        ("max_tcp_speed", "max_tcp_angular_speed", "torque_limits", "position_tolerance_qc", "budget_ms", "speed_band"),
    )
    max_tcp = f.get("max_tcp_speed", f.number(positive=True), None)
    if max_tcp is not None and tcp_frame is None:
        raise f.error("max_tcp_speed", "needs robot.tcp_frame to know which frame to limit")
    max_turn = f.get("max_tcp_angular_speed", f.number(positive=True), None)
    if max_turn is not None and tcp_frame is None:
        raise f.error("max_tcp_angular_speed", "needs robot.tcp_frame to know which frame to limit")
    torque = f.get("torque_limits", f.boolean, True)
    band = f.get("speed_band", f.number(), PlanningConfig.speed_band)
    if not 0.0 <= band <= MAX_SPEED_BAND:
        raise f.error("speed_band", f"must be in [0, {MAX_SPEED_BAND}] (a fraction of the path speed), got {band!r}")
    return PlanningConfig(
        tcp_frame=tcp_frame,
        max_tcp_speed=max_tcp,
        max_tcp_angular_speed=max_turn,
        torque_limits=torque and model.has_dynamics,
        position_tolerance_qc=f.get("position_tolerance_qc", f.number(positive=True), 1.0),
        budget_ms=f.get("budget_ms", f.number(positive=True), PlanningConfig.budget_ms),
        speed_band=band,
    )
