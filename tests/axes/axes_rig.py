"""Helpers of the axes tests: unique virtual channels, cells with other profiles (imported by name:
this folder is not a package, so ``conftest`` itself is not imported by the tests)."""

from __future__ import annotations

import dataclasses
import uuid

from service.config import CellConfig


def unique_channel(prefix: str = "axes") -> str:
    return f"{prefix}-{uuid.uuid4().hex[:12]}"


def with_profiles(cell: CellConfig, profiles: dict[str, dict[str, object]], sync_period_ms: float) -> CellConfig:
    """The cell with some axes switched to another profile (and the SYNC period set)."""
    axes = []
    for a in cell.axes:
        change = profiles.get(a.joint)
        axes.append(dataclasses.replace(a, **change) if change else a)  # type: ignore[arg-type]
    bus = dataclasses.replace(cell.bus, sync_period_ms=sync_period_ms)
    return dataclasses.replace(cell, axes=tuple(axes), bus=bus)
