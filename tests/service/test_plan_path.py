"""The plan request path: the plain-Python schema fast path, the cell planner built once, the timing
a plan reply carries (what bench/service_latency.py splits the latency with)."""

from __future__ import annotations

import copy
import itertools
from typing import Any

import numpy as np
import pytest
from svc_helpers import SHORT_TARGET

from pvtflow.planner.plan import PlanInput
from pvtflow.service.api import (
    MAX_TEXT,
    MAX_WAYPOINTS,
    ApiError,
    parse_payload,
    parse_plan,
)
from pvtflow.service.api.schema_check import _plain_plan, _validator
from pvtflow.service.cell_planner import CellPlanner, plan_cell_program

DOF = 6
ROW = [0.1, -0.2, 0.3, -0.1, 0.2, 0.0]


def _valid_requests() -> list[dict[str, Any]]:
    """Well-formed plan requests, every field used (the fast path must take all of them)."""
    base: list[dict[str, Any]] = [
        {"waypoints": [ROW, [0.0] * DOF]},
        {"waypoints": [[1, 0, 0, 0, 0, 0]] * MAX_WAYPOINTS, "start": "first"},
        {"target": ROW},
        {"target": [0] * DOF, "label": "x" * MAX_TEXT, "include_program": True},
        {"waypoints": [ROW], "start": "current", "tolerance_qc": 0.5, "joint_names": ["a"]},
        {"waypoints": [ROW], "tolerance_qc": 10000, "label": "", "include_program": False},
        {"target": ROW, "velocity_scale": 0.5, "acceleration_scale": 1},
        {"waypoints": [ROW], "velocity_scale": 1, "acceleration_scale": 1e-3},
    ]
    return base


def _mutations(req: dict[str, Any]) -> list[Any]:
    """Requests one step away from ``req``: wrong types, sizes, values, fields (most are invalid)."""
    bad_values: list[Any] = [None, True, False, "1", 1.5, 0, -1, [], {}, [[]], [None], ["a"], [True] * DOF]
    out: list[Any] = [None, [], "plan", 3, [req]]
    for key_, value in itertools.product(
        [
            "waypoints",
            "target",
            "joint_names",
            "start",
            "tolerance_qc",
            "label",
            "include_program",
            "velocity_scale",
            "acceleration_scale",
            "extra",
        ],
        bad_values,
    ):
        m = copy.deepcopy(req)
        m[key_] = value
        out.append(m)
    for key_ in list(req):
        m = copy.deepcopy(req)
        del m[key_]
        out.append(m)
    rows = req.get("waypoints")
    if rows:
        for edit in (
            lambda r: r[0].append(0.0),
            lambda r: r[0].pop(),
            lambda r: r[0].__setitem__(0, True),
            lambda r: r[0].__setitem__(0, "0.1"),
            lambda r: r[0].__setitem__(0, None),
            lambda r: r.append([0.0] * (DOF + 1)),
            lambda r: r.extend([[0.0] * DOF] * MAX_WAYPOINTS),
            lambda r: r.__setitem__(0, tuple(r[0])),
        ):
            m = copy.deepcopy(req)
            edit(m["waypoints"])
            out.append(m)
    for extra in (
        {"tolerance_qc": 0.49},
        {"tolerance_qc": 10000.5},
        {"label": "x" * (MAX_TEXT + 1)},
        {"start": "now"},
        {"velocity_scale": 1.0000001},
        {"acceleration_scale": 0.0},
        {"velocity_scale": -1e-9},
    ):
        m = copy.deepcopy(req)
        m.update(extra)
        out.append(m)
    return out


def test_the_schema_fast_path_accepts_only_what_the_schema_accepts():
    validator = _validator("plan", DOF)
    taken = 0
    for req in _valid_requests():
        assert validator.is_valid(req), req
        assert _plain_plan(req, DOF), req  # the common requests do take the fast path
        for m in _mutations(req):
            if _plain_plan(m, DOF):
                taken += 1
                assert validator.is_valid(m), m
    assert taken > 0  # some mutations stay valid (e.g. a dropped optional field) and are fast too
    assert _plain_plan({"waypoints": [[0.0] * 3]}, None)  # the schema without a joint count


@pytest.mark.parametrize(
    "payload, code",
    [
        (b'{"waypoints": [[0, 0, 0, 0, 0]]}', "wrong_joint_count"),
        (b'{"waypoints": [[0, 0, 0, 0, 0, true]]}', "invalid_request"),
        (b'{"target": [0, 0, 0, 0, 0, 0], "waypoints": [[0, 0, 0, 0, 0, 0]]}', "invalid_request"),
        (b'{"waypoints": [[0, 0, 0, 0, 0, NaN]]}', "not_finite"),
        (b'{"waypoints": [[0, 0, 0, 0, 0, 1e999]], "label": "x"}', "not_finite"),
        (b'{"waypoints": [[0, 0, 0, 0, 0, 99]]}', "out_of_limits"),
        (b'{"target": [0, 0, 0, 0, 0, 0], "tolerance_qc": 0.1}', "invalid_request"),
    ],
)
def test_bad_plan_requests_still_get_the_schema_s_error(arm6, payload, code):
    with pytest.raises(ApiError) as err:
        parse_plan(parse_payload(payload), arm6.joint_names, arm6.joint_limits())
    assert err.value.code.value == code


def test_not_finite_names_the_place_of_the_first_bad_number():
    with pytest.raises(ApiError) as err:
        parse_payload(b'{"waypoints": [[0, 0], [0, Infinity]], "label": "x"}')
    assert err.value.details["path"] == "$.waypoints[1][1]"


def test_a_cell_planner_built_once_plans_like_a_one_off_call(arm6):
    lim = arm6.joint_limits()
    mid = 0.5 * (lim.upper + lim.lower)
    first = np.vstack([mid, mid + 0.1 * (lim.upper - mid), mid - 0.1 * (lim.upper - mid)])
    second = np.vstack([mid, np.asarray(SHORT_TARGET)])
    planner = CellPlanner(arm6)
    for waypoints in (first, second, first):  # the same planner, again and again
        reused = planner.plan(PlanInput(waypoints))
        once = plan_cell_program(arm6, PlanInput(waypoints))
        assert reused.ok and once.ok and reused.program is not None and once.program is not None
        for a, b in zip(reused.program.axes, once.program.axes, strict=True):
            assert np.array_equal(a.records, b.records)
        t = reused.timing
        assert 0 < t["plan"] < t["total"] and t["knots"] > 0 and t["cpu"] > 0


def test_a_cell_planner_refusing_its_options_answers_every_plan_with_the_reason(arm6):
    import dataclasses

    bad = dataclasses.replace(arm6, planning=dataclasses.replace(arm6.planning, max_tcp_speed=-1.0))
    result = CellPlanner(bad).plan(PlanInput([[0.0] * DOF, SHORT_TARGET]))
    assert not result.ok and result.code == "invalid_input" and "max_tcp_speed" in result.message


def test_a_plan_reply_splits_its_time(arm6, serve):
    s = serve(arm6)
    planner = s.service.planner
    reply = s.request("plan", {"waypoints": [[0.0] * DOF, SHORT_TARGET], "start": "first"})
    assert reply.ok, reply.data
    t = reply.data["timing_ms"]
    # TOPP-RA + knots = the pipeline, inside motion.plan, inside the service's time from the query's arrival
    assert t["plan"] + t["knots"] == pytest.approx(t["total"], abs=0.01)
    assert t["total"] <= t["request"] <= t["service"]
    assert 0 < t["cpu"] <= t["total"] + 1.0  # thread CPU clock ticks may round up
    again = s.request("plan", {"target": SHORT_TARGET})
    assert again.ok and s.service.planner is planner  # one planner for the life of the service


def test_the_planning_process_plans_like_the_service_s_own_planner_and_survives_its_child(arm6, arm6_planning):
    import os
    import signal

    from pvtflow.service.api import PlanRequest
    from pvtflow.service.planning import PlanningError

    waypoints = np.array([[0.0] * DOF, SHORT_TARGET])
    service = arm6_planning
    reply = service.plan(PlanRequest(waypoints, start="first", include_program=True))
    here = CellPlanner(arm6).plan(PlanInput(waypoints))
    assert here.program is not None
    for axis, expected in zip(reply["program"]["axes"], here.program.axes, strict=True):
        assert np.array_equal(np.asarray(axis["records"]), expected.records)
    assert reply["timing_ms"]["total"] > 0

    os.kill(service.planner._process.pid, signal.SIGKILL)  # the child dies: one request fails, clearly
    with pytest.raises(PlanningError, match="restarted"):
        service.planner.plan(PlanInput(waypoints))
    again = service.plan(PlanRequest(waypoints, start="first"))  # and a new child answers the next one
    assert again["records"] == reply["records"]


def test_a_service_planning_in_a_process_is_open_once_that_process_is_warmed_up(tmp_path) -> None:
    """``MotionService.open`` returns (and ``pvtflow serve`` says it is up) only once the planning
    process has warmed up: the first plan request after start does not wait for its start-up."""
    from test_stop_then_move import cell_file

    from pvtflow.axes.canbus.clock import Clock
    from pvtflow.service.motion import MotionService

    service = MotionService(
        cell_file("gantry3"), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, planner_process=True
    )
    try:
        service.open()
        assert service.planner.ready
    finally:
        service.close()
    assert service.planner._process is None  # closed with the service
