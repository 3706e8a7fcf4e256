"""Tool poses through the service: request parsing, pose files for the CLI, a linear move end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from svc_helpers import check_reply, wait_until

from pvtflow.planner.cartesian import LineTolerance, ToolLine, placement_pose, pose_placement
from pvtflow.planner.ik import IkSolver
from pvtflow.planner.plan import PlanInput
from pvtflow.service.api import ApiError, parse_plan
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
NAMES = ARM.joint_names
LIMITS = ARM.joint_limits()
IK = IkSolver(ARM.model, "tool0", LIMITS.lower, LIMITS.upper)
Q1 = [0.2, 0.3, 0.4, 0.1, 0.6, 0.2]


def pose_near(q: list[float], dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> list[float]:
    p = placement_pose(IK.fk(np.array(q)))
    p[:3] += (dx, dy, dz)
    return [float(x) for x in p]


POSE = pose_near(Q1, dx=-0.2, dz=0.1)


def refusal(data: object) -> ApiError:
    with pytest.raises(ApiError) as err:
        parse_plan(data, NAMES, LIMITS)
    return err.value


def test_a_pose_request_is_parsed_with_its_motion_and_start() -> None:
    req = parse_plan({"poses": [POSE], "motion": "joint", "start": Q1}, NAMES, LIMITS)
    assert req.poses is not None and req.poses.shape == (1, 7)
    assert req.motion == "joint" and req.start == "joints"
    np.testing.assert_allclose(req.start_joints, Q1)
    current = parse_plan({"poses": [POSE]}, NAMES, LIMITS)
    assert current.start == "current" and current.start_joints is None and current.motion == "linear"
    # joint_names orders the start's values
    named = parse_plan({"poses": [POSE], "start": Q1[::-1], "joint_names": list(NAMES[::-1])}, NAMES, LIMITS)
    np.testing.assert_allclose(named.start_joints, Q1)


@pytest.mark.parametrize(
    ("change", "code", "words"),
    [
        ({"poses": [[*POSE[:3], 0.0, 0.0, 0.0, 0.5]]}, "invalid_request", "norm 0.5"),
        ({"poses": [POSE[:6]]}, "invalid_request", "$.poses[0] has 6 values"),
        ({"poses": [[*POSE[:2], math.nan, *POSE[3:]]]}, "not_finite", "$.poses[0][2]"),
        ({"waypoints": [Q1]}, "invalid_request", "exactly one of"),
        ({"motion": "circular"}, "invalid_request", "$.motion"),
        ({"start": "first"}, "invalid_request", "first is for waypoints"),
        ({"start": Q1[:5]}, "wrong_joint_count", "$.start has 5 values"),
        ({"start": [*Q1[:5], 9.0]}, "out_of_limits", "$.start"),
        ({"poses": []}, "invalid_request", "$.poses"),
    ],
)
def test_bad_pose_requests_are_refused_saying_which_field(change: dict, code: str, words: str) -> None:
    data = {"poses": [POSE], **change}
    if code == "not_finite":  # NaN is refused where the payload is read, before the schema
        from pvtflow.service.api import parse_payload

        with pytest.raises(ApiError) as err:
            parse_payload(json.dumps(data).encode())
        exc = err.value
    else:
        exc = refusal(data)
    assert exc.code.value == code, exc.message
    assert words in exc.message


def test_motion_and_a_joint_start_are_for_poses_only() -> None:
    assert "motion is for poses" in refusal({"waypoints": [Q1], "motion": "linear"}).message
    assert "start is for poses" in refusal({"waypoints": [Q1], "start": Q1}).message


def test_pvtflow_plan_writes_a_program_from_a_pose_file(tmp_path, capsys) -> None:
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"poses": [POSE, pose_near(Q1, dx=-0.2, dy=0.1, dz=0.1)], "start": Q1}))
    out = tmp_path / "prog.json"
    assert main(["plan", "--waypoints", str(poses), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["motion"] == "linear" and summary["joint_samples"] > 3
    program = json.loads(out.read_text())
    assert program["metadata"]["motion"] == "linear"
    assert main(["validate", str(out)]) == 0
    # offline, the start must be given; a bad quaternion is named with its pose
    poses.write_text(json.dumps({"poses": [POSE]}))
    assert main(["plan", "--waypoints", str(poses), "-o", str(out)]) == 2
    assert "start" in capsys.readouterr().err
    poses.write_text(json.dumps({"poses": [POSE, [*POSE[:3], 0, 0, 0, 2.0]], "start": Q1}))
    assert main(["plan", "--waypoints", str(poses), "-o", str(out)]) == 2
    assert "pose 1" in capsys.readouterr().err
    # a pose out of reach: not planned (exit 1), the pose named
    poses.write_text(json.dumps({"poses": [POSE, [3.0, 0.0, 0.5, *POSE[3:]]], "start": Q1}))
    assert main(["plan", "--waypoints", str(poses), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "(unreachable)" in err and "pose 1" in err


@pytest.mark.wall
def test_a_linear_move_runs_on_the_simulated_arm_and_ends_on_the_pose(arm6, serve) -> None:
    """Over zenoh: move off the wrist singularity of the home position (a joint move), then a
    linear move from where the axes are through two poses; the drives end on the last pose."""
    s = serve(arm6)
    col = s.follow()
    first = s.request("plan", {"target": Q1})
    assert first.ok, first.data
    done = s.request("execute", {"plan_id": first.data["plan_id"], "wait": True}, timeout=60)
    assert done.ok, done.data

    last = pose_near(Q1, dx=-0.2, dy=0.1, dz=0.1)
    plan = s.request("plan", {"poses": [POSE, last], "motion": "linear"})
    assert plan.ok, plan.data
    check_reply("plan", plan.data)
    p = plan.data
    np.testing.assert_allclose(p["start"], Q1, atol=1e-3)  # from where the axes are
    assert p["waypoints"] > 3 and p["timing_ms"]["ik"] > 0
    end = IK.fk(np.array(p["end"]))
    assert np.linalg.norm(end.translation - np.array(last[:3])) < 1e-5

    ex = s.request("execute", {"plan_id": p["plan_id"], "wait": True}, timeout=60)
    assert ex.ok, ex.data
    assert wait_until(lambda: bool(col.events("motion_ended", ex.data["motion_id"])), timeout=30)
    for drive in s.sim:
        assert drive.faults == []
    q_end = s.service.current_joint_positions()
    reached = IK.fk(q_end)
    line = ToolLine(pose_placement(POSE), pose_placement(last))
    dp, dr, u = line.deviation(reached, LineTolerance())
    assert u == pytest.approx(1.0, abs=1e-3) and dp < 2e-4 and dr < 1e-3  # a count of each axis away at most

    # an unreachable pose: refused, nothing runs
    far = s.request("plan", {"poses": [[3.0, 0.0, 0.5, *POSE[3:]]]})
    assert not far.ok and far.error_code == "plan_failed"
    assert far.data["error"]["details"]["result"] == "unreachable" and far.data["error"]["details"]["pose"] == 0


def test_the_planning_process_plans_poses_like_the_service_s_own_planner(arm6, arm6_planning) -> None:
    from pvtflow.service.api import PlanRequest
    from pvtflow.service.cell_planner import CellPlanner

    req = parse_plan({"poses": [POSE], "start": Q1, "include_program": True}, NAMES, LIMITS)
    assert isinstance(req, PlanRequest)
    reply = arm6_planning.plan(req)
    here = CellPlanner(arm6).plan(PlanInput(np.array(Q1), [POSE], "linear"))
    assert here.program is not None and here.waypoints is not None
    assert reply["waypoints"] == len(here.waypoints)
    for axis, expected in zip(reply["program"]["axes"], here.program.axes, strict=True):
        assert np.array_equal(np.asarray(axis["records"]), expected.records)


def test_pvtflow_request_plan_sends_a_pose_file_as_a_poses_request(arm6, serve, tmp_path, capsys) -> None:
    s = serve(arm6)
    file = tmp_path / "poses.json"
    file.write_text(json.dumps({"poses": [POSE], "motion": "joint", "start": Q1}))
    assert main(["request", "plan", "--connect", s.endpoint, "--waypoints", str(file)]) == 0
    reply = json.loads(capsys.readouterr().out)
    check_reply("plan", reply)
    np.testing.assert_allclose(reply["start"], Q1)
    end = IK.fk(np.array(reply["end"]))
    assert np.linalg.norm(end.translation - np.array(POSE[:3])) < 1e-5
    # --start belongs to waypoints: refused before anything is sent
    assert main(["request", "plan", "--connect", s.endpoint, "--waypoints", str(file), "--start", "first"]) == 2
    assert "pose file" in capsys.readouterr().err
