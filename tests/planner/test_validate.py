"""The validator: a valid program passes; one program per rule that breaks it, caught by that rule."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hand_programs import GOOD_RECORDS, LIMITS, SCALING, axis, program

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.drive.scaling import DriveLimits
from pvtflow.planner.validate import validate_program


def only(report, rule: str):
    found = [f for f in report.findings if f.rule == rule]
    assert found, f"no {rule} finding in:\n{report.format_text()}"
    return found


def test_valid_program(good_program: PvtProgram) -> None:
    report = validate_program(good_program)
    assert report.ok and not report.errors and not report.warnings
    assert "VALID" in report.format_text()
    j1 = report.axes[0]
    assert j1.max_velocity_rpm == pytest.approx(90.0)
    assert j1.max_acceleration_rpm_s == pytest.approx(7200.0)
    assert j1.velocity_ratio == pytest.approx(90 / 4000)
    data = report.to_json()
    json.dumps(data)
    assert data["ok"] is True and data["errors"] == []


@pytest.mark.parametrize(
    ("records", "record", "text"),
    [
        ([[2**31, 0, 1], [100, 0, 50], [100, 0, 0]], 0, "position 2147483648 qc is outside int32"),
        ([[0, 0, 1], [100, 2**23, 50], [100, 0, 0]], 1, "velocity 8388608 velocity units is outside int24"),
        ([[0, 0, 1], [100, 0, 300], [100, 0, 0]], 1, "time 300 ms is outside 0..255"),
    ],
)
def test_record_range(records, record: int, text: str) -> None:
    report = validate_program(program(axis(records)))
    f = only(report, "record-range")[0]
    assert not report.ok and f.record == record and f.axis == "joint_1" and text in f.message


def test_start_record_must_be_at_rest() -> None:
    report = validate_program(program(axis([[0, 7, 1], [100, 0, 50], [100, 0, 0]])))
    f = only(report, "start-record")[0]
    assert f.record == 0 and "velocity 0" in f.message and f.amount == 7


def test_start_dwell_of_zero_ms() -> None:
    report = validate_program(program(axis([[0, 0, 0], [100, 0, 50], [100, 0, 0]])))
    f = only(report, "time-range")[0]
    assert f.record == 0 and "dwell" in f.message
    assert report.axes[0].max_velocity_rpm is None  # no reconstruction to judge


def test_time_zero_before_the_end_stops_interpolation_early() -> None:
    report = validate_program(program(axis([[0, 0, 1], [50, 0, 0], [100, 0, 50], [100, 0, 0]])))
    f = only(report, "time-range")[0]
    assert f.record == 1 and "ends interpolation here" in f.message


def test_end_record_needs_time_zero() -> None:
    report = validate_program(program(axis([[0, 0, 1], [100, 0, 50], [100, 0, 10]])))
    f = only(report, "end-record")[0]
    assert f.record == 2 and "time 0" in f.message and "underflow" in f.message


def test_end_record_must_repeat_the_final_position() -> None:
    report = validate_program(program(axis([[0, 0, 1], [100, 0, 50], [120, 0, 0]])))
    f = only(report, "end-record")[0]
    assert f.record == 2 and "differs by 20 qc" in f.message and f.amount == 20


def test_motion_must_end_at_rest() -> None:
    report = validate_program(program(axis([[0, 0, 1], [100, 30, 50], [100, 0, 0]])))
    f = only(report, "end-record")[0]
    assert f.record == 1 and "at rest" in f.message


def test_velocity_limit_with_record_and_amount() -> None:
    # 0 -> 10000 qc in 100 ms: peak 1.5 * 100 = 150 qc/ms = 4500 rpm > 4000 (0x607F)
    report = validate_program(
        program(
            axis(
                [[0, 0, 1], [10000, 0, 100], [10000, 0, 0]],
                limits=dataclasses.replace(LIMITS, max_acceleration_rpm_s=1e6),
            )
        )
    )
    f = only(report, "velocity-limit")[0]
    assert f.record == 1 and f.severity == "error"
    assert f.value == pytest.approx(4500.0) and f.amount == pytest.approx(500.0)
    assert "0x607F" in f.message and "12.50%" in f.message and "also at the drive's 1 ms samples" in f.message


def test_acceleration_limit_with_record_and_amount() -> None:
    # 0 -> 1000 qc in 40 ms: 6 * 1000 / 1600 = 3.75 qc/ms^2 = 112500 rpm/s > 30000 (0x60C5)
    report = validate_program(program(axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]])))
    f = only(report, "acceleration-limit")[0]
    assert f.record == 1 and f.value == pytest.approx(112500.0) and "0x60C5" in f.message
    assert f.amount == pytest.approx(82500.0)


def test_position_limit_between_records() -> None:
    """Both records inside 0x607D, the cubic between them outside: caught along the reconstruction."""
    lim = dataclasses.replace(LIMITS, max_position_qc=1000, max_profile_velocity_rpm=1e5, max_acceleration_rpm_s=1e7)
    # from 900 at +30 qc/ms (900 units) back to 900 at rest in 40 ms: swings past 1000
    report = validate_program(
        program(axis([[900, 0, 1], [1000, 0, 10], [1000, 900, 1], [900, 0, 40], [900, 0, 0]], limits=lim))
    )
    f = only(report, "position-limit")[0]
    assert f.record == 3 and "above 0x607D:02 1000 qc" in f.message and f.amount > 0


def test_profile_velocity_and_acceleration_are_warnings() -> None:
    lim = dataclasses.replace(LIMITS, profile_velocity_rpm=50.0, profile_acceleration_rpm_s=5000.0)
    report = validate_program(program(axis(GOOD_RECORDS, limits=lim)))
    assert report.ok  # warnings only
    assert only(report, "profile-velocity")[0].severity == "warning"
    assert "0x6081" in only(report, "profile-velocity")[0].message
    assert "0x6083" in only(report, "profile-acceleration")[0].message


def test_fixed_period_rules() -> None:
    rec = [[0, 0, 2], [1, 0, 2], [3, 0, 3], [4, 0, 2], [4, 0, 2]]
    report = validate_program(program(axis(rec, profile="cia402_ip_linear")))
    f = only(report, "period")[0]
    assert f.record == 2 and "differs from the axis's period 2 ms by +1 ms" in f.message
    stop = validate_program(program(axis([[0, 0, 2], [1, 0, 2], [3, 0, 2]], profile="cia402_ip_linear")))
    assert "must repeat the one before" in only(stop, "end-record")[0].message
    ok = validate_program(
        program(axis([[0, 0, 2], [1, 0, 2], [3, 0, 2], [4, 0, 2], [4, 0, 2]], profile="sync_setpoint"))
    )
    assert ok.ok, ok.format_text()


def test_fixed_period_acceleration_is_the_velocity_step() -> None:
    # a step of 100 qc per 1 ms period from rest: 100 qc/ms in 1 ms = 3e6 rpm/s
    report = validate_program(program(axis([[0, 0, 1], [100, 0, 1], [100, 0, 1]], profile="cia402_ip_linear")))
    assert only(report, "acceleration-limit")[0].record == 1


def test_findings_name_the_axis() -> None:
    bad = axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]], name="joint_2", node_id=2)
    report = validate_program(program(axis(GOOD_RECORDS), bad))
    assert {f.axis for f in report.errors} == {"joint_2"}
    assert "joint_2 record 1: [acceleration-limit]" in report.format_text()


def test_json_report_of_a_bad_program() -> None:
    report = validate_program(program(axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]])), source="x.json")
    data = json.loads(json.dumps(report.to_json()))
    assert data["ok"] is False and data["source"] == "x.json"
    e = data["errors"][0]
    assert e["rule"] == "acceleration-limit" and e["axis"] == "joint_1" and e["record"] == 1
    assert e["unit"] == "rpm/s" and e["amount"] > 0


def test_many_findings_are_summarised_in_text() -> None:
    rec = [[0, 0, 1]] + [[1000 * (k % 2), 0, 20] for k in range(1, 30)] + [[0, 0, 0]]
    rec[-2][0] = 0
    report = validate_program(program(axis(np.array(rec))))
    assert len(only(report, "acceleration-limit")) > 8
    assert "more [acceleration-limit] finding(s) on joint_1" in report.format_text()


def test_unchecked_ranges_round_trip_through_json() -> None:
    data = program(axis([[0, 0, 1], [100, 0, 50], [100, 0, 0]])).to_json()
    data["axes"][0]["records"][1][2] = 256
    with pytest.raises(ValueError, match=r"axes\[0\].records\[1\] time"):
        PvtProgram.from_json(data)
    p = PvtProgram.from_json(data, check_ranges=False)
    assert only(validate_program(p), "record-range")[0].record == 1


def test_drive_limits_fixture_is_consistent() -> None:
    assert DriveLimits(**LIMITS.to_json()) == LIMITS


def random_epos2_records(rng: np.random.Generator, n: int) -> np.ndarray:
    """A wandering EPOS2 program: start at rest, n motion records of 1..255 ms, end at rest with time 0."""
    positions = np.cumsum(rng.integers(-400, 400, n))
    velocities = rng.integers(-300, 300, n)
    velocities[-1] = 0
    times = rng.integers(1, 256, n)
    motion = np.column_stack([positions, velocities, times])
    return np.vstack([[0, 0, int(rng.integers(1, 10))], motion, [positions[-1], 0, 0]])


@pytest.mark.parametrize("sample_period_ms", [None, 1.0])
def test_summary_is_the_reconstructions_exact_worst(sample_period_ms) -> None:
    """Per axis, the summary's numbers are those of the drive's reconstruction, to the last bit."""
    rng = np.random.default_rng(7)
    lim = dataclasses.replace(LIMITS, max_profile_velocity_rpm=1e7, max_acceleration_rpm_s=1e9)
    axes = [axis(random_epos2_records(rng, 40 + 10 * k), f"joint_{k}", k, limits=lim) for k in range(1, 5)]
    report = validate_program(program(*axes), sample_period_ms=sample_period_ms)
    assert report.ok, report.format_text()
    for a, summary in zip(axes, report.axes, strict=True):
        recon = a.reconstruction()
        lo, hi = recon.position_range()
        assert summary.max_velocity_rpm == float(np.max(a.scaling.qc_per_ms_to_rpm(recon.max_abs_velocity())))
        assert summary.max_acceleration_rpm_s == float(
            np.max(a.scaling.qc_per_ms2_to_rpm_s(recon.max_abs_acceleration()))
        )
        assert (summary.min_position_qc, summary.max_position_qc) == (float(lo.min()), float(hi.max()))
        assert summary.duration_ms == recon.end_time == float(a.records[:, 2].sum())
        assert summary.velocity_ratio == summary.max_velocity_rpm / lim.max_profile_velocity_rpm
        assert (summary.sampled_velocity_ratio > 0.0) == (sample_period_ms is not None)


def test_a_limit_at_the_worst_value_is_kept_just_above_it_is_broken() -> None:
    """The round-off allowance of ``exceeds``: at 0x607F (or within 1e-9 above) passes, beyond it fails."""
    rng = np.random.default_rng(3)
    records = random_epos2_records(rng, 60)
    wide = dataclasses.replace(LIMITS, max_profile_velocity_rpm=1e7, max_acceleration_rpm_s=1e9)
    worst = validate_program(program(axis(records, limits=wide)), sample_period_ms=None).axes[0]
    for limit, ok in (
        (worst.max_velocity_rpm, True),
        (worst.max_velocity_rpm / (1 + 0.5e-9), True),
        (worst.max_velocity_rpm / (1 + 2e-9), False),
    ):
        lim = dataclasses.replace(wide, max_profile_velocity_rpm=limit)
        report = validate_program(program(axis(records, limits=lim)), sample_period_ms=None)
        assert report.ok is ok
        if not ok:  # on the segments that reach the worst value, and no other
            recon = axis(records).reconstruction()
            seg_v = SCALING.qc_per_ms_to_rpm(recon.max_abs_velocity())
            found = only(report, "velocity-limit")
            assert [f.record for f in found] == np.flatnonzero(seg_v == worst.max_velocity_rpm).tolist()
            assert all(f.value == worst.max_velocity_rpm and f.amount > 0 for f in found)


def test_record_findings_land_on_their_own_axis_and_record() -> None:
    """Rules checked over all axes' records at once still name each axis and its record index."""
    good = [[0, 0, 1], [100, 0, 50], [200, 0, 50], [300, 0, 50], [300, 0, 0]]
    times = [[0, 0, 1], [100, 0, 0], [200, 0, 300], [300, 0, 50], [300, 0, 0]]
    ranges = [[0, 0, 1], [100, 2**23, 50], [2**31, 0, 50], [300, 0, 256], [300, 0, 0]]
    report = validate_program(
        program(
            axis(good, "joint_1", 1),
            axis(times, "joint_2", 2),
            axis(good, "joint_3", 3),
            axis(ranges, "joint_4", 4),
            axis(good, "joint_5", 5),
        )
    )
    found = {(f.axis, f.rule, f.record) for f in report.findings if f.rule in ("time-range", "record-range")}
    assert found == {
        ("joint_2", "time-range", 1),
        ("joint_2", "time-range", 2),
        ("joint_2", "record-range", 2),
        ("joint_4", "record-range", 1),
        ("joint_4", "record-range", 2),
        ("joint_4", "record-range", 3),
        ("joint_4", "time-range", 3),
    }
    assert [a.axis for a in report.axes] == [f"joint_{k}" for k in range(1, 6)]
    assert report.axes[0] == dataclasses.replace(report.axes[2], axis="joint_1")


@pytest.mark.parametrize("cut", ["two_columns", "flat"])
def test_records_of_the_wrong_shape_are_a_finding_not_a_crash(cut: str, good_program: PvtProgram) -> None:
    prog = good_program
    ax = prog.axes[0]
    records = ax.records[:, :2] if cut == "two_columns" else ax.records[:, 0]
    broken = dataclasses.replace(prog, axes=(dataclasses.replace(ax, records=records), *prog.axes[1:]))
    for period in (None, 1.0):
        report = validate_program(broken, sample_period_ms=period)
        assert not report.ok
        assert [f.axis for f in report.errors] == [ax.joint]
        assert "got an array of shape" in report.errors[0].message


def test_linear_steps_of_one_count_cannot_accelerate_past_0x60c5_for_long() -> None:
    """A step of one count is within the rounding of whole counts, a run of them is not: 20 periods
    of one count more each is 1 qc/ms^2 on average, against a 0x60C5 of 0.5 qc/ms^2."""
    lim = DriveLimits(4000, 15000, -100000, 100000)  # 15000 rpm/s = 0.5 qc/ms^2 at 2000 qc/rev
    steps = np.concatenate((np.arange(1, 21), np.arange(20, 0, -1)))
    positions = np.concatenate(([0], np.cumsum(steps), [steps.sum()]))
    records = [[int(p), 0, 1] for p in positions]
    report = validate_program(program(axis(records, profile="cia402_ip_linear", limits=lim)))
    spans = [f for f in report.errors if f.rule == "acceleration-limit"]
    assert spans and "periods" in spans[0].message and "0x60C5 15000" in spans[0].message


def _mutations(records: np.ndarray) -> list[np.ndarray]:
    """``records`` as they are, and once broken by each rule on records (one change each)."""
    out = [records]
    last = len(records) - 1
    for row, col, value in (
        (3, 0, 2**31),  # record-range: position
        (4, 1, 2**23),  # record-range: velocity
        (5, 2, 300),  # record-range and time-range
        (6, 2, 0),  # time 0 before the end
        (0, 1, 5),  # start not at rest
        (0, 2, 0),  # no dwell
        (last, 2, 7),  # no end marker
        (last, 1, 3),  # end not at rest
        (last - 1, 1, 3),  # the last motion record not at rest
        (last, 0, int(records[last, 0]) + 1),  # the end record elsewhere
    ):
        broken = records.copy()
        broken[row, col] = value
        out.append(broken)
    return out


def test_one_look_at_all_axes_changes_no_answer(monkeypatch) -> None:
    """The compiled look at a program of EPOS2 axes (``screen._epos2_screen``) gives the report the
    rule-by-rule path gives, for records that keep every rule and for records that break one."""
    from pvtflow.planner.validate import screen

    rng = np.random.default_rng(17)
    wide = dataclasses.replace(LIMITS, max_profile_velocity_rpm=1e7, max_acceleration_rpm_s=1e9)
    base = [random_epos2_records(rng, 30 + 7 * k) for k in range(3)]
    cases = []
    for k in range(3):
        for broken in _mutations(base[k]):
            recs = [broken if j == k else base[j] for j in range(3)]
            cases.append(program(*(axis(r, f"joint_{j}", j + 1, limits=wide) for j, r in enumerate(recs))))
    cases.append(program(*(axis(r, f"joint_{j}", j + 1) for j, r in enumerate(base))))  # over 0x607F: motion findings
    fast = [validate_program(p, sample_period_ms=period) for p in cases for period in (None, 1.0)]
    unclean = screen._epos2_screen

    def nothing_clean(*args):
        worst, clean = unclean(*args)
        return worst, np.zeros_like(clean)

    monkeypatch.setattr(screen, "_epos2_screen", nothing_clean)
    slow = [validate_program(p, sample_period_ms=period) for p in cases for period in (None, 1.0)]
    assert sum(r.ok for r in fast) == 6  # the unbroken program (once per axis's list), with and without the samples
    for f, s in zip(fast, slow, strict=True):
        assert f.errors == s.errors and f.warnings == s.warnings and f.axes == s.axes


def test_position_range_of_a_smooth_motion_is_exact() -> None:
    """The worst values skip the exact position range of segments inside the band of the segment
    starts: the lowest and highest position are still the reconstruction's, to the last bit."""
    t = np.arange(0, 2001, 20)
    pos = np.rint(1e5 * np.sin(t / 300.0) + 3e4 * np.sin(t / 37.0)).astype(np.int64)
    vel = np.rint(
        (1e5 / 300.0 * np.cos(t / 300.0) + 3e4 / 37.0 * np.cos(t / 37.0)) / SCALING.qc_per_ms_per_velocity_unit
    )
    vel[0] = vel[-1] = 0
    records = np.vstack([[pos[0], 0, 1], np.column_stack([pos[1:], vel[1:], np.diff(t)]), [pos[-1], 0, 0]])
    records[1:-1, 1][-1] = 0
    wide = dataclasses.replace(
        LIMITS,
        max_profile_velocity_rpm=1e9,
        max_acceleration_rpm_s=1e12,
        min_position_qc=-(2**31),
        max_position_qc=2**31 - 1,
    )
    a = axis(records, limits=wide)
    report = validate_program(program(a), sample_period_ms=None)
    assert report.ok, report.format_text()
    lo, hi = a.reconstruction().position_range()
    assert (report.axes[0].min_position_qc, report.axes[0].max_position_qc) == (float(lo.min()), float(hi.max()))
    assert float(lo.min()) < float(records[:, 0].min())  # the extremes lie between records: solved, not read
