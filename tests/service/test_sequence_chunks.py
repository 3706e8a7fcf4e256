"""Exact stops in a motion sequence (blend_radius 0) are true rest-to-rest stops: the sequence is planned in
chunks cut after each, joined into one program (issue 38, service/sequence_chunks.py)."""

from __future__ import annotations

import copy
import itertools

import numpy as np
import pytest
import yaml

from pvtflow.planner.path import PlanResult
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlan, CellPlanner
from pvtflow.service.config import CONFIG_DIR, load_cell_config
from pvtflow.service.sequence_chunks import _renumbered, chunks

ARM = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
EXAMPLE = yaml.safe_load((CONFIG_DIR / "sequences" / "arm6-pick-and-place.yaml").read_text())


@pytest.fixture(scope="module")
def planner() -> CellPlanner:
    return CellPlanner(ARM)


def test_a_sequence_is_cut_after_every_exact_stop_but_the_last_item() -> None:
    items = [{"blend_radius": 0.02}, {}, {"blend_radius": 0.0}, {"blend_radius": 0.01}, {"blend_radius": 0}]
    assert [(first, len(chunk)) for first, chunk in chunks(items)] == [(0, 2), (2, 1), (3, 2)]
    assert chunks([{"blend_radius": "x"}, {}]) == [(0, [{"blend_radius": "x"}, {}])]  # the check refuses it


def test_an_all_exact_stop_sequence_is_no_slower_than_its_items_as_separate_motions(planner) -> None:
    """Every radius 0: the program lasts exactly what the items planned one by one last together, the axes
    at rest at every goal, one validated program whose items' spans follow each other to its end."""
    start = np.array(EXAMPLE["start"], dtype=float)
    items = copy.deepcopy(EXAMPLE["sequence"])
    for item in items:
        item["blend_radius"] = 0.0
    whole = planner.plan(PlanInput(start, sequence=items))
    assert whole.ok, whole.message
    program = whole.program
    assert validate_program(program).ok
    separate, here, ends = 0, start, []
    for item in items:
        alone = planner.plan(PlanInput(here, sequence=[item]))
        assert alone.ok, alone.message
        separate += alone.program.duration_ms
        ends.append(separate)
        here = alone.waypoints[-1]
    assert program.duration_ms == separate
    spans = program.metadata["items"]
    assert [s["index"] for s in spans] == list(range(len(items)))
    assert all(a["end_s"] == b["start_s"] for a, b in itertools.pairwise(spans))
    assert spans[-1]["end_s"] == pytest.approx(program.duration_ms / 1000.0)
    for axis in program.axes:  # at rest at every goal: where one item's program ends
        velocity = axis.reconstruction().velocity(np.array(ends, dtype=float))
        np.testing.assert_allclose(velocity, 0.0, atol=1e-9)


def test_the_shipped_pick_and_place_runs_in_chunks_faster_than_as_one_path(planner) -> None:
    """Its two LIN downs stop (the gripper acts there): three chunks, and with the stops at rest the cycle is
    shorter than the one path through the stops was (2.017 s for the second cycle of two, bench/RESULTS.md)."""
    start = np.array(EXAMPLE["start"], dtype=float)
    out = planner.plan(PlanInput(start, sequence=EXAMPLE["sequence"]))
    assert out.ok, out.message
    summary = out.program.metadata["chunks"]
    assert [c["items"] for c in summary] == [[0, 1], [2, 4], [5, 5]]
    assert sum(c["duration_ms"] for c in summary) == out.program.duration_ms
    single = planner.planner.plan(PlanInput(start, sequence=EXAMPLE["sequence"]))  # as one path, untimed knots
    assert out.program.duration_ms < 1000.0 * single.trajectory.duration


def test_a_chunks_refusal_names_the_item_by_its_index_in_the_sequence() -> None:
    refused = CellPlan("unreachable", "sequence item 1: the pose is out of reach", details={"item": 1, "items": [1, 2]})
    renumbered = _renumbered(refused, 4)
    assert renumbered.message == "sequence item 5: the pose is out of reach"
    assert renumbered.details == {"item": 5, "items": [5, 6]}


def test_a_bad_item_after_an_exact_stop_refuses_the_sequence_naming_it(planner) -> None:
    start = np.array(EXAMPLE["start"], dtype=float)
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[4]["pose"] = [3.0, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0]  # 3 m away: out of reach
    out = planner.plan(PlanInput(start, sequence=items))
    assert not out.ok and out.code == "unreachable"
    assert out.details["item"] == 4 and "item 4" in out.message
    items = copy.deepcopy(EXAMPLE["sequence"])
    items[3]["motion"] = "circ"
    out = planner.plan(PlanInput(start, sequence=items))
    assert out.code == PlanResult.INVALID_INPUT.value and out.details["item"] == 3
