"""Reading one YAML mapping of a cell file field by field, and the one error every mistake becomes.

Every problem is reported as ``FILE: FIELD: PROBLEM`` (a :class:`ConfigError`), never as a
traceback, so that a commissioning engineer can fix the file without reading code.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar


class ConfigError(ValueError):
    """A cell configuration problem: which file, which field, what is wrong."""

    def __init__(self, file: str | Path, where: str, problem: str) -> None:
        self.file = str(file)
        self.where = where
        self.problem = problem
        super().__init__(f"{self.file}: {where}: {problem}" if where else f"{self.file}: {problem}")


T = TypeVar("T")


class Fields:
    """Reads one YAML mapping, naming the file and the field in every error."""

    def __init__(self, file: Path, where: str, data: Any, allowed: tuple[str, ...]) -> None:
        self.file = file
        self.where = where
        if not isinstance(data, Mapping):
            raise ConfigError(file, where or "(top level)", f"must be a mapping, got {type(data).__name__}")
        self.data = data
        unknown = [k for k in data if k not in allowed]
        if unknown:
            raise ConfigError(file, self.path(str(unknown[0])), f"unknown field (allowed: {', '.join(allowed)})")

    def path(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def error(self, key: str, problem: str) -> ConfigError:
        return ConfigError(self.file, self.path(key), problem)

    def get(self, key: str, convert: Callable[[str, Any], T], default: Any = ...) -> T:
        if key not in self.data or self.data[key] is None:
            if default is ...:
                raise self.error(key, "missing")
            return default
        return convert(key, self.data[key])

    # converters -------------------------------------------------------------------------------
    def number(self, positive: bool = False) -> Callable[[str, Any], float]:
        def conv(key: str, v: Any) -> float:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise self.error(key, f"must be a finite number, got {v!r}")
            if positive and v <= 0:
                raise self.error(key, f"must be positive, got {v!r}")
            return float(v)

        return conv

    def integer(self, lo: int, hi: int) -> Callable[[str, Any], int]:
        def conv(key: str, v: Any) -> int:
            if isinstance(v, bool) or not isinstance(v, int):
                raise self.error(key, f"must be an integer, got {v!r}")
            if not lo <= v <= hi:
                raise self.error(key, f"{v} is outside [{lo}, {hi}]")
            return v

        return conv

    def string(self, key: str, v: Any) -> str:
        if not isinstance(v, str) or not v:
            raise self.error(key, f"must be a non-empty string, got {v!r}")
        return v

    def boolean(self, key: str, v: Any) -> bool:
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def boolean_or_auto(self, key: str, v: Any) -> bool | None:
        """true, false, or ``auto`` (None: the program decides, the field's comment says how)."""
        if v == "auto":
            return None
        if not isinstance(v, bool):
            raise self.error(key, f"must be true, false or auto, got {v!r}")
        return v
