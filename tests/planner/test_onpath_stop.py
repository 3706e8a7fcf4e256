"""The on-path stop (issue 37, planner side): rest on the planned path within the joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.planner.build import build_program
from pvtflow.planner.knots import DriveAxis
from pvtflow.planner.limits import JointLimits, joint_limits_from_drives
from pvtflow.planner.onpath_program import resume_from_rest
from pvtflow.planner.onpath_rejoin import NoRejoinError, reference_of
from pvtflow.planner.onpath_stop import (
    brake_on_path,
    jerk_override,
    override,
    quick_stop_time,
    resume,
    stopped_motion,
)
from pvtflow.planner.path import JointPath, PlanError
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.timing import parameterize, timing_constraints
from pvtflow.planner.trajectory import Trajectory
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import planner_for_cell
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


def _mixed_axes() -> list[DriveAxis]:
    s = AxisScaling.prismatic(4096, 0.02)
    lim = DriveLimits(3000, 30000, 0, 245000)
    return [
        DriveAxis("x", 1, "cia402_ip_linear", s, lim, period_ms=2),
        DriveAxis("y", 2, "sync_setpoint", s, lim, period_ms=1),
        DriveAxis("z", 3, "parker_slvdn", s, lim, period_ms=4, interpolation_submode=-1),
        DriveAxis("w", 4, "parker_slvdn", s, lim, period_ms=4, interpolation_submode=-2),
        DriveAxis("v", 5, "epos2_pvt", s, lim),
    ]


@pytest.mark.parametrize("fraction", [0.3, 0.6])
def test_stopped_motion_validates_on_every_profile(fraction: float) -> None:
    cell = load_cell_config()
    arm_axes = list(cell.ordered_axes())
    mixed = _mixed_axes()
    mixed_limits = joint_limits_from_drives(
        [a.joint for a in mixed], [a.scaling for a in mixed], [a.limits for a in mixed]
    )
    mixed_wp = np.array([[0.01] * 5, [0.4, 0.3, 0.2, 0.25, 0.35], [0.1, 0.45, 0.05, 0.3, 0.2]])
    cases = [
        (planner_for_cell(cell).plan(PlanInput(WAYPOINTS)).trajectory, cell.joint_limits(), arm_axes),
        (Planner(mixed_limits).plan(PlanInput(mixed_wp)).trajectory, mixed_limits, mixed),
    ]
    for motion, limits, axes in cases:
        t0 = fraction * motion.duration
        stop = brake_on_path(motion, t0, limits)
        whole = stopped_motion(motion, stop)
        assert whole.duration == pytest.approx(stop.t_end, abs=1e-9)
        built = build_program(whole, axes, "stop")
        report = validate_program(built.program)
        assert report.ok, report.format_text()
        # the drives' reconstruction as close to the braking path as the uninterrupted plan's is to the plan
        planned = build_program(motion, axes, "plan")
        assert built.knots.deviation_qc <= max(1.0, planned.knots.deviation_qc), (
            built.knots.deviation_qc,
            planned.knots.deviation_qc,
        )

        # every axis at rest together: the programs end as closely as the uninterrupted plan's (one period of
        # the slowest fixed-period drive apart at most, what each drive's own period rounds to)
        def spread(program) -> float:
            ends = [float(a.records[:, 2].sum()) for a in program.axes]
            return max(ends) - min(ends)

        longest_period = max((a.period_ms or 1) for a in axes)  # the braking's end moves each axis's rounding
        assert spread(built.program) <= spread(planned.program) + longest_period
        for a in built.program.axes:
            assert a.records[-1, 1] == 0


@pytest.mark.parametrize("fraction", [0.2, 0.6])
def test_resume_after_pause_reaches_the_end_from_rest_within_the_limits(fraction: float) -> None:
    stop = brake_on_path(MOTION, fraction * MOTION.duration, LIMITS)
    rest = resume(MOTION, stop, LIMITS)
    np.testing.assert_allclose(rest.position(0.0), stop.trajectory.position(stop.trajectory.duration), atol=1e-9)
    assert np.max(np.abs(rest.velocity(0.0))) < 1e-9 and np.max(np.abs(rest.velocity(rest.duration))) < 1e-9
    np.testing.assert_allclose(rest.position(rest.duration), WAYPOINTS[-1], atol=1e-9)
    rv, ra = rest.limit_ratios(LIMITS)
    assert rv <= 1.0 + 1e-9 and ra <= 1.0 + 1e-9
    # pause + resume costs time against the uninterrupted motion, but not more than a stop and a restart
    total = stop.t_end + rest.duration
    assert MOTION.duration < total < MOTION.duration + 4.0 * stop.duration
    # placed from rest as a plan (a resume no ramp joins to the planned records): all of 0x60C5 until the planned
    # speed, no share of the speed given away (before: 0.95 of it)
    fastest = resume_from_rest(MOTION, stop, LIMITS)
    np.testing.assert_allclose(fastest.position(fastest.duration), WAYPOINTS[-1], atol=1e-9)
    rv, ra = fastest.limit_ratios(LIMITS)
    assert rv <= 1.0 + 1e-9 and 0.99 <= ra <= 1.0 + 1e-9
    at_95 = override(MOTION, stop.trajectory, stop.trajectory.duration, 0.95, LIMITS, rest_at_end=False)
    assert fastest.duration <= rest.duration + 1e-9 and fastest.duration < at_95.duration


@pytest.mark.parametrize(("v0", "v1"), [(1.0, 0.3), (0.3, 1.0), (0.0, 1.0)])
def test_jerk_override_changes_path_speed_within_its_acceleration_and_jerk(v0: float, v1: float) -> None:
    """The S-curve of a jerk-limited change of speed (a program's path: the plan at one path speed): from the
    running path speed to ``v1``, |s''| within its acceleration, its jerk within the given one, then on ``v1``."""
    ones = np.ones(len(MOTION.sd))
    planned = Trajectory.from_path_velocities(MOTION.path, MOTION.gridpoints, ones, MOTION.joint_names)
    if v0 > 0.0:
        running = planned.slowed(1.0 / v0) if v0 != 1.0 else planned
        t0 = 0.2 * running.duration
    else:  # at rest: a pause's end
        running = stopped_motion(planned, brake_on_path(planned, 0.3 * planned.duration, LIMITS))
        t0 = running.duration
    accel, jerk = 2.0, 40.0  # path units (program seconds) per s^2, s^3
    change = jerk_override(planned, running, t0, v1, accel, jerk)
    t = np.arange(0.0, change.duration, 1e-4)
    sd = np.interp(t, change.breakpoints, change.sd)  # the S-curve's steps are 0.1 ms: s'' per step
    sdd = np.diff(sd) / 1e-4
    assert abs(sd[0] - v0) < 1e-6 and change.sd[-1] == v1
    assert np.max(np.abs(sdd)) <= accel * 1.01
    assert np.max(np.abs(np.diff(sdd)) / 1e-4) <= jerk * 1.05
    ramp = t < (abs(v1 - v0) / accel + accel / jerk) * 1.05 + 1e-3  # the S-curve's length at most
    assert np.all(np.abs(sd[~ramp] - v1) < 1e-9)


def test_the_rejoin_takes_a_path_along_one_line_only() -> None:
    """Override 1.0's re-timing that joins the plan later (``onpath_rejoin``) bounds one reference joint's motion:
    every joint a fixed multiple of it, which holds on a line in joint space and not on a curved path."""
    jerk = 10.0 * np.asarray(LIMITS.acceleration)
    line = parameterize(JointPath(WAYPOINTS[:2], LIMITS), LIMITS, timing_constraints(LIMITS))
    ref, per_unit, sign = reference_of(line, 0.2 * line.duration, jerk)
    travel = WAYPOINTS[1] - WAYPOINTS[0]
    np.testing.assert_allclose(per_unit * travel[ref], travel, rtol=1e-6, atol=1e-9)
    assert sign == np.sign(travel[ref])
    with pytest.raises(NoRejoinError):
        reference_of(MOTION, 0.2 * MOTION.duration, jerk)
