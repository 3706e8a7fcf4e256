"""A ROS JointTrajectory's time_from_start is not used (pvtflow times the motion): said out loud by
``pvtflow plan`` and ``pvtflow request plan``, never dropped without a word (service/waypoints.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from pvtflow.service.cli import main
from pvtflow.service.waypoints import ros_time_from_start

NAMES = [f"joint_{i}" for i in range(1, 7)]
A, B = [0.1, 0.0, 0.1, 0.0, 0.1, 0.0], [0.2, -0.1, 0.2, -0.1, 0.2, -0.1]


def ros1(tmp_path: Path) -> Path:
    path = tmp_path / "ros1.yaml"
    points = [
        {"positions": A, "time_from_start": {"secs": 1, "nsecs": 0}},
        {"positions": B, "time_from_start": {"secs": 2, "nsecs": 500000000}},
    ]
    path.write_text(yaml.safe_dump({"joint_trajectory": {"joint_names": NAMES, "points": points}}))
    return path


def ros2(tmp_path: Path, times: bool = True) -> Path:
    path = tmp_path / "ros2.json"
    points = [{"positions": A}, {"positions": B}]
    if times:
        points[0]["time_from_start"] = {"sec": 0, "nanosec": 0}
        points[1]["time_from_start"] = {"sec": 2, "nanosec": 0}
    path.write_text(json.dumps({"joint_names": NAMES, "points": points}))
    return path


def test_the_times_are_read_in_both_ros_forms(tmp_path: Path) -> None:
    assert ros_time_from_start(ros1(tmp_path)) == pytest.approx(2.5)
    assert ros_time_from_start(ros2(tmp_path)) == pytest.approx(2.0)
    assert ros_time_from_start(ros2(tmp_path, times=False)) is None


def test_plan_warns_that_the_times_are_not_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", "--waypoints", str(ros1(tmp_path)), "-o", str(tmp_path / "p.json")]) == 0
    err = capsys.readouterr().err
    assert "time_from_start (the last 2.5 s) are not used: pvtflow times the motion itself" in err, err
    assert " s here)" in err and "--velocity-scale" in err
    assert main(["plan", "--waypoints", str(ros2(tmp_path, times=False)), "-o", str(tmp_path / "q.json")]) == 0
    assert "time_from_start" not in capsys.readouterr().err


def test_request_plan_warns_too(serve, arm6, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    served = serve(arm6)
    assert main(["request", "plan", "--waypoints", str(ros2(tmp_path)), "--connect", served.endpoint]) == 0
    err = capsys.readouterr().err
    assert "time_from_start (the last 2 s) are not used" in err, err
