"""max_jerk through the service side: the cell file (per axis), the plan request (api), the
planning pipeline (CellPlanner) and ``pvtflow plan --max-jerk``."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.cartesian import placement_pose
from pvtflow.planner.ik import IkSolver
from pvtflow.planner.jerk import JerkTrajectory
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.planner.validate import validate_program
from pvtflow.service.api import ApiError, ErrorCode, parse_plan
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config

ARM = CONFIG_DIR / "cells" / "arm6.yaml"
CELL = load_cell_config(ARM)
NAMES = CELL.joint_names
LIMITS = CELL.joint_limits()
WAYPOINTS = [[0.0] * 6, [0.6, -0.4, 0.5, 0.3, -0.3, 0.8], [-0.3, 0.2, -0.2, -0.4, 0.2, -0.5]]


def arm_with_jerk(tmp_path: Path, jerk: dict[int, Any]) -> Path:
    """arm6 with ``max_jerk`` on the axes given (index -> value), written to a file."""
    data = yaml.safe_load(ARM.read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "arm6.urdf")
    for i, value in jerk.items():
        data["axes"][i]["max_jerk"] = value
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_cell_file_with_max_jerk_plans_jerk_limited_and_a_request_overrides_it(tmp_path: Path) -> None:
    cell = load_cell_config(arm_with_jerk(tmp_path, {0: 60.0, 3: 200}))
    assert cell.planning.max_jerk == (60.0, math.inf, math.inf, 200.0, math.inf, math.inf)
    assert load_cell_config(ARM).planning.max_jerk is None
    planner = CellPlanner(cell)
    by_cell = planner.plan(PlanInput(WAYPOINTS))
    assert by_cell.ok and by_cell.program is not None and by_cell.plan is not None
    assert isinstance(by_cell.plan.trajectory, JerkTrajectory)
    assert by_cell.program.metadata["max_jerk"] == [60.0, None, None, 200.0, None, None]
    assert {"topp", "jerk"} <= set(by_cell.timing)
    assert not validate_program(by_cell.program).errors
    override = [1000.0] * 6
    by_request = planner.plan(PlanInput(WAYPOINTS, max_jerk=override))
    assert by_request.ok and by_request.program is not None
    assert by_request.program.metadata["max_jerk"] == override
    assert by_request.program.duration_ms < by_cell.program.duration_ms
    refused = planner.plan(PlanInput(WAYPOINTS, max_jerk=[1.0] * 5))
    assert not refused.ok and refused.code == "invalid_input" and "max_jerk has 5 values" in refused.message


@pytest.mark.parametrize(
    ("value", "words"),
    [(0, "must be positive"), (-5.0, "must be positive"), ("fast", "must be a finite number"), (True, "finite number")],
)
def test_a_bad_max_jerk_in_the_cell_file_is_named(tmp_path: Path, value: Any, words: str) -> None:
    path = arm_with_jerk(tmp_path, {2: value})
    with pytest.raises(ConfigError) as info:
        load_cell_config(path)
    assert info.value.where == "axes[2].max_jerk"
    assert words in info.value.problem


def test_the_plan_request_takes_max_jerk_in_its_joint_order() -> None:
    req = parse_plan({"target": [0.1] * 6}, NAMES)
    assert req.max_jerk is None
    jerk = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    req = parse_plan({"target": [0.1] * 6, "max_jerk": jerk}, NAMES)
    assert req.max_jerk is not None and list(req.max_jerk) == jerk
    reordered = parse_plan({"target": [0.1] * 6, "max_jerk": jerk, "joint_names": list(reversed(NAMES))}, NAMES)
    assert reordered.max_jerk is not None and list(reordered.max_jerk) == jerk[::-1]
    poses = parse_plan({"poses": [[0.6, 0.1, 0.3, 0, 0, 0, 1]], "max_jerk": jerk}, NAMES)
    assert poses.max_jerk is not None and list(poses.max_jerk) == jerk


@pytest.mark.parametrize(
    ("value", "code"),
    [
        ([1.0] * 5, ErrorCode.WRONG_JOINT_COUNT),
        ([1.0] * 7, ErrorCode.WRONG_JOINT_COUNT),
        ([1.0, 0, 1, 1, 1, 1], ErrorCode.INVALID_REQUEST),
        ([1.0, 1, 1, 1, 1, -2], ErrorCode.INVALID_REQUEST),
        ([1.0, 1, 1, "2", 1, 1], ErrorCode.INVALID_REQUEST),
        ([1.0, 1, 1, True, 1, 1], ErrorCode.INVALID_REQUEST),
        (100.0, ErrorCode.INVALID_REQUEST),
    ],
)
def test_a_bad_max_jerk_in_a_plan_request_is_refused(value: Any, code: ErrorCode) -> None:
    with pytest.raises(ApiError) as info:
        parse_plan({"target": [0.1] * 6, "max_jerk": value}, NAMES)
    assert info.value.code is code
    assert "max_jerk" in str(info.value)


def test_pvtflow_plan_max_jerk(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    wp = tmp_path / "wp.json"  # one segment: two solves of seconds each, what is tested is where max_jerk comes from
    wp.write_text(json.dumps({"joint_names": list(NAMES), "waypoints": WAYPOINTS[:2]}))
    out = tmp_path / "jerk.json"
    jerk = 5.0 * LIMITS.acceleration
    text = ",".join(f"{j:.17g}" for j in jerk)
    # a budget no loaded host reaches: both plans are the solver's optimum, whatever the time they take
    budget = ["--budget-ms", "60000"]
    assert main(["plan", "--waypoints", str(wp), "-o", str(out), "--max-jerk", text, "--json", *budget]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["max_jerk"] == pytest.approx(list(jerk))
    program = PvtProgram.loads(out.read_text())
    assert program.metadata["max_jerk"] == pytest.approx(list(jerk))
    assert not validate_program(program).errors
    # the cell file's max_jerk, without the option
    cell = arm_with_jerk(tmp_path, dict(enumerate(jerk.tolist())))
    same = tmp_path / "same.json"
    assert main(["plan", "--config", str(cell), "--waypoints", str(wp), "-o", str(same), *budget]) == 0
    capsys.readouterr()
    assert PvtProgram.loads(same.read_text()).duration_ms == program.duration_ms
    for value, says in (
        ("1,2,3", "--max-jerk has 3 values, the cell has 6 joints"),
        ("1,1,0,1,1,1", "--max-jerk[2] must be positive, got 0"),
        ("1,1,1,nan,1,1", "--max-jerk[3] must be positive, got nan"),
        ("a,b", "--max-jerk must be a list of 6 positive numbers"),
    ):
        bad = tmp_path / "bad.json"
        assert main(["plan", "--waypoints", str(wp), "-o", str(bad), "--max-jerk", value]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1, err
        assert not bad.exists()


def test_a_jerk_limited_linear_tool_move_holds_the_tcp_speeds() -> None:
    """Tool poses take the same timing after inverse kinematics: a 29 cm line under the TCP linear
    and angular speed limits and a jerk limit, every one of them held."""
    planner = Planner(LIMITS, CELL.model, "tool0", max_tcp_speed=0.3, max_tcp_angular_speed=0.5)
    q1 = np.array([0.2, 0.3, 0.4, 0.1, 0.6, 0.2])
    target = placement_pose(IkSolver(CELL.model, "tool0", LIMITS.lower, LIMITS.upper).fk(q1))
    target[:3] += (-0.25, 0.0, 0.15)
    jerk = 10.0 * LIMITS.acceleration
    topp = planner.plan(PlanInput(q1, [target], "linear"))
    out = planner.plan(PlanInput(q1, [target], "linear", max_jerk=jerk))
    assert out.ok and topp.ok and isinstance(out.trajectory, JerkTrajectory), out.message
    traj = out.trajectory
    t = traj.check_times(64)
    q, qd = traj.position(t), traj.velocity(t)
    # held at the rows and 32 samples per interval (as TOPP-RA holds them at its samples): between those, by 1e-4
    assert CELL.model.frame_speeds(q, qd, "tool0").max() <= 0.3 * (1 + 1e-3)
    assert CELL.model.frame_angular_speeds(q, qd, "tool0").max() <= 0.5 * (1 + 1e-3)
    assert np.max(np.abs(traj.jerk(t)) / jerk) <= 1.001
    assert traj.duration >= topp.trajectory.duration
    assert out.details["samples"] == len(traj.path.points) and "jerk_s" in out.details


def test_a_plan_request_with_max_jerk_through_the_service(arm6, tmp_path: Path) -> None:
    """A plan request's max_jerk reaches the planner; the program records it and is jerk-limited."""
    from svc_helpers import SHORT_TARGET, check_reply, served_cell

    jerk = (4.0 * LIMITS.acceleration).tolist()
    with served_cell(arm6, tmp_path) as s:
        plain = s.request("plan", {"target": SHORT_TARGET})
        limited = s.request("plan", {"target": SHORT_TARGET, "max_jerk": jerk, "include_program": True})
        late = s.request("plan", {"target": SHORT_TARGET, "max_jerk": jerk, "budget_ms": 0.001})
    assert plain.ok and limited.ok, limited.data
    assert plain.data["optimal"] is True and "gap" not in plain.data
    assert isinstance(limited.data["optimal"], bool)  # the cell's 200 ms budget: optimal unless the VM stalls
    assert limited.data["gap"]["lower_bound_s"] <= limited.data["gap"]["duration_s"]
    assert not late.ok and late.data["error"]["code"] == "timeout", late.data
    assert late.data["error"]["details"]["budget_ms"] == 0.001
    check_reply("plan", limited.data)
    assert limited.data["program"]["metadata"]["max_jerk"] == pytest.approx(jerk)
    assert {"topp", "jerk"} <= set(limited.data["timing_ms"])
    assert limited.data["duration_s"] > plain.data["duration_s"]


def test_the_planning_process_plans_jerk_limited_like_the_service_s_own_planner(arm6, arm6_planning) -> None:
    """A request's max_jerk crosses to the planning child (real cells plan there) and back."""
    from pvtflow.service.api import PlanRequest

    waypoints = np.array([[0.0] * 6, [0.3, -0.2, 0.3, -0.2, 0.3, -0.2]])
    jerk = 4.0 * LIMITS.acceleration
    reply = arm6_planning.plan(
        PlanRequest(waypoints, start="first", include_program=True, max_jerk=jerk, budget_ms=60000.0)
    )
    assert reply["optimal"] is True  # a budget the solve fits in: the same plan as without one
    here = CellPlanner(arm6).plan(PlanInput(waypoints, max_jerk=jerk))
    assert here.program is not None
    assert reply["program"]["metadata"]["max_jerk"] == pytest.approx(list(jerk))
    for axis, expected in zip(reply["program"]["axes"], here.program.axes, strict=True):
        assert np.array_equal(np.asarray(axis["records"]), expected.records)
