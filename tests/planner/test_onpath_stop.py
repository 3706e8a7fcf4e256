"""The on-path stop (issue 37, planner side): rest on the planned path within the joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.onpath_stop import brake_on_path, override, quick_stop_time
from pvtflow.planner.path import JointPath, PlanError
from pvtflow.planner.timing import parameterize, timing_constraints
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS: JointLimits = ARM.joint_limits()
WAYPOINTS = np.array(
    [[0.0, -1.0, 1.2, 0.3, -0.2, 0.0], [1.1, 0.2, -0.4, -0.6, 0.5, 1.0], [-0.5, 0.6, 0.3, 0.8, -0.7, -1.2]]
)
MOTION = parameterize(JointPath(WAYPOINTS, LIMITS), LIMITS, timing_constraints(LIMITS))


@pytest.mark.parametrize("fraction", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_brake_on_path_rests_on_the_path_within_the_limits(fraction: float) -> None:
    t0 = fraction * MOTION.duration
    stop = brake_on_path(MOTION, t0, LIMITS)
    braking = stop.trajectory
    # continuous in velocity where it begins, every axis at rest at the same instant
    np.testing.assert_allclose(braking.velocity(0.0), MOTION.velocity(t0), atol=1e-9)
    assert np.max(np.abs(braking.velocity(braking.duration))) < 1e-9
    rv, ra = braking.limit_ratios(LIMITS)
    assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9
    # on the planned path: every braking position is the path's at a path position between start and end
    s = np.linspace(stop.s_start, stop.s_end, 50)
    t = braking.time_at(s)
    np.testing.assert_allclose(braking.position(t), MOTION.path(s), atol=1e-9)
    np.testing.assert_allclose(braking.position(0.0), MOTION.position(t0), atol=1e-9)
    # not much longer than the off-path quick stop (which leaves the path)
    assert stop.duration <= 1.6 * quick_stop_time(MOTION, t0, LIMITS) + 0.01


@pytest.mark.parametrize(("fraction", "scale"), [(0.2, 0.3), (0.5, 0.05), (0.4, 0.7), (0.6, 1.0)])
def test_override_retimes_the_rest_within_the_limits(fraction: float, scale: float) -> None:
    t0 = fraction * MOTION.duration
    slower = override(MOTION, MOTION, t0, scale, LIMITS)
    np.testing.assert_allclose(slower.velocity(0.0), MOTION.velocity(t0), atol=1e-9)
    assert np.max(np.abs(slower.velocity(slower.duration))) < 1e-9
    rv, ra = slower.limit_ratios(LIMITS)
    assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9
    np.testing.assert_allclose(slower.position(slower.duration), WAYPOINTS[-1], atol=1e-9)
    assert slower.duration >= (MOTION.duration - t0) - 1e-9
    # and back to the planned speed from the slowed motion
    back = override(MOTION, slower, 0.3 * slower.duration, 1.0, LIMITS)
    rv, ra = back.limit_ratios(LIMITS)
    assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9


def test_override_refuses_a_scale_out_of_range() -> None:
    with pytest.raises(PlanError):
        override(MOTION, MOTION, 0.1, 1.5, LIMITS)
