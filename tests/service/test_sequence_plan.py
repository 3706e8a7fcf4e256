"""The sequence plan request and ``pvtflow plan --sequence`` (issue 38)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from svc_helpers import wait_until

from pvtflow.service.api import ApiError
from pvtflow.service.api.requests import parse_plan
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR

ARM6 = CONFIG_DIR / "cells" / "arm6.yaml"
NAMES = [f"joint_{i}" for i in range(1, 7)]
EXAMPLE = CONFIG_DIR / "sequences" / "arm6-pick-and-place.yaml"


def test_a_sequence_request_is_parsed_with_its_targets_in_the_cells_joint_order() -> None:
    req = parse_plan(
        {
            "sequence": [
                {"motion": "ptp", "target": [6, 5, 4, 3, 2, 1], "blend_radius": 0.01, "label": "a"},
                {"motion": "lin", "pose": [0.5, 0, 0.3, 0, 0, 0, 1]},
            ],
            "start": [0.0] * 6,
            "joint_names": list(reversed(NAMES)),
        },
        NAMES,
    )
    assert req.sequence is not None and req.sequence[0]["target"] == [1, 2, 3, 4, 5, 6]
    inp = req.plan_input(np.zeros(6))
    assert inp.sequence == req.sequence and inp.poses is None


@pytest.mark.parametrize(
    ("sequence", "path"),
    [
        ([{"motion": "arc", "pose": [0, 0, 0, 0, 0, 0, 1]}], "$.sequence[0].motion"),
        ([{"motion": "lin", "pose": [1, 2]}], "$.sequence[0].pose"),
        ([{"motion": "lin", "pose": [0, 0, 0, 0, 0, 0, 1], "blend_radius": -1}], "$.sequence[0].blend_radius"),
        ([{"motion": "ptp", "target": [1, 2]}], "$.sequence[0].target"),
    ],
)
def test_a_bad_sequence_request_is_refused_naming_the_field(sequence: list, path: str) -> None:
    with pytest.raises(ApiError) as exc:
        parse_plan({"sequence": sequence}, NAMES)
    assert exc.value.details.get("path") == path


def test_pvtflow_plan_sequence_plans_the_shipped_pick_and_place(tmp_path: Path, capsys) -> None:
    out = tmp_path / "cycle.json"
    assert main(["plan", "--config", str(ARM6), "--sequence", str(EXAMPLE), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [i["label"] for i in summary["items"]][:2] == ["above pick", "pick"]
    program = json.loads(out.read_text())
    assert program["metadata"]["motion"] == "sequence" and len(program["metadata"]["items"]) == 6


def test_pvtflow_plan_sequence_refuses_overlapping_blends_naming_both_items(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(EXAMPLE.read_text().replace("blend_radius: 0.0, label: pick", "blend_radius: 0.11, label: pick"))
    assert main(["plan", "--config", str(ARM6), "--sequence", str(bad), "-o", str(tmp_path / "x.json")]) == 1
    err = capsys.readouterr().err
    assert "items 0 and 1" in err and "Traceback" not in err
    assert not (tmp_path / "x.json").exists()


@pytest.mark.wall
def test_a_sequence_request_plans_and_runs_on_the_served_arm(arm6, serve) -> None:  # type: ignore[no-untyped-def]
    """Over zenoh: the shipped pick and place, planned from where the axes stand, runs to its end on the
    simulated drives (their own checks of every record included) as one motion, and the events say
    which item runs, each item once and in order, with its label (issue 38 item 6)."""
    items = yaml.safe_load(EXAMPLE.read_text())["sequence"]
    s = serve(arm6)
    col = s.follow()
    plan = s.request("plan", {"sequence": items, "start": "current"})
    assert plan.ok, plan.data
    done = s.request("execute", {"plan_id": plan.data["plan_id"], "wait": True}, timeout=120)
    assert done.ok, done.data
    assert done.data["outcome"]["result"] == "finished", done.data
    for drive in s.sim:
        assert drive.faults == []
    motion_id = done.data["motion_id"]
    assert wait_until(lambda: bool(col.events("motion_ended", motion_id)), timeout=30)
    started = [e["item"] for e in col.events("item_started", motion_id)]
    assert started == [{"index": i, "label": item.get("label")} for i, item in enumerate(items)]


def test_the_item_running_follows_the_programs_time_scale() -> None:
    """``Motion.item_at``: the items' spans are on the trajectory's timeline; the program runs them
    slowed by its time scale, so a moment just past an item's end on the trajectory is still that
    item in the program when the program is slower."""
    from pvtflow.axes.drive.program import PvtProgram
    from pvtflow.service.motion.runs import Motion

    items = [
        {"index": 0, "label": "a", "start_s": 0.0, "end_s": 1.0},
        {"index": 1, "label": None, "start_s": 1.0, "end_s": 2.0},
    ]
    motion = Motion("m-1", None, None, PvtProgram(cell="c", axes=(), metadata={"items": items, "time_scale": 1.1}), 0.0)
    assert motion.item_at(None) is None and motion.item_at(-1.0) is None
    assert motion.item_at(0.0) == {"index": 0, "label": "a"}
    assert motion.item_at(1050.0) == {"index": 0, "label": "a"}  # 1050 ms of program: 0.955 s of trajectory
    assert motion.item_at(1150.0) == {"index": 1, "label": None}
    assert motion.item_at(9999.0) == {"index": 1, "label": None}
    plain = Motion("m-2", None, None, PvtProgram(cell="c", axes=(), metadata={}), 0.0)
    assert plain.item_at(500.0) is None
