"""Knot placement: every program it emits is executable as it is, within the tolerance of the plan."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pvtflow.axes.drive.interpolation import (
    LINEAR_QUANTIZATION_QC,
    Interpolation,
    epos2_pvt,
    linear,
    linear_span_excess,
)
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.planner.build import build_program
from pvtflow.planner.knots import DriveAxis, KnotOptions, fixed_period_kernels, place_knots
from pvtflow.planner.limits import joint_limits_from_drives
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import planner_for_cell
from pvtflow.service.config import load_cell_config


@pytest.fixture(scope="module")
def arm6():
    cell = load_cell_config()
    return cell, list(cell.ordered_axes())


def _random_waypoints(cell, rng: np.random.Generator, n: int) -> np.ndarray:
    lim = cell.joint_limits()
    return lim.lower + (lim.upper - lim.lower) * (0.15 + 0.7 * rng.random((n, lim.dof)))


def _deviation_qc(program, trajectory, axes, time_scale: float) -> np.ndarray:
    """Worst |reconstruction - plan| per axis, measured here independently of planner.knots."""
    n = math.ceil(trajectory.duration * 1000.0 * time_scale - 1e-6)
    t_ms = np.arange(n + 1.0)
    q = trajectory.position(t_ms / (1000.0 * time_scale))
    out = []
    for i, (ax, ap) in enumerate(zip(axes, program.axes, strict=True)):
        recon = ap.reconstruction()
        plan_qc = ax.scaling.position_to_qc(q[:, i])
        out.append(np.abs(recon.position(t_ms + ap.records[0, 2]) - plan_qc).max())
    return np.array(out)


def test_arm6_program_is_valid_close_and_sparse(arm6) -> None:
    cell, axes = arm6
    wp = _random_waypoints(cell, np.random.default_rng(4), 5)
    out = planner_for_cell(cell).plan(PlanInput(wp))
    assert out.ok, out.message
    built = build_program(out.trajectory, axes, cell.name)
    report = validate_program(built.program)
    assert report.ok, report.format_text()
    for s in report.axes:  # exactly inside 0x607F / 0x60C5 on the drive's own reconstruction
        assert s.velocity_ratio <= 1.0 + 1e-9 and s.acceleration_ratio <= 1.0 + 1e-9
    dev = _deviation_qc(built.program, out.trajectory, axes, built.knots.time_scale)
    assert np.all(dev <= 1.0 + 1e-9)
    assert dev.max() == pytest.approx(built.knots.deviation_qc, abs=1e-6)
    duration_s = built.program.duration_ms / 1000.0
    records_per_axis_s = np.mean([len(a.records) for a in built.program.axes]) / duration_s
    assert records_per_axis_s < 40  # a uniform 10 ms grid needs 100
    assert built.knots.time_scale < 1.02
    for a in built.program.axes:  # integer times 1..255, time 0 only at the end
        assert a.records[0, 1] == 0 and a.records[-1, 2] == 0
        assert np.all((a.records[:-1, 2] >= 1) & (a.records[:-1, 2] <= 255))
        assert a.duration_ms == built.program.axes[0].duration_ms  # all axes end together


def test_duration_close_to_the_fine_reference(arm6) -> None:
    cell, axes = arm6
    wp = _random_waypoints(cell, np.random.default_rng(8), 4)
    out = planner_for_cell(cell).plan(PlanInput(wp))
    reference = planner_for_cell(cell, 3000)
    reference.speed_band = 0.0  # the time-optimal motion, whatever band a cell file asks for
    ref = reference.plan(PlanInput(wp))
    built = build_program(out.trajectory, axes, cell.name)
    # the knots add at most the whole-ms rounding and a small slow-down to the planned duration
    assert built.program.duration_ms / 1000.0 <= out.trajectory.duration * built.knots.time_scale + 0.0025
    assert built.program.duration_ms / 1000.0 / ref.trajectory.duration < 1.06


def test_naive_sampling_overshoots_but_placed_knots_do_not(arm6) -> None:
    """The issue's premise: a uniform 10 ms grid of exact samples violates 0x60C5 on the EPOS2."""
    cell, axes = arm6
    wp = _random_waypoints(cell, np.random.default_rng(1), 3)
    traj = planner_for_cell(cell).plan(PlanInput(wp)).trajectory
    worst = 0.0
    t_ms = np.arange(0, math.floor(traj.duration * 1000) + 1, 10.0)
    q, qd = traj.position(t_ms / 1000), traj.velocity(t_ms / 1000)
    for i, ax in enumerate(axes):
        s = ax.scaling
        rec = np.column_stack(
            (np.rint(s.position_to_qc(q[:, i])), np.rint(s.velocity_to_drive(qd[:, i])), np.full(len(t_ms), 10))
        )
        rec = np.vstack((rec, [rec[-1, 0], 0, 0])).astype(np.int64)
        rec[0, 2] = 1
        pc = epos2_pvt(rec, s.qc_per_ms_per_velocity_unit)
        a_rpm_s = float(s.qc_per_ms2_to_rpm_s(pc.max_abs_acceleration()).max())
        worst = max(worst, a_rpm_s / ax.limits.max_acceleration_rpm_s)
    assert worst > 1.05
    built = build_program(traj, axes, cell.name)
    assert max(a.acceleration_ratio for a in built.knots.axes) <= 1.0 + 1e-9


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 6))
def test_random_plans_always_validate(arm6, seed: int, n: int) -> None:
    cell, axes = arm6
    wp = _random_waypoints(cell, np.random.default_rng(seed), n)
    out = planner_for_cell(cell).plan(PlanInput(wp))
    if not out.ok:  # the planner may refuse a path (e.g. out of limits): not this test's subject
        return
    built = build_program(out.trajectory, axes, cell.name)
    assert validate_program(built.program).ok
    assert built.knots.deviation_qc <= 1.0


# --- fixed-period profiles -------------------------------------------------------------------------------
def _fixed_period_axes() -> list[DriveAxis]:
    s = AxisScaling.prismatic(4096, 0.02)
    lim = DriveLimits(3000, 30000, 0, 245000)
    return [
        DriveAxis("x", 1, "cia402_ip_linear", s, lim, period_ms=2),
        DriveAxis("y", 2, "sync_setpoint", s, lim, period_ms=1),
        DriveAxis("z", 3, "parker_slvdn", s, lim, period_ms=4, interpolation_submode=-1),
        DriveAxis("w", 4, "parker_slvdn", s, lim, period_ms=4, interpolation_submode=-2),
        DriveAxis("v", 5, "epos2_pvt", s, lim),
    ]


def test_fixed_period_profiles_one_record_per_period() -> None:
    axes = _fixed_period_axes()
    limits = joint_limits_from_drives([a.joint for a in axes], [a.scaling for a in axes], [a.limits for a in axes])
    wp = np.array([[0.01] * 5, [0.4, 0.3, 0.2, 0.25, 0.35], [0.1, 0.45, 0.05, 0.3, 0.2]])
    traj = Planner(limits).plan(PlanInput(wp)).trajectory
    built = build_program(traj, axes, "mixed")
    report = validate_program(built.program)
    assert report.ok, report.format_text()
    for ax, a in zip(axes, built.program.axes, strict=True):
        if ax.period_ms is not None:
            assert np.all(a.records[:, 2] == ax.period_ms)
            assert a.records[-1, 0] == a.records[-2, 0]  # at rest at the end
    z = built.program.axis("z")
    assert np.any(z.records[:, 1] != 0)  # Parker -1 takes the velocity
    assert np.all(built.program.axis("x").records[:, 1] == 0)


def test_linear_drive_below_one_count_per_period_squared_plans_within_its_acceleration() -> None:
    """A linear drive at 1 ms whose 0x60C5 is far below one count per period squared: its records
    step by whole counts (each step judged net of the rounding), and over any span of periods the
    velocity changes no faster than 0x60C5 allows plus the rounding of whole counts."""
    s = AxisScaling.revolute(500, 1.0)
    lim = DriveLimits(3000, 5000, -(10**6), 10**6)  # 5000 rpm/s = 0.042 qc/ms^2 at 500 qc/rev
    axes = [DriveAxis("j", 1, "cia402_ip_linear", s, lim, period_ms=1)]
    limits = joint_limits_from_drives(["j"], [s], [lim])
    traj = Planner(limits).plan(PlanInput(np.array([[0.0], [3.0]]))).trajectory
    result = place_knots(traj, axes, KnotOptions(max_time_scale=1.05))
    records = result.axes[0].records
    recon = linear(records, 1.0)
    a_max = float(s.rpm_s_to_qc_per_ms2(lim.max_acceleration_rpm_s))
    assert a_max < 1.0  # one count per ms^2 is more than the drive allows
    assert linear_span_excess(recon.c1, 1.0, a_max)[2] <= 1e-9
    assert np.abs(np.diff(records[:, 0], 2)).max() <= math.floor(a_max + LINEAR_QUANTIZATION_QC)
    program = PvtProgram("t", (AxisProgram("j", 1, "cia402_ip_linear", s, lim, records=records),))
    assert validate_program(program).ok
    # the same records with one sustained count more per period squared break the span rule
    steps = np.diff(records[:-1, 0])
    pushed = np.concatenate(([records[0, 0]], records[0, 0] + np.cumsum(steps + np.arange(len(steps)))))
    assert linear_span_excess(np.diff(pushed).astype(float), 1.0, a_max)[2] > 0


def test_options_are_checked() -> None:
    with pytest.raises(ValueError, match="tolerance_qc"):
        KnotOptions(tolerance_qc=0.1)
    with pytest.raises(ValueError, match="period"):
        DriveAxis("x", 1, "cia402_ip_linear", AxisScaling(1000, 1.0), DriveLimits(1, 1, 0, 1))


@pytest.mark.parametrize("step", [1e-5, 1e-3, 0.05])
def test_short_moves_are_executable(arm6, step: float) -> None:
    """A move of a count or a few: whole ms and whole counts dominate, the program still holds."""
    cell, axes = arm6
    lim = cell.joint_limits()
    mid = 0.5 * (lim.lower + lim.upper)
    out = planner_for_cell(cell).plan(PlanInput(np.array([mid, mid + step])))
    assert out.ok, out.message
    built = build_program(out.trajectory, axes, cell.name)
    assert validate_program(built.program).ok
    assert built.knots.deviation_qc <= 1.0
    # the slow-down whole counts call for is small in absolute terms
    assert built.program.duration_ms <= out.trajectory.duration * 1000 * 1.05 + 50


def test_the_kernels_take_the_reconstruction_codes() -> None:
    codes = [k.code for k in Interpolation]
    assert len(set(codes)) == len(codes)
    assert (
        Interpolation.LINEAR.code,
        Interpolation.CUBIC_PV.code,
        Interpolation.CUBIC_P.code,
    ) == (fixed_period_kernels.LINEAR, fixed_period_kernels.CUBIC_PV, fixed_period_kernels.CUBIC_P)
