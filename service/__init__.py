"""The service: cell files, the command line and the zenoh motion service over the planner and the axes."""

from __future__ import annotations

from pvtflow.axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: a command loads only what it runs on)
_HOMES: dict[str, str] = {
    "CellConfig": "pvtflow.service.config",
    "ConfigError": "pvtflow.service.config",
    "load_cell_config": "pvtflow.service.config",
    "MotionService": "pvtflow.service.motion",
    "main": "pvtflow.service.cli",
}
__all__ = ["CellConfig", "ConfigError", "MotionService", "load_cell_config", "main"]

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
