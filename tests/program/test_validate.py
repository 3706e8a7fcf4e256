"""The validator: a valid program passes; one program per rule that breaks it, caught by that rule."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from axes.scaling import DriveLimits
from planner.program import PvtProgram
from planner.validate import validate_program

from .conftest import GOOD_RECORDS, LIMITS, axis, program


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
