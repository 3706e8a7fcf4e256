"""The S-curve floor of the jerk-limited timing (planner/scurve.py): a speed per waypoint segment."""

from __future__ import annotations

import itertools

import numpy as np

from pvtflow.planner import scurve
from pvtflow.planner.jerk.warm import rests_of
from pvtflow.planner.path import JointPath
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
GANTRY = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")


def paths(cell, count: int, seed: int) -> list[JointPath]:
    lim = cell.joint_limits()
    rng = np.random.default_rng(seed)
    return [
        JointPath(lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof))), lim)
        for _ in range(count)
    ]


def one_speed_per_section(path: JointPath, rests, limits, jmax) -> float:
    """The duration with one speed for each section between rests (the floor before the segments' own)."""
    return sum(
        t
        for lo, hi in itertools.pairwise(rests)
        for t, _ in scurve._phases(hi - lo, *scurve._bounds(path, lo, hi, limits, jmax))
    )


def test_a_speed_per_segment_is_never_longer_and_much_shorter_on_most_paths() -> None:
    """On random 8-waypoint arm6 paths (jerk 10 x amax per second) the floor is never longer than with
    one speed per section, and a quarter shorter at the median (bench/RESULTS.md: 2.44x -> 1.61x of
    copp-py's TOPP3 at 1000 stations)."""
    limits = ARM.joint_limits()
    jmax = 10.0 * limits.acceleration
    ratios = []
    for path in paths(ARM, 10, seed=21):
        rests = rests_of(path)
        duration = scurve.rest_to_rest(path, rests, limits, jmax)[4][-1]
        ratios.append(duration / one_speed_per_section(path, rests, limits, jmax))
    assert max(ratios) <= 1.0 + 1e-9
    assert np.median(ratios) <= 0.75


def test_the_profile_is_one_motion_through_every_waypoint_at_rest_at_the_rests() -> None:
    """Each interval's constant jerk, from its start's s, s', s'', ends at the next gridpoint's (the
    phases of all the segments joined without a jump), every waypoint is a gridpoint, and the motion
    is at rest with s'' = 0 at every rest."""
    for cell in (ARM, GANTRY):
        limits = cell.joint_limits()
        jmax = 4.0 * limits.acceleration
        for path in paths(cell, 4, seed=22):
            rests = rests_of(path)
            g, sd, sdd, j, t = scurve.rest_to_rest(path, rests, limits, jmax)
            h = np.diff(t)
            assert np.all(h >= 0.0) and np.all(sd >= 0.0)
            sigma = h * (sd[:-1] + h * (0.5 * sdd[:-1] + h * j / 6.0))
            np.testing.assert_allclose(g[:-1] + sigma, g[1:], rtol=0.0, atol=1e-8 * path.length)
            np.testing.assert_allclose(sd[:-1] + h * (sdd[:-1] + 0.5 * j * h), sd[1:], rtol=0.0, atol=1e-8 * np.max(sd))
            np.testing.assert_allclose(sdd[:-1] + j * h, sdd[1:], rtol=0.0, atol=1e-8 * np.max(np.abs(sdd)))
            assert np.all(np.min(np.abs(g[:, None] - path.waypoint_s[None, :]), axis=0) <= 1e-12 * path.length)
            at_rest = np.isin(g, rests)
            assert np.all(sd[at_rest] == 0.0) and np.all(np.abs(sdd[at_rest]) <= 1e-9 * np.max(np.abs(sdd)))
