"""The planner's compiled kernels are never loaded stale from numba's cache."""

from __future__ import annotations

import os
from pathlib import Path

from pvtflow.planner.kernel_cache import HERE, INTERPOLATION, KERNEL_SOURCES, PlannerCacheLocator, sources_stamp
from pvtflow.planner.knots import check_kernels, quantize_kernels
from pvtflow.planner.validate import screen


def test_every_module_with_kernels_is_in_the_stamp() -> None:
    """A kernel inlines functions of other modules (the drive's cubic among them): all in the stamp."""
    with_kernels = {p for p in HERE.rglob("*.py") if "@njit" in p.read_text() or "njit(" in p.read_text()}
    with_kernels.discard(HERE / "kernel_cache.py")
    assert with_kernels | {INTERPOLATION} == set(KERNEL_SOURCES)


def test_the_stamp_changes_with_any_source(tmp_path: Path) -> None:
    files = tuple(tmp_path / f"m{i}.py" for i in range(3))
    for f in files:
        f.write_text("x = 1\n")
    before = sources_stamp(files)
    os.utime(files[2], ns=(1, 1))  # only the third changes
    assert sources_stamp(files) != before
    files[0].write_text("x = 22\n")
    assert sources_stamp(files)[0] != before[0]


def test_planner_kernels_use_the_planner_locator() -> None:
    for kernel in (check_kernels.check_segments, quantize_kernels.repair_chains, screen._epos2_worst):
        locator = kernel._cache._impl._locator
        assert isinstance(locator, PlannerCacheLocator)
        stamp = locator.get_source_stamp()
        assert stamp[1] == sources_stamp(KERNEL_SOURCES)  # the cubic's file is in every kernel's stamp
