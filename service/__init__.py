"""The service: cell files, the command line and the zenoh motion service over the planner and the axes."""

from __future__ import annotations

from axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: a command loads only what it runs on)
_HOMES: dict[str, str] = {
    "CellConfig": "service.config",
    "ConfigError": "service.config",
    "load_cell_config": "service.config",
    "MotionService": "service.motion",
    "main": "service.cli",
}
__all__ = ["CellConfig", "ConfigError", "MotionService", "load_cell_config", "main"]

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
