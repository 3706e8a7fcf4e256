"""The service: cell files, the command line and the zenoh motion service over the planner and the axes."""

from __future__ import annotations

import importlib
from typing import Any

# public name -> the module that defines it (loaded on first use: a command loads only what it runs on)
_HOMES: dict[str, str] = {
    "CellConfig": "service.config",
    "ConfigError": "service.config",
    "load_cell_config": "service.config",
    "MotionService": "service.motion",
    "main": "service.cli",
}
__all__ = ["CellConfig", "ConfigError", "MotionService", "load_cell_config", "main"]


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
