"""The data pvtflow ships, and the one place that knows where it lives: cells, robots, EDS files, zenoh configs.

Installed it is package data of ``pvtflow.configs``; in a source tree it is the repository's configs/ folder. Found
with importlib.resources, and used as files on disk: canopen, Pinocchio and zenoh open them by path, and a cell
file names its URDF relative to itself (``../robots/arm6.urdf``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def _on_disk() -> Path:
    root = resources.files(__name__)
    if not isinstance(root, Path):  # e.g. imported from a zip: pip always installs pvtflow as files
        raise ImportError(f"pvtflow's data must be installed as files on disk, not in {root}")
    return root


CONFIG_DIR = _on_disk()
CELLS_DIR = CONFIG_DIR / "cells"  # NAME.yaml: the shipped cells, by name
ROBOTS_DIR = CONFIG_DIR / "robots"  # NAME.urdf: the shipped robots a cell file may name (robot.name)
EDS_DIR = CONFIG_DIR / "eds"  # the simulated drives' dictionaries; vendor/: drive makers' own files, unchanged
ZENOH_DIR = CONFIG_DIR / "zenoh"  # the service's and the clients' zenoh configs, the example credentials
DEFAULT_CELL = CELLS_DIR / "arm6.yaml"  # the demo arm: every command's cell when none is given


def shipped_cells() -> list[str]:
    """The cells pvtflow ships, by name (``--config NAME``)."""
    return sorted(p.stem for p in CELLS_DIR.glob("*.yaml"))


def shipped_cell(name: str) -> Path | None:
    """The file of the shipped cell ``name`` (``arm6``: cells/arm6.yaml), None when pvtflow ships none of that name."""
    return CELLS_DIR / f"{name}.yaml" if name in shipped_cells() else None


__all__ = [
    "CELLS_DIR",
    "CONFIG_DIR",
    "DEFAULT_CELL",
    "EDS_DIR",
    "ROBOTS_DIR",
    "ZENOH_DIR",
    "shipped_cell",
    "shipped_cells",
]
