"""The drive's executed jerk (planner/knots/window_jerk.py): the 10-ms-window jerk of each axis's
reconstruction, from the records as the drive interpolates them, within 1.2 x the plan's jerk limit."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.interpolation import epos2_pvt
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def test_window_jerk_is_the_peak_of_the_acceleration_change_over_10_ms() -> None:
    """Against the definition, sampled every 0.01 ms (the acceleration is linear between records, so
    the peak is at a record or 10 ms before one, where the sampling lands exactly)."""
    rng = np.random.default_rng(3)
    times = rng.integers(3, 40, 12)
    positions = np.cumsum(rng.integers(-300, 300, 12))
    velocities = rng.integers(-400, 400, 12)
    records = np.column_stack((positions, velocities, times)).astype(np.int64)
    records[0, 1] = records[-1, 1] = 0
    records = np.vstack((records, [records[-1, 0], 0, 0]))
    recon = epos2_pvt(records, 0.0333)
    t = np.arange(-WINDOW_MS - 1.0, recon.end_time + 1.0, 0.01)
    # each sample's acceleration from both sides of it (a step at a record counts either way)
    left, right = recon.acceleration(t - 1e-9), recon.acceleration(t + 1e-9)
    left_w, right_w = recon.acceleration(t + WINDOW_MS - 1e-9), recon.acceleration(t + WINDOW_MS + 1e-9)
    dense = max(np.abs(left_w - left).max(), np.abs(right_w - right).max()) / WINDOW_MS
    assert window_jerk(recon) == pytest.approx(dense, rel=1e-6)


def _random_paths(cell_name: str, count: int, seed: int) -> tuple[CellPlanner, list[np.ndarray]]:
    cell = load_cell_config(CONFIG_DIR / "cells" / f"{cell_name}.yaml")
    lim = cell.joint_limits()
    rng = np.random.default_rng(seed)
    return CellPlanner(cell), [
        lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof))) for _ in range(count)
    ]


@pytest.mark.parametrize(("cell_name", "factor"), [("arm6", 10.0), ("arm6", 4.0), ("gantry3", 4.0)])
def test_the_drives_window_jerk_stays_within_1_2_x_the_jerk_limit(cell_name: str, factor: float) -> None:
    """Random 8-waypoint paths, max_jerk = factor x amax per second: on every axis the drive's own
    reconstruction of the records changes its acceleration over any 10 ms by at most 1.2 x the
    limit x 10 ms, the program validates, and the records still follow the plan within 1 count."""
    cp, paths = _random_paths(cell_name, 2, seed=int(factor) + len(cell_name))
    for wp in paths:
        res = cp.plan(PlanInput(wp, max_jerk=factor * cp.limits.acceleration))
        assert res.ok and res.program is not None and res.plan is not None and res.build is not None, res.message
        assert validate_program(res.program).ok
        assert res.build.knots.deviation_qc <= 1.0
        for cfg, ap, jmax in zip(cp.cell.ordered_axes(), res.program.axes, res.plan.details["max_jerk"], strict=True):
            limit_qc_ms3 = jmax * cfg.scaling.qc_per_joint_unit * 1e-9  # joint units/s^3 -> qc/ms^3
            assert window_jerk(ap.reconstruction()) <= 1.2 * limit_qc_ms3 * (1.0 + 1e-9), ap.name
