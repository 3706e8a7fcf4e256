"""``pvtflow plan`` and ``pvtflow validate``: exit codes, reports, plot, batch, waypoint formats."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hand_programs import axis, program

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.service.cli import main
from pvtflow.service.config import load_cell_config
from pvtflow.service.waypoints import WaypointError, parse_waypoints

ARM6 = load_cell_config()
NAMES = ARM6.joint_names
WAYPOINTS = [[0.0] * 6, [0.6, -0.4, 0.5, 0.3, -0.3, 0.8], [-0.3, 0.2, -0.2, -0.4, 0.2, -0.5]]


@pytest.fixture(scope="module")
def planned(tmp_path_factory) -> Path:
    """One program planned through the CLI from pvtflow's own waypoint JSON."""
    d = tmp_path_factory.mktemp("plan")
    wp = d / "wp.json"
    wp.write_text(json.dumps({"joint_names": list(NAMES), "waypoints": WAYPOINTS}))
    out = d / "program.json"
    assert main(["plan", "--waypoints", str(wp), "-o", str(out)]) == 0
    return out


def test_plan_writes_a_valid_program(planned: Path, capsys) -> None:
    p = PvtProgram.loads(planned.read_text())
    assert [a.joint for a in p.axes] == list(NAMES) and p.cell == "arm6"
    assert p.metadata["deviation_qc"]["joint_1"] <= 1.0
    assert main(["validate", str(planned)]) == 0
    assert "VALID (0 error(s)" in capsys.readouterr().out


def test_plan_takes_a_ros_joint_trajectory_in_yaml_and_json(tmp_path: Path, planned: Path) -> None:
    order = list(reversed(NAMES))  # a ROS message names its joints: any order
    points = [
        {"positions": list(reversed(w)), "velocities": [0.0] * 6, "time_from_start": {"sec": i, "nanosec": 0}}
        for i, w in enumerate(WAYPOINTS)
    ]
    msg = {"header": {"frame_id": ""}, "joint_names": order, "points": points}
    ours = PvtProgram.loads(planned.read_text())
    for name, text in (("wp.yaml", yaml.safe_dump({"joint_trajectory": msg})), ("wp.json", json.dumps(msg))):
        (tmp_path / name).write_text(text)
        out = tmp_path / f"{name}.program.json"
        assert main(["plan", "--waypoints", str(tmp_path / name), "-o", str(out), "--json"]) == 0
        got = PvtProgram.loads(out.read_text())
        for a, b in zip(got.axes, ours.axes, strict=True):
            assert np.array_equal(a.records, b.records)  # the same motion as from our own format


def test_plan_bad_inputs_exit_2_with_one_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"joint_names": ["nope", *NAMES[1:]], "waypoints": [[0] * 6, [1] * 6]}))
    assert main(["plan", "--waypoints", str(bad), "-o", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err
    assert "unknown joint 'nope'" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert main(["plan", "--waypoints", str(tmp_path / "missing.json"), "-o", str(tmp_path / "x.json")]) == 2
    assert "file not found" in capsys.readouterr().err
    assert main(["plan", "--config", str(tmp_path / "none.yaml"), "--waypoints", str(bad), "-o", "x"]) == 2
    assert not (tmp_path / "x.json").exists()


def test_plan_scales_speed_and_acceleration_and_records_it(tmp_path: Path, planned: Path, capsys) -> None:
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"joint_names": list(NAMES), "waypoints": WAYPOINTS}))
    out = tmp_path / "half.json"
    assert main(["plan", "--waypoints", str(wp), "-o", str(out), "--velocity-scale", "0.5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["velocity_scale"] == 0.5 and max(summary["velocity_ratio"].values()) <= 0.5 * (1 + 1e-9)
    half, full = PvtProgram.loads(out.read_text()), PvtProgram.loads(planned.read_text())
    assert half.metadata["velocity_scale"] == 0.5 and half.metadata["acceleration_scale"] == 1.0
    assert half.duration_ms > full.duration_ms
    assert [a.limits for a in half.axes] == [a.limits for a in full.axes]  # the drives' own 0x607F / 0x60C5
    for option, value, says in (
        ("--velocity-scale", "0", "--velocity-scale must be in (0, 1], got 0"),
        ("--acceleration-scale", "-1", "--acceleration-scale must be in (0, 1], got -1"),
        ("--acceleration-scale", "1.01", "--acceleration-scale must be in (0, 1], got 1.01"),
        ("--velocity-scale", "nan", "--velocity-scale must be in (0, 1], got nan"),
    ):
        bad = tmp_path / "bad.json"
        assert main(["plan", "--waypoints", str(wp), "-o", str(bad), f"{option}={value}"]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1 and not bad.exists()


def test_plan_unplannable_exits_1(tmp_path: Path, capsys) -> None:
    wp = tmp_path / "far.json"
    wp.write_text(json.dumps({"waypoints": [[0.0] * 6, [50.0] + [0.0] * 5]}))  # outside joint_1's range
    assert main(["plan", "--waypoints", str(wp), "-o", str(tmp_path / "x.json")]) == 1
    assert "out_of_limits: " in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


def _write(path: Path, p: PvtProgram) -> Path:
    path.write_text(p.dumps(indent=1))
    return path


def test_validate_exit_codes(tmp_path: Path, capsys) -> None:
    good = _write(tmp_path / "good.json", program(axis([[0, 0, 1], [100, 0, 50], [100, 0, 0]])))
    bad = _write(tmp_path / "bad.json", program(axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]])))
    assert main(["validate", str(good)]) == 0
    assert main(["validate", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "joint_1 record 1: [acceleration-limit]" in out and "0x60C5" in out


@pytest.mark.parametrize(
    ("content", "text"),
    [
        ("{not json", "not JSON"),
        ('{"waypoints": [[0, 1]]}', "not a PVT program"),
        ("", "not JSON"),
        (None, "file not found"),
        ("DIR", "directory"),
    ],
)
def test_validate_unreadable_input_exits_2_without_traceback(tmp_path: Path, capsys, content, text: str) -> None:
    path = tmp_path / "input.json"
    if content == "DIR":
        path = tmp_path / "empty_dir"
        path.mkdir()
    elif content is not None:
        path.write_text(content)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


def test_validate_out_of_range_record_is_a_violation_not_unreadable(tmp_path: Path, capsys) -> None:
    data = program(axis([[0, 0, 1], [100, 0, 50], [100, 0, 0]])).to_json()
    data["axes"][0]["records"][1][1] = 2**23  # outside int24
    path = tmp_path / "range.json"
    path.write_text(json.dumps(data))
    assert main(["validate", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["errors"][0]["rule"] == "record-range" and report["errors"][0]["record"] == 1


def test_validate_json_report(tmp_path: Path, capsys) -> None:
    bad = _write(tmp_path / "bad.json", program(axis([[0, 7, 1], [1000, 0, 40], [1000, 0, 0]])))
    assert main(["validate", str(bad), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False and report["source"] == str(bad)
    assert {e["rule"] for e in report["errors"]} == {"start-record", "acceleration-limit"}
    assert report["axes"][0]["axis"] == "joint_1"


def test_validate_plot(tmp_path: Path, planned: Path) -> None:
    png = tmp_path / "out.png"
    assert main(["validate", str(planned), "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    bad = _write(tmp_path / "bad.json", program(axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]])))
    png2 = tmp_path / "bad.png"
    assert main(["validate", str(bad), "--plot", str(png2)]) == 1
    assert png2.stat().st_size > 5_000


def test_validate_batch_folder_with_summary(tmp_path: Path, planned: Path, capsys) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "a_planned.json").write_text(planned.read_text())
    _write(folder / "b_bad.json", program(axis([[0, 0, 1], [1000, 0, 40], [1000, 0, 0]])))
    (folder / "c_junk.json").write_text("[]")
    assert main(["validate", str(folder)]) == 2  # the worst outcome wins: unreadable
    out = capsys.readouterr().out
    assert "3 program(s): 1 valid, 1 with violations, 1 unreadable" in out
    assert "INVALID" in out and "UNREADABLE" in out
    (folder / "c_junk.json").unlink()
    assert main(["validate", str(folder), "--json"]) == 1
    reports = json.loads(capsys.readouterr().out)
    assert [r["ok"] for r in reports] == [True, False]


def test_waypoint_formats_and_errors() -> None:
    ours = parse_waypoints(json.dumps({"waypoints": WAYPOINTS}), NAMES)
    assert ours.shape == (3, 6)
    bare = parse_waypoints(json.dumps(WAYPOINTS), NAMES)
    assert np.array_equal(ours, bare)
    ros_yaml = yaml.safe_dump(
        {"trajectory": {"joint_names": list(NAMES), "points": [{"positions": w} for w in WAYPOINTS]}}
    )
    assert np.array_equal(parse_waypoints(ros_yaml, NAMES), ours)
    for text, msg in [
        ("joint_names: [a]\npoints: []", "points: must be a non-empty list"),
        (json.dumps({"waypoints": [[0] * 5, [1] * 5]}), "must be a list of 6 joint values, got 5 values"),
        (json.dumps({"waypoints": [[0] * 6, [0, 0, "x", 0, 0, 0]]}), r"waypoints[1][2]: must be a finite number"),
        (json.dumps({"waypoints": [[0] * 6]}), "at least 2 waypoints"),
        (json.dumps({"joint_names": list(NAMES[:5]), "waypoints": [[0] * 5, [1] * 5]}), "joint_6' of the cell"),
        (json.dumps({"points": [{"velocities": [0] * 6}]}), "needs 'positions'"),
        ("a: [1, 2\n", "neither JSON nor YAML"),
        (json.dumps({"foo": 1}), "not a waypoint file"),
    ]:
        with pytest.raises(WaypointError) as err:
            parse_waypoints(text, NAMES, "f.json")
        assert msg in str(err.value) and str(err.value).startswith("f.json")


def test_plan_has_a_budget_and_says_whether_the_plan_is_optimal(tmp_path: Path, capsys) -> None:
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"joint_names": list(NAMES), "waypoints": WAYPOINTS}))
    jerk = ",".join(str(10.0 * a) for a in ARM6.joint_limits().acceleration)
    out = tmp_path / "p.json"
    assert (
        main(["plan", "--waypoints", str(wp), "-o", str(out), "--max-jerk", jerk, "--budget-ms", "60000", "--json"])
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["budget_ms"] == 60000 and summary["optimal"] is True
    assert summary["gap"]["lower_bound_s"] <= summary["gap"]["duration_s"]
    assert main(["plan", "--waypoints", str(wp), "-o", str(out), "--json"]) == 0  # no jerk limit: TOPP-RA, exact
    summary = json.loads(capsys.readouterr().out)
    assert summary["budget_ms"] == ARM6.planning.budget_ms and summary["optimal"] is True and "gap" not in summary
    late = tmp_path / "late.json"
    assert main(["plan", "--waypoints", str(wp), "-o", str(late), "--budget-ms", "0.001"]) == 1
    err = capsys.readouterr().err
    assert "timeout: " in err and "past its budget of 0.001 ms" in err and not late.exists()
    assert main(["plan", "--waypoints", str(wp), "-o", str(late), "--budget-ms", "-5"]) == 2
    assert "--budget-ms must be a positive number of ms, got -5" in capsys.readouterr().err


def test_plan_says_why_a_plan_is_not_optimal() -> None:
    """The deadline, or the torque limits between the solver's rows (planner/jerk: its optimum slowed)."""
    from pvtflow.planner.path import PlanResult
    from pvtflow.planner.plan import PlanOutput
    from pvtflow.service.cell_planner import CellPlan
    from pvtflow.service.plan_cmd import _not_optimal_reason

    def reason(**details: object) -> str:
        return _not_optimal_reason(CellPlan("ok", plan=PlanOutput(PlanResult.OK, details=details)), 50.0)

    assert reason(solver_finished=False, torque_scale=1.3) == "the 50 ms budget came first"
    slowed = reason(solver_finished=True, torque_scale=1.039)
    assert slowed == "slowed 3.9 % to hold the torque limits between the solver's rows"
