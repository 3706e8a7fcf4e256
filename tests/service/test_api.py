"""The request models, schemas and error codes, without a bus or a network."""

from __future__ import annotations

import json

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from pvtflow.service.api import (
    ERROR_DESCRIPTIONS,
    QUERYABLES,
    ApiError,
    ErrorCode,
    check_cell_name,
    key,
    parse_payload,
    parse_plan,
    parse_recover,
    reply_schema,
    request_schema,
)

NAMES = ("joint_1", "joint_2", "joint_3")


def code_of(fn, *args) -> str:
    with pytest.raises(ApiError) as err:
        fn(*args)
    return err.value.code.value


def test_every_schema_is_a_valid_json_schema_and_every_code_is_documented():
    for op in QUERYABLES:
        Draft202012Validator.check_schema(request_schema(op, 6))
        Draft202012Validator.check_schema(reply_schema(op))
    for topic in ("state", "telemetry", "events", "error"):
        Draft202012Validator.check_schema(reply_schema(topic))
    assert set(ERROR_DESCRIPTIONS) == set(ErrorCode)
    Draft202012Validator(reply_schema("error")).validate(ApiError(ErrorCode.BUSY, "x", {"a": 1}).to_json())


def test_plan_requests_are_reordered_by_joint_name_and_checked_against_limits(arm6):
    names = arm6.joint_names
    req = parse_plan(
        {"waypoints": [[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]], "joint_names": list(reversed(names))},
        names,
        arm6.joint_limits(),
    )
    np.testing.assert_allclose(req.waypoints, [[0.6, 0.5, 0.4, 0.3, 0.2, 0.1]])
    assert req.start == "current"
    lim = arm6.joint_limits()
    edge = [float(lim.upper[0])] + [0.0] * 5
    assert parse_plan({"target": edge}, names, lim).waypoints.shape == (1, 6)
    over = [float(lim.upper[0]) + 1e-6] + [0.0] * 5
    with pytest.raises(ApiError) as err:
        parse_plan({"target": over}, names, lim)
    assert err.value.code is ErrorCode.OUT_OF_LIMITS and err.value.details["joint"] == "joint_1"
    assert code_of(parse_plan, {"waypoints": [[0.0] * 6], "start": "first"}, names, lim) == "invalid_request"


@pytest.mark.parametrize(
    ("payload", "code"),
    [
        (b"{", "malformed_json"),
        (b"\x80", "malformed_json"),
        (b"1" * 5000, "malformed_json"),  # an integer literal longer than Python parses
        (b"[" * 100000, "malformed_json"),  # deeper than the parser's recursion
        (b'{"a": [1, {"b": NaN}]}', "not_finite"),
        (b'{"a": -Infinity}', "not_finite"),
        (b"x" * (2 << 20), "too_large"),
    ],
)
def test_payload_problems_have_their_codes(payload, code):
    assert code_of(parse_payload, payload) == code


def test_empty_payload_is_an_empty_request_and_numbers_out_of_float_range_are_not_finite():
    assert parse_payload(b"") == {} and parse_payload(None) == {}
    big = json.dumps({"target": [10**400, 0, 0]}).encode()
    assert code_of(parse_plan, parse_payload(big), NAMES) == "not_finite"


def test_messages_name_the_place_of_the_problem():
    with pytest.raises(ApiError) as err:
        parse_plan({"waypoints": [[0, 0, 0], [0, 0]]}, NAMES)
    assert err.value.code is ErrorCode.WRONG_JOINT_COUNT
    assert err.value.details == {"path": "$.waypoints[1]", "expected": 3, "got": 2}
    with pytest.raises(ApiError) as err:
        parse_plan({"target": [0, 0, 0], "speed": 1}, NAMES)
    assert err.value.code is ErrorCode.INVALID_REQUEST and "'speed'" in err.value.message
    with pytest.raises(ApiError) as err:
        parse_plan({"target": [0, "a", 0]}, NAMES)
    assert err.value.details["path"] == "$.target[1]"


def test_key_expressions_and_cell_names():
    assert key("arm6", "plan") == "pvtflow/arm6/plan"
    assert key("*", "status") == "pvtflow/*/status"
    assert check_cell_name("gantry3") == "gantry3"
    for bad in ("a/b", "*", "cell$", "", "a b"):
        with pytest.raises(ValueError):
            check_cell_name(bad)


def test_docs_api_md_has_the_current_schemas_and_every_error_code():
    from pathlib import Path

    from pvtflow.service.api import SCHEMA_DOC_BEGIN, SCHEMA_DOC_END, schema_document

    doc = (Path(__file__).resolve().parents[2] / "docs" / "API.md").read_text(encoding="utf-8")
    start, end = doc.index(SCHEMA_DOC_BEGIN), doc.index(SCHEMA_DOC_END) + len(SCHEMA_DOC_END)
    assert doc[start:end] == schema_document(), "docs/API.md is stale: regenerate with python -m pvtflow.service.api"
    for code in ErrorCode:
        assert f"| `{code.value}` |" in doc, code


def test_a_request_that_takes_no_fields_says_so() -> None:
    with pytest.raises(ApiError, match="a recover request takes no fields, got 'x'"):
        parse_recover({"x": 1})


def test_plan_requests_take_speed_and_acceleration_scales_in_0_1():
    req = parse_plan({"target": [0, 0, 0]}, NAMES)
    assert (req.velocity_scale, req.acceleration_scale) == (1.0, 1.0)
    req = parse_plan({"target": [0, 0, 0], "velocity_scale": 0.5, "acceleration_scale": 1}, NAMES)
    assert (req.velocity_scale, req.acceleration_scale) == (0.5, 1.0)
    for field in ("velocity_scale", "acceleration_scale"):
        for value in (0, -0.1, 1.5, "0.5", None, True, [0.5]):
            with pytest.raises(ApiError) as err:
                parse_plan({"target": [0, 0, 0], field: value}, NAMES)
            assert err.value.code is ErrorCode.INVALID_REQUEST, (field, value)
            assert err.value.message.startswith(f"$.{field}: ") and err.value.details["path"] == f"$.{field}"
        payload = json.dumps({"target": [0, 0, 0], field: 0.5}).replace("0.5", "NaN").encode()
        with pytest.raises(ApiError) as err:
            parse_plan(parse_payload(payload), NAMES)
        assert err.value.code is ErrorCode.NOT_FINITE and err.value.details["path"] == f"$.{field}"
