"""A package's front door that loads each public name's module on first use.

``pvtflow report`` should not import the recorder's writer, nor ``pvtflow validate`` the CAN stack:
a package lists where each of its public names lives, and the module is imported only when the
name is asked for (PEP 562). axes holds it because every layer may point down to axes.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(
    package: str, homes: Mapping[str, str], public: list[str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``, whose public name -> module is ``homes``."""

    def get(name: str) -> Any:
        if name in homes:
            return getattr(importlib.import_module(homes[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def names() -> list[str]:
        return sorted(set(public) | set(homes))

    return get, names
