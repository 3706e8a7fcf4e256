"""Tool poses: Pinocchio IK, straight tool lines sampled into a joint path, refusals that say where."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from pvtflow.planner.cartesian import (
    MAX_JOINT_STEP,
    CartesianResult,
    LineTolerance,
    PoseSolver,
    ToolLine,
    check_poses,
    placement_pose,
    pose_placement,
)
from pvtflow.planner.ik import IkSolver, IkStatus
from pvtflow.planner.path import PlanError, PlanResult
from pvtflow.planner.plan import PlanInput, Planner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
LIMITS = ARM.joint_limits()
IK = IkSolver(ARM.model, "tool0", LIMITS.lower, LIMITS.upper)
POSES = PoseSolver(IK, LIMITS)
TOL = LineTolerance()
# a pose away from every singularity (the wrist bent, the elbow bent)
Q1 = np.array([0.2, 0.3, 0.4, 0.1, 0.6, 0.2])


def random_q(rng: np.random.Generator) -> np.ndarray:
    mid, half = 0.5 * (LIMITS.lower + LIMITS.upper), 0.5 * (LIMITS.upper - LIMITS.lower)
    return mid + 0.7 * half * rng.uniform(-1.0, 1.0, LIMITS.dof)


def moved(q: np.ndarray, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> np.ndarray:
    p = placement_pose(IK.fk(q))
    p[:3] += (dx, dy, dz)
    return p


def deviations(path_points: np.ndarray, line: ToolLine) -> np.ndarray:
    return np.array([line.deviation(IK.fk(q), TOL)[:2] for q in path_points])


def test_ik_round_trip_fk_of_the_solution_is_the_pose() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = random_q(rng)
        target = IK.fk(q)
        sol = IK.solve(target, q + rng.normal(0.0, 0.05, LIMITS.dof))
        assert sol.ok, sol
        reached = IK.fk(sol.q)
        assert np.linalg.norm(reached.translation - target.translation) < 1e-6
        assert np.linalg.norm(pin.log3(reached.rotation.T @ target.rotation)) < 1e-5
        assert np.all(sol.q >= LIMITS.lower) and np.all(sol.q <= LIMITS.upper)


def test_ik_keeps_inside_the_joint_limits_and_says_when_a_pose_needs_more() -> None:
    near = Q1.copy()
    near[0] = LIMITS.upper[0] - 0.05
    beyond = near.copy()
    beyond[0] = LIMITS.upper[0] + 0.2  # the same arm turned further than joint_1 may go
    sol = IK.solve(IK.fk(beyond), near)
    assert sol.status is IkStatus.JOINT_LIMIT and sol.joint == 0
    assert np.all(sol.q <= LIMITS.upper) and np.all(sol.q >= LIMITS.lower)


def test_a_linear_move_follows_the_line_within_the_tolerance_on_the_joint_path() -> None:
    """The joint path itself (the spline through the samples, what TOPP-RA times), sampled far
    finer than its samples, keeps the tool within 0.05 mm and 0.05 degree of the line."""
    rng = np.random.default_rng(5)
    checked = 0
    while checked < 4:
        qa, qb = random_q(rng), random_q(rng)
        try:
            tool = POSES.solve(qa, [placement_pose(IK.fk(qb))])
        except PlanError:
            continue
        checked += 1
        path = tool.path
        assert len(path.points) >= 3
        line = ToolLine(IK.fk(qa), IK.fk(qb))
        dev = deviations(path(np.linspace(0.0, path.length, 2000)), line)
        assert dev[:, 0].max() <= TOL.position * 1.001
        assert dev[:, 1].max() <= TOL.orientation * 1.001
        # it ends on the pose, the last sample solved exactly
        end = IK.fk(path.points[-1])
        assert np.linalg.norm(end.translation - IK.fk(qb).translation) < 1e-6


def test_the_samples_stay_on_one_branch_along_the_line() -> None:
    """Each sample seeded from the previous one: small joint steps, the wrist never flips (the sign
    of joint_5 kept where the line does not cross zero), and every sample is on the line."""
    qa = Q1
    tool = POSES.solve(qa, [moved(qa, dx=-0.25, dz=0.15), moved(qa, dx=-0.25, dy=0.2, dz=0.15)])
    q = tool.path.points
    assert np.max(np.abs(np.diff(q, axis=0))) <= MAX_JOINT_STEP
    assert np.all(q[:, 4] > 0.0)
    lines = {0: ToolLine(IK.fk(qa), pose_placement(moved(qa, dx=-0.25, dz=0.15)))}
    lines[1] = ToolLine(lines[0].b, pose_placement(moved(qa, dx=-0.25, dy=0.2, dz=0.15)))
    for k in range(1, len(q)):
        dp, dr, u = lines[int(tool.pose_of[k])].deviation(IK.fk(q[k]), TOL)
        assert dp < 1e-5 and dr < 1e-4
        assert u == pytest.approx(tool.fraction[k], abs=1e-4)
    assert list(tool.pose_of[[0, -1]]) == [-1, 1]
    # the last pose has other solutions (other branches, found from far seeds): the line ends on the
    # one it started on, not on whichever a solver would find first
    end = pose_placement(moved(qa, dx=-0.25, dy=0.2, dz=0.15))
    others = [sol.q for sol in (IK.solve(end, seed) for seed in POSES._restart_seeds()) if sol.ok]
    assert any(np.max(np.abs(o - q[-1])) > 1.0 for o in others)


def test_an_unreachable_pose_is_refused_with_its_index() -> None:
    far = moved(Q1)
    far[:3] = (3.0, 0.0, 0.5)
    for motion in ("linear", "joint"):
        with pytest.raises(PlanError) as err:
            POSES.solve(Q1, [moved(Q1, dz=0.05), far], motion)
        assert err.value.result is CartesianResult.UNREACHABLE
        assert err.value.details["pose"] == 1
        assert "pose 1" in err.value.message


def test_a_line_past_a_joint_limit_is_refused_where_it_happens() -> None:
    """Around the back of the robot: joint_1 would have to turn past its limit on the way."""
    qa = np.array([2.6, 0.3, 0.4, 0.1, 0.6, 0.2])
    qb = qa.copy()
    qb[0] = -2.6
    with pytest.raises(PlanError) as err:
        POSES.solve(qa, [placement_pose(IK.fk(qb))])
    assert err.value.result is CartesianResult.JOINT_LIMIT
    assert err.value.details["pose"] == 0 and err.value.details["joint"] == "joint_1"
    assert 0.05 < err.value.details["fraction"] < 0.95
    assert "% of the way" in err.value.message


def test_a_line_through_a_singularity_is_refused_where_it_happens() -> None:
    qa = np.array([-1.782, 0.244, 1.613, -0.168, 0.747, -1.683])
    qb = np.array([1.509, 0.217, 1.295, 1.2, 1.023, -1.85])
    with pytest.raises(PlanError) as err:
        POSES.solve(qa, [placement_pose(IK.fk(qb))])
    assert err.value.result is CartesianResult.SINGULAR
    assert err.value.details["pose"] == 0 and 0.2 < err.value.details["fraction"] < 0.8
    # the same two poses as a joint move: no line, no singularity on the way
    assert len(POSES.solve(qa, [placement_pose(IK.fk(qb))], "joint").path.points) == 2


@pytest.mark.parametrize(
    ("poses", "words"),
    [
        ([[0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 0.9]], "norm 0.9"),
        ([[0.5, 0.0, 0.3, 0.0, 0.0, 1.0]], "7 numbers"),
        ([[0.5, 0.0, math.nan, 0.0, 0.0, 0.0, 1.0]], "not a finite number"),
        ([], "at least one pose"),
    ],
)
def test_bad_poses_are_refused_with_what_is_wrong(poses: list, words: str) -> None:
    with pytest.raises(PlanError) as err:
        check_poses(poses)
    assert err.value.result is PlanResult.INVALID_INPUT
    assert words in err.value.message


def test_a_nearly_unit_quaternion_is_normalized() -> None:
    p = check_poses([[0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0004]])
    assert np.linalg.norm(p[0, 3:]) == pytest.approx(1.0)


def test_planned_linear_move_holds_the_tcp_speeds() -> None:
    """TOPP-RA along the joint path of a line, with the TCP linear and angular speed limits."""
    planner = Planner(LIMITS, ARM.model, "tool0", max_tcp_speed=0.3, max_tcp_angular_speed=0.5)
    out = planner.plan(PlanInput(Q1, [moved(Q1, dx=-0.25, dz=0.15)], "linear"))
    assert out.ok, out.message
    traj = out.trajectory
    assert traj is not None and out.details["samples"] == len(traj.path.points)
    t = np.linspace(0.0, traj.duration, 2000)
    q, qd = traj.position(t), traj.velocity(t)
    v = ARM.model.frame_speeds(q, qd, "tool0")
    w = ARM.model.frame_angular_speeds(q, qd, "tool0")
    assert v.max() <= 0.3 * 1.01 and v.max() >= 0.3 * 0.9  # the linear limit binds on a 29 cm line
    assert w.max() <= 0.5 * 1.01


def test_angular_speed_matches_the_frame_jacobian() -> None:
    rng = np.random.default_rng(2)
    q, qd = rng.uniform(-1, 1, (5, 6)), rng.uniform(-1, 1, (5, 6))
    w = ARM.model.frame_angular_speeds(q, qd, "tool0")
    ref = [np.linalg.norm((ARM.model.frame_jacobian(a, "tool0") @ b)[3:]) for a, b in zip(q, qd, strict=True)]
    np.testing.assert_allclose(w, ref, atol=1e-12)


def test_plan_poses_refuses_without_a_tool_frame_and_an_unknown_motion() -> None:
    assert Planner(LIMITS).plan(PlanInput(Q1, [moved(Q1, dz=0.05)])).result is PlanResult.INVALID_INPUT
    out = Planner(LIMITS, ARM.model, "tool0").plan(PlanInput(Q1, [moved(Q1, dz=0.05)], "circular"))
    assert out.result is PlanResult.INVALID_INPUT and "circular" in out.message


def test_the_tool_already_at_the_pose_is_nothing_to_move() -> None:
    out = Planner(LIMITS, ARM.model, "tool0").plan(PlanInput(Q1, [placement_pose(IK.fk(Q1))]))
    assert out.result is PlanResult.REPEATED_WAYPOINT


def test_the_cell_validates_the_angular_speed_limit(tmp_path) -> None:
    from pvtflow.service.config import ConfigError

    text = (CONFIG_DIR / "cells" / "arm6.yaml").read_text()
    text = text.replace("urdf: ../robots/arm6.urdf", f"urdf: {CONFIG_DIR / 'robots' / 'arm6.urdf'}")
    good = tmp_path / "good.yaml"
    good.write_text(text.replace("  max_tcp_speed: 2.0", "  max_tcp_speed: 2.0\n  max_tcp_angular_speed: 3.0"))
    assert load_cell_config(good).planning.max_tcp_angular_speed == 3.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("  max_tcp_speed: 2.0", "  max_tcp_speed: 2.0\n  max_tcp_angular_speed: -1"))
    with pytest.raises(ConfigError) as err:
        load_cell_config(bad)
    assert "planning.max_tcp_angular_speed: must be positive" in str(err.value)


def test_corners_between_lines_stay_within_the_tolerance_on_the_joint_path() -> None:
    """Three lines meeting at corners: the spline through the samples rounds each corner, and
    samples are added there until it keeps within the tolerance of the lines."""
    p1 = moved(Q1, dx=-0.2, dz=0.1)
    p2 = p1.copy()
    p2[1] += 0.15
    p3 = p2.copy()
    p3[0] += 0.1
    tool = POSES.solve(Q1, [p1, p2, p3])
    lines = [ToolLine(IK.fk(Q1), pose_placement(p1)), ToolLine(pose_placement(p1), pose_placement(p2))]
    lines.append(ToolLine(pose_placement(p2), pose_placement(p3)))
    path = tool.path
    worst = np.zeros(2)
    for q in path(np.linspace(0.0, path.length, 6000)):
        placement = IK.fk(q)
        worst = np.maximum(worst, min((line.deviation(placement, TOL)[:2] for line in lines), key=lambda d: d[0]))
    assert worst[0] <= TOL.position and worst[1] <= TOL.orientation
    # each pose is a sample: the path goes through the corners exactly
    ends = [k for k in range(1, len(tool.pose_of) - 1) if tool.pose_of[k] != tool.pose_of[k + 1]]
    assert [int(tool.pose_of[k]) for k in ends] == [0, 1]
    assert all(tool.fraction[k] == 1.0 for k in ends)
