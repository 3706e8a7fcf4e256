"""Speed and acceleration scaling per request (``velocity_scale``, ``acceleration_scale``).

The override scales the joint velocity and acceleration limits a motion is planned with, and the
limits its knots are placed against; the program keeps the drives' own 0x607F / 0x60C5. Anything
but a number in (0, 1] is refused with the field's name, and nothing is planned.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pvtflow.axes.drive.interpolation import exceeds
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
GANTRY = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
LIMITS = ARM.joint_limits()
WAYPOINTS = np.array([[0.0] * 6, [0.6, -0.4, 0.5, 0.3, -0.3, 0.8], [-0.3, 0.2, -0.2, -0.4, 0.2, -0.5]])


@pytest.mark.parametrize("field", ["velocity_scale", "acceleration_scale"])
@pytest.mark.parametrize("value", [0.0, -0.5, 1.0001, 2, math.nan, math.inf, "0.5", None, True])
def test_a_scale_outside_0_1_is_refused_naming_the_field(field: str, value: object) -> None:
    out = Planner(LIMITS).plan(PlanInput(WAYPOINTS, **{field: value}))  # type: ignore[arg-type]
    assert not out.ok and out.trajectory is None
    assert out.result.value == "invalid_input"
    assert out.message.startswith(f"{field} must be") and "(0, 1]" in out.message
    assert out.details == {"field": field}


def test_scale_1_is_the_unscaled_plan_and_a_smaller_one_is_slower_and_inside_the_scaled_limits() -> None:
    planner = Planner(LIMITS)
    full = planner.plan(PlanInput(WAYPOINTS)).trajectory
    assert full is not None
    assert (
        planner.plan(PlanInput(WAYPOINTS, velocity_scale=1.0, acceleration_scale=1.0)).trajectory.duration
        == full.duration
    )
    previous = full.duration
    for vs, acc in ((1.0, 0.5), (0.5, 1.0), (0.5, 0.5), (0.1, 0.25)):
        tr = planner.plan(PlanInput(WAYPOINTS, velocity_scale=vs, acceleration_scale=acc)).trajectory
        assert tr is not None
        t = np.concatenate((np.linspace(0.0, tr.duration, 4001), tr.check_times()))
        assert np.abs(tr.velocity(t)).max(axis=0).max() > 0
        assert np.all(np.abs(tr.velocity(t)) <= vs * LIMITS.velocity * (1 + 1e-5))
        assert np.all(np.abs(tr.acceleration(t)) <= acc * LIMITS.acceleration * (1 + 1e-5))
        rv, ra = tr.limit_ratios(LIMITS.scaled(vs, acc))
        assert max(rv, ra) > 0.99  # time-optimal under the scaled limits: one of them is reached
        assert tr.duration > full.duration
        if (vs, acc) == (0.5, 0.5):
            assert tr.duration > previous
        previous = tr.duration
    # a pure velocity scale on a motion that is velocity-bound everywhere would take 1/vs as long;
    # here it takes longer than the full plan and at most twice as long
    half = planner.plan(PlanInput(WAYPOINTS, velocity_scale=0.5, acceleration_scale=1.0)).trajectory
    assert full.duration < half.duration <= 2.0 * full.duration * (1 + 1e-6)


@pytest.mark.parametrize("cell", [ARM, GANTRY], ids=lambda c: c.name)
def test_a_half_speed_program_stays_under_half_the_drives_limits_and_records_the_scales(cell) -> None:
    """velocity_scale 0.5: the drives' reconstruction of every record (the validator's exact check)
    stays under half of 0x607F; the program still carries the drives' own limits."""
    lim = cell.joint_limits()
    rng = np.random.default_rng(5)
    planner = CellPlanner(cell)
    for _ in range(3):
        w = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((5, lim.dof)))
        res = planner.plan(PlanInput(w, velocity_scale=0.5, acceleration_scale=0.7))
        assert res.ok, res.message
        prog = res.program
        assert prog.metadata["velocity_scale"] == 0.5 and prog.metadata["acceleration_scale"] == 0.7
        for ax, cfg in zip(prog.axes, cell.ordered_axes(), strict=True):
            assert ax.limits == cfg.limits  # the drive's own objects, not the scaled ones
        report = validate_program(prog)
        assert report.ok
        # at most the scaled limit, with the round-off allowance both sides of the bus judge limits by
        assert not exceeds(max(a.velocity_ratio for a in report.axes), 0.5)
        assert not exceeds(max(a.acceleration_ratio for a in report.axes), 0.7)
    full = planner.plan(PlanInput(w))
    assert full.program.metadata["velocity_scale"] == 1.0
    assert full.program.duration_ms < res.program.duration_ms


def test_a_bad_scale_on_the_cell_plans_nothing() -> None:
    res = CellPlanner(ARM).plan(PlanInput(WAYPOINTS, velocity_scale=math.nan))
    assert not res.ok and res.program is None and res.code == "invalid_input"
    assert "velocity_scale" in res.message
