"""Where numba keeps the planner's compiled loops, and when it must compile them again.

numba caches a compiled function next to its source and recompiles it when *that* file changes,
not when a function it calls from another file does. The planner's kernels inline the drive's
cubic (``axes.drive.interpolation``) into the knot placement's (``planner/knots/*_kernels.py``) and the
validator's: after an edit of ``hermite`` alone they would keep running the old formula from the
cache. So every planner kernel is stamped with all the kernel sources (``KERNEL_SOURCES``): a
change to any of them recompiles them all (about 15 s, once), and a stale kernel is never loaded.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from numba.core import config
from numba.core.caching import InTreeCacheLocator

HERE = Path(__file__).resolve().parent
INTERPOLATION = HERE.parent / "axes" / "drive" / "interpolation.py"  # the drive's cubic, inlined by the kernels
KERNEL_SOURCES = (
    INTERPOLATION,
    *(
        HERE / n
        for n in (
            "cartesian.py",
            "constraints.py",
            "ik.py",
            "knots/check_kernels.py",
            "knots/fixed_period_kernels.py",
            "knots/quantize_kernels.py",
            "knots/records_kernels.py",
            "knots/refine_kernels.py",
            "knots/round_kernels.py",
            "knots/samples_kernels.py",
            "path.py",
            "slowdown.py",
            "smooth_kernels.py",
            "topp/passes.py",
            "topp/rows.py",
            "topp/seidel.py",
            "speed_band.py",
            "timing.py",
            "trajectory.py",
            "validate/screen.py",
        )
    ),
)


def sources_stamp(paths: tuple[Path, ...]) -> tuple[tuple[int, int], ...]:
    """(mtime in ns, size) of every file: what a change to any of them changes."""
    return tuple((st.st_mtime_ns, st.st_size) for st in (os.stat(p) for p in paths))


class PlannerCacheLocator(InTreeCacheLocator):
    """numba's in-tree cache (``__pycache__`` next to the source), for the planner's modules only (its
    subpackages' too), with every kernel source in the stamp that decides whether a cached kernel is
    still valid."""

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> PlannerCacheLocator | None:
        if HERE not in Path(py_file).resolve().parents:
            return None  # not the planner's: numba's own locators decide
        return super().from_function(py_func, py_file)

    def get_source_stamp(self) -> Any:
        return (super().get_source_stamp(), sources_stamp(KERNEL_SOURCES))


def install() -> None:
    """Put PlannerCacheLocator before numba's own locators (unless the user chose locators), for
    every kernel decorated from now on."""
    if not config.CACHE_LOCATOR_CLASSES:
        config.CACHE_LOCATOR_CLASSES = ",".join(
            (
                f"{__name__}.PlannerCacheLocator",
                "UserProvidedCacheLocator",
                "InTreeCacheLocator",
                "UserWideCacheLocator",
                "IPythonCacheLocator",
                "ZipCacheLocator",
            )
        )
