"""Cell configuration: the robot, its CAN bus and its axes, read from YAML and checked field by field.

Every problem is reported as ``FILE: FIELD: PROBLEM`` (a :class:`ConfigError`), never as a
traceback, so that a commissioning engineer can fix the file without reading code. The cell is
cell.py, the reading reader.py (one module per section of the file: robot and planning, bus, axis,
homing), the field reader and the error fields.py.
"""

from pvtflow.configs import CONFIG_DIR
from pvtflow.service.config.bus_section import PYTHON_CAN_INTERFACES
from pvtflow.service.config.cell import CellConfig, PlanningConfig
from pvtflow.service.config.fields import ConfigError
from pvtflow.service.config.reader import load_cell_config, parse_cell_config
from pvtflow.service.config.robot_section import shipped_robots

__all__ = [
    "CONFIG_DIR",
    "PYTHON_CAN_INTERFACES",
    "CellConfig",
    "ConfigError",
    "PlanningConfig",
    "load_cell_config",
    "parse_cell_config",
    "shipped_robots",
]
