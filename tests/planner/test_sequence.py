"""Motion sequences (issue 38): PTP, LIN and CIRC items blended into one program, measured on the
drives' own reconstruction (every ms of the program, the tool by forward kinematics)."""

from __future__ import annotations

import copy
import itertools

import numpy as np
import pytest
import yaml

from pvtflow.planner.cartesian import placement_pose
from pvtflow.planner.path import PlanResult
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
EXAMPLE = yaml.safe_load((CONFIG_DIR / "sequences" / "arm6-pick-and-place.yaml").read_text())
# the items' paths outside the blend spheres, on the drives' reconstruction
PATH_TOLERANCE = 1e-4  # m


@pytest.fixture(scope="module")
def planner() -> CellPlanner:
    return CellPlanner(ARM)


def with_radius(r: float) -> list[dict]:
    items = copy.deepcopy(EXAMPLE["sequence"])
    for item in items:
        if item.get("blend_radius", 0.0) > 0.0:
            item["blend_radius"] = r
    return items


def reconstructed_joints(program) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The joint positions every ms of the drives' reconstruction (M, dof)."""
    t = np.arange(0, program.duration_ms + 1, dtype=float)
    cols = []
    for axis in program.axes:
        qc = axis.reconstruction().position(t)
        cols.append(axis.scaling.qc_to_position(qc))
    return np.column_stack(cols)


def test_the_shipped_pick_and_place_blends_and_keeps_the_tool_on_the_paths_outside_the_spheres(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    result = planner.plan(PlanInput(start, sequence=EXAMPLE["sequence"]))
    assert result.ok, result.message
    program = result.program
    assert validate_program(program, sample_period_ms=None).ok  # every drive limit, blends included
    items = program.metadata["items"]
    assert [i["label"] for i in items] == [i.get("label") for i in EXAMPLE["sequence"]]
    assert all(a["end_s"] == pytest.approx(b["start_s"]) for a, b in itertools.pairwise(items))
    assert all(i["end_s"] > i["start_s"] for i in items)
    solver = planner.planner.sequences
    solved = solver.solve(start, EXAMPLE["sequence"])
    qs = reconstructed_joints(program)
    dp, dr, outside = solver.deviations(solved, qs)
    assert outside.sum() > 0.5 * len(qs) and (~outside).sum() > 10  # the blends are passed through
    assert float(dp[outside].max()) <= PATH_TOLERANCE
    assert float(dr[outside].max()) <= np.radians(0.1)
    # the TCP speed limit holds on the reconstruction, inside the blends too
    tool = np.array([solver.ik.fk(q).translation for q in qs])
    speed = np.linalg.norm(np.diff(tool, axis=0), axis=1) / 1e-3
    assert float(speed.max()) <= ARM.planning.max_tcp_speed * 1.01


def test_blending_shortens_the_cycle_and_the_tool_never_stops_inside_a_blend(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    durations = {}
    for r in (0.0, 0.05):
        out = planner.planner.plan(PlanInput(start, sequence=with_radius(r)))
        assert out.ok, out.message
        durations[r] = out.trajectory.duration
        if r > 0.0:
            # at each blended item's end (the middle of its blend) the path speed is far from zero
            ends = [
                i["end_s"]
                for i, item in zip(out.details["items"], with_radius(r), strict=True)
                if item.get("blend_radius", 0.0) > 0.0
            ]
            qd = out.trajectory.velocity(np.array(ends))
            assert np.all(np.linalg.norm(qd, axis=1) > 0.2)
    assert durations[0.05] < durations[0.0] - 0.05


def test_a_circ_item_keeps_the_tool_on_its_arc_and_its_orientation_on_the_slerp(planner) -> None:
    q0 = np.array([0.5, -0.4, 0.9, 0.3, 0.8, 0.0])
    ik = planner.planner.poses.ik
    here = placement_pose(ik.fk(q0))
    goal, via = here.copy(), here[:3].copy()
    goal[:3] += (0.0, -0.16, 0.0)
    via += (0.0, -0.08, 0.08)  # a half circle of 0.08 m radius in the y-z plane
    goal[3:] = placement_pose(ik.fk(q0 + np.array([0, 0, 0, 0, 0, 0.4])))[3:]  # the tool turns meanwhile
    items = [
        {"motion": "circ", "pose": goal.tolist(), "via": via.tolist(), "label": "arc"},
        {"motion": "lin", "pose": here.tolist()},
    ]
    result = planner.plan(PlanInput(q0, sequence=items))
    assert result.ok, result.message
    assert validate_program(result.program, sample_period_ms=None).ok
    solver = planner.planner.sequences
    solved = solver.solve(q0, items)
    arc = solved.paths[0]
    assert arc.radius == pytest.approx(0.08, abs=1e-6)
    qs = reconstructed_joints(result.program)
    t_end = result.program.metadata["items"][0]["end_s"] * 1000.0
    on_arc = qs[: int(t_end * 0.98)]
    tol = solver.poses.tolerance
    dev = np.array([arc.deviation(ik.fk(q), tol)[:2] for q in on_arc])
    assert float(dev[:, 0].max()) <= PATH_TOLERANCE
    assert float(dev[:, 1].max()) <= np.radians(0.1)
    tool = np.array([ik.fk(q).translation for q in qs])
    assert float((np.linalg.norm(np.diff(tool, axis=0), axis=1) / 1e-3).max()) <= ARM.planning.max_tcp_speed * 1.01


def test_overlapping_blend_spheres_are_refused_naming_both_items(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[2]["blend_radius"] = 0.07  # retreat (0.12 m long) blending with the ptp's 0.02: ok by sum...
    out = planner.planner.plan(PlanInput(start, sequence=items))
    assert out.result is PlanResult.INVALID_INPUT  # ... but more than half of its own 0.12 m
    assert out.details["items"] == [2, 3] and "half" in out.message
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[0]["blend_radius"], items[1]["blend_radius"] = 0.04, 0.0
    items[3]["blend_radius"], items[4]["blend_radius"] = 0.055, 0.07  # 0.125 m > the 0.12 m down between them
    out = planner.planner.plan(PlanInput(start, sequence=items))
    assert out.result is PlanResult.INVALID_INPUT
    assert out.details["items"] == [3, 4] and "exceed" in out.message and "never shrunk" in out.message


def test_an_item_that_cannot_be_planned_refuses_the_whole_sequence_with_its_index(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[4]["pose"] = [3.0, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0]  # 3 m away: out of reach
    items[4]["blend_radius"] = 0.0
    out = planner.planner.plan(PlanInput(start, sequence=items))
    assert out.result.value == "unreachable"
    assert out.details["item"] == 4 and "item 4" in out.message
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[1]["motion"] = "circ"
    out = planner.planner.plan(PlanInput(start, sequence=items))
    assert out.result is PlanResult.INVALID_INPUT and out.details["item"] == 1 and out.details["field"] == "via"


def test_a_jerk_limited_sequence_holds_its_limits(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    result = planner.plan(
        PlanInput(start, sequence=EXAMPLE["sequence"], max_jerk=20.0 * ARM.joint_limits().acceleration)
    )
    assert result.ok, result.message
    assert result.program.metadata.get("max_jerk") is not None
    assert validate_program(result.program, sample_period_ms=None).ok


def test_a_circ_about_a_center_and_a_blend_between_a_line_and_an_arc(planner) -> None:
    q0 = np.array([0.5, -0.4, 0.9, 0.3, 0.8, 0.0])
    ik = planner.planner.poses.ik
    here = placement_pose(ik.fk(q0))
    corner = here.copy()
    corner[:3] += (0.0, -0.1, 0.0)
    end = corner.copy()
    end[:3] += (0.0, -0.06, 0.06)  # a quarter circle about corner + (0, 0, 0.06)
    center = (corner[:3] + np.array([0.0, 0.0, 0.06])).tolist()
    items = [
        {"motion": "lin", "pose": corner.tolist(), "blend_radius": 0.02},
        {"motion": "circ", "pose": end.tolist(), "center": center},
    ]
    result = planner.plan(PlanInput(q0, sequence=items))
    assert result.ok, result.message
    assert validate_program(result.program, sample_period_ms=None).ok
    solver = planner.planner.sequences
    solved = solver.solve(q0, items)
    assert solved.paths[1].radius == pytest.approx(0.06, abs=1e-9)
    dp, _, outside = solver.deviations(solved, reconstructed_joints(result.program))
    assert (~outside).sum() > 5 and float(dp[outside].max()) <= PATH_TOLERANCE
    off = copy.deepcopy(items)
    off[1]["center"] = np.add(center, (0.0, 0.0, 0.01)).tolist()  # not equidistant from both ends
    out = planner.planner.plan(PlanInput(q0, sequence=off))
    assert out.result is PlanResult.INVALID_INPUT and out.details["item"] == 1 and out.details["field"] == "center"
