"""Every class of bad input gets reply_err with a clear code, nothing moves, and the service stays up."""

from __future__ import annotations

import copy
import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from svc_helpers import SHORT_TARGET, check_reply, nothing_moved, served_cell

from pvtflow.service.api import MAX_REQUEST_BYTES, MAX_WAYPOINTS

GOOD = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1]

CASES = [
    # (op, raw payload, expected code)
    ("plan", b"{", "malformed_json"),
    ("plan", b"plan me", "malformed_json"),
    ("plan", b"\xff\xfe\x00garbage", "malformed_json"),
    ("execute", b'{"plan_id": "p-1"', "malformed_json"),
    ("status", b"{'recent': 1}", "malformed_json"),
    ("plan", b"[]", "invalid_request"),
    ("plan", b'"waypoints"', "invalid_request"),
    ("plan", b"{}", "invalid_request"),
    ("plan", b'{"waypoints": "up"}', "invalid_request"),
    ("plan", b'{"waypoints": []}', "invalid_request"),
    ("plan", b'{"target": [true, 0, 0, 0, 0, 0]}', "invalid_request"),
    ("plan", b'{"target": ["0.1", 0, 0, 0, 0, 0]}', "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "waypoints": [GOOD]}).encode(), "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "speed": 2}).encode(), "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "start": "somewhere"}).encode(), "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "tolerance_qc": 0}).encode(), "invalid_request"),
    ("execute", b'{"plan_id": 17}', "invalid_request"),
    ("execute", b'{"plan_id": "../../etc/passwd"}', "invalid_request"),
    ("execute", b"{}", "invalid_request"),
    ("execute", b'{"program": [1, 2]}', "invalid_request"),
    ("execute", b'{"program": {"format": "pvtflow.pvt-program"}}', "invalid_request"),
    ("validate", b'{"program": {}, "plan_id": "p-1"}', "invalid_request"),
    ("status", b'{"recent": "ten"}', "invalid_request"),
    ("status", b'{"recent": 1000}', "invalid_request"),
    ("stop", b'{"reason": 5}', "invalid_request"),
    ("recover", b'{"force": true}', "invalid_request"),
    ("plan", json.dumps({"target": GOOD[:5]}).encode(), "wrong_joint_count"),
    ("plan", json.dumps({"target": [*GOOD, 0.0]}).encode(), "wrong_joint_count"),
    ("plan", json.dumps({"target": GOOD, "max_jerk": [100.0] * 5}).encode(), "wrong_joint_count"),
    ("plan", json.dumps({"target": GOOD, "max_jerk": [100.0] * 5 + [0]}).encode(), "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "max_jerk": [100.0] * 5 + [-1]}).encode(), "invalid_request"),
    ("plan", json.dumps({"target": GOOD, "max_jerk": 100.0}).encode(), "invalid_request"),
    ("plan", b'{"target": [0, 0, 0, 0, 0, 0.1], "max_jerk": [1, 1, NaN, 1, 1, 1]}', "not_finite"),
    ("plan", json.dumps({"waypoints": [GOOD, GOOD[:2]]}).encode(), "wrong_joint_count"),
    ("plan", b'{"target": [NaN, 0, 0, 0, 0, 0]}', "not_finite"),
    ("plan", b'{"target": [0, Infinity, 0, 0, 0, 0]}', "not_finite"),
    ("plan", b'{"waypoints": [[0, 0, 0, 0, 0, -Infinity]]}', "not_finite"),
    ("plan", b'{"target": [0, 0, 1e999, 0, 0, 0]}', "not_finite"),
    ("plan", b'{"target": [0, 0, 0, 0, 0, 0], "tolerance_qc": NaN}', "not_finite"),
    ("plan", json.dumps({"target": [10.0, 0, 0, 0, 0, 0]}).encode(), "out_of_limits"),
    ("plan", json.dumps({"waypoints": [GOOD, [0, -9.0, 0, 0, 0, 0]]}).encode(), "out_of_limits"),
    ("plan", json.dumps({"target": GOOD, "joint_names": ["a", "b", "c", "d", "e", "f"]}).encode(), "unknown_joint"),
    ("plan", json.dumps({"target": GOOD, "joint_names": ["joint_1"] * 6}).encode(), "unknown_joint"),
    ("execute", b'{"plan_id": "p-0000000000000000"}', "unknown_plan"),
    ("validate", b'{"plan_id": "p-0000000000000000"}', "unknown_plan"),
    ("plan", json.dumps({"waypoints": [GOOD] * (MAX_WAYPOINTS + 1)}).encode(), "too_large"),
    ("plan", b'{"label": "' + b"x" * (MAX_REQUEST_BYTES + 10) + b'"}', "too_large"),
    ("plan", json.dumps({"target": [0.0] * 6}).encode(), "plan_failed"),  # already there
]


@pytest.fixture(scope="module")
def served(arm6, tmp_path_factory):
    """One service for the whole module: every bad request of every test goes to it."""
    with served_cell(arm6, tmp_path_factory.mktemp("journal")) as s:
        yield s


def test_every_bad_input_class_gets_its_error_code_and_nothing_moves(served):
    for op, payload, code in CASES:
        reply = served.request(op, payload)
        assert not reply.ok, (op, payload[:80], reply.data)
        check_reply("error", reply.data)
        assert reply.data["error"]["code"] == code, (op, payload[:80], reply.data)
        assert reply.data["error"]["message"]
    nothing_moved(served)
    status = served.request("status")
    assert status.ok and status.data["state"] == "idle"


def test_bad_programs_are_refused_before_anything_is_sent(served, gantry3):
    plan = served.request("plan", {"target": SHORT_TARGET, "include_program": True})
    assert plan.ok
    program = plan.data["program"]
    # a record faster than the drive's 0x607F: the validator's verdict, nothing sent
    fast = copy.deepcopy(program)
    fast["axes"][0]["records"][1][1] = 7_000_000
    reply = served.request("execute", {"program": fast})
    assert reply.data["error"]["code"] == "validation_failed", reply.data
    assert reply.data["error"]["details"]["report"]["ok"] is False
    # a program for other drive limits (not this cell's)
    other = copy.deepcopy(program)
    other["axes"][2]["limits"]["max_profile_velocity_rpm"] = 9000
    reply = served.request("execute", {"program": other})
    assert reply.data["error"]["code"] == "wrong_cell", reply.data
    # validate tells the same without an error
    verdict = served.request("validate", {"program": other})
    assert verdict.ok and verdict.data["ok"] is False and verdict.data["cell_problems"]
    # records out of their integer range
    huge = copy.deepcopy(program)
    huge["axes"][1]["records"][1][0] = 2**40
    assert served.request("execute", {"program": huge}).data["error"]["code"] == "invalid_request"
    nothing_moved(served)


# --- generated bad requests (the bench runs 10 000 of them: bench/fuzz_requests.py) --------------------
ALLOWED = {
    "plan": {"waypoints", "target", "joint_names", "start", "tolerance_qc", "label", "include_program"},
    "validate": {"plan_id", "program"},
    "execute": {"plan_id", "program", "label", "wait"},
    "stop": {"reason"},
    "status": {"recent"},
    "recover": set(),
    "home": {"joints", "wait"},
}
OPS = sorted(ALLOWED)
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12,
)


def _not_json(b: bytes) -> bool:
    try:
        json.loads(b)
    except ValueError:
        return True
    return False


@st.composite
def bad_requests(draw: st.DrawFn) -> tuple[str, bytes]:
    kind = draw(st.sampled_from(["bytes", "not_object", "unknown_field", "bad_vector", "bad_id", "bad_recent"]))
    op = draw(st.sampled_from(OPS))
    if kind == "bytes":
        return op, draw(st.binary(min_size=1, max_size=64).filter(_not_json))
    if kind == "not_object":
        value = draw(json_values.filter(lambda v: not isinstance(v, dict) and v is not None))
        return op, json.dumps(value).encode()
    if kind == "unknown_field":
        body = draw(st.dictionaries(st.text(min_size=1, max_size=8), json_values, min_size=1, max_size=3))
        extra = draw(st.text(min_size=1, max_size=8).filter(lambda k: k not in ALLOWED[op]))
        body[extra] = draw(json_values)
        return op, json.dumps(body).encode()
    if kind == "bad_vector":
        n = draw(st.integers(0, 9))
        bad = st.floats(allow_nan=True, allow_infinity=True).filter(lambda x: x != x or abs(x) > 4.0)
        vector = draw(st.lists(st.floats(-1, 1) | bad | st.text(max_size=3) | st.booleans(), min_size=n, max_size=n))
        if n == 6 and all(isinstance(x, float) and abs(x) <= 1.0 for x in vector):
            vector[0] = float("nan")  # keep it bad
        return "plan", json.dumps({"target": vector}).encode()
    if kind == "bad_id":
        return draw(st.sampled_from(["execute", "validate"])), json.dumps(
            {"plan_id": draw(st.text(max_size=70))}
        ).encode()
    in_range = st.integers().filter(lambda r: not 0 <= r <= 100)
    not_a_count = st.floats().filter(lambda f: not (math.isfinite(f) and f.is_integer() and 0 <= f <= 100))
    return "status", json.dumps({"recent": draw(in_range | st.text() | not_a_count)}).encode()


@settings(
    max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
)
@given(request=bad_requests())
def test_generated_bad_requests_are_all_answered_with_errors(served, request):
    op, payload = request
    reply = served.request(op, payload)
    assert not reply.ok, (op, payload, reply.data)
    check_reply("error", reply.data)
    assert reply.data["error"]["code"] != "internal_error", reply.data


def test_a_bug_in_a_handler_is_an_internal_error_reply_and_the_service_stays_up(served, monkeypatch):
    def broken(req):
        raise IndexError("index 32640 is out of bounds")  # what a planner bug looks like from here

    monkeypatch.setattr(served.service, "plan", broken)
    reply = served.request("plan", {"target": SHORT_TARGET})
    assert reply.data["error"]["code"] == "internal_error"
    assert "IndexError" in reply.data["error"]["message"]
    monkeypatch.undo()
    assert served.request("status").ok
    assert served.request("plan", {"target": SHORT_TARGET}).ok


def test_after_all_those_requests_the_service_is_up_and_nothing_moved(served):
    # the same service answered every request of this module
    status = served.request("status")
    assert status.ok and status.data["state"] == "idle"
    nothing_moved(served)
