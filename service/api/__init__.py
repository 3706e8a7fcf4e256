"""The zenoh API of one cell: key expressions, request/reply payloads, JSON Schemas, error codes.

Every payload is JSON. A request is checked in this order, and the first problem found is the
answer (a :class:`ApiError`, sent with ``reply_err``): size (``too_large``), JSON syntax
(``malformed_json``), the request's JSON Schema (``invalid_request``, ``wrong_joint_count``,
``too_large``), then the values (``not_finite``, ``unknown_joint``, ``out_of_limits``). Only a
request that passes all of them reaches the planner or the drives, so a bad request changes nothing.

The schemas below are the one description of the payloads: the service validates with them,
docs/API.md prints them, and the tests check every reply against them.

Where each part lives: ``wire`` (key expressions, error codes, JSON, limits, cell states),
``request_schemas`` and ``reply_schemas`` (the JSON Schemas), ``schema_check`` (a request checked
against its schema), ``schema_doc`` (docs/API.md's schema section: ``python -m pvtflow.service.api``),
``requests`` (each request checked and parsed). The names below are the API's
public surface.
"""

from __future__ import annotations

from pvtflow.service.api.reply_schemas import reply_schema
from pvtflow.service.api.request_schemas import SCHEMA_DIALECT, request_schema
from pvtflow.service.api.requests import (
    ExecuteRequest,
    HomeRequest,
    OverrideRequest,
    PauseRequest,
    PlanRequest,
    RecoverRequest,
    ResumeRequest,
    StatusRequest,
    StopMode,
    StopRequest,
    ValidateRequest,
    check_limits,
    parse_execute,
    parse_home,
    parse_override,
    parse_pause,
    parse_plan,
    parse_recover,
    parse_resume,
    parse_status,
    parse_stop,
    parse_validate,
)
from pvtflow.service.api.schema_check import check_schema
from pvtflow.service.api.schema_doc import SCHEMA_DOC_BEGIN, SCHEMA_DOC_END, schema_document
from pvtflow.service.api.wire import (
    API_VERSION,
    ERROR_DESCRIPTIONS,
    ID_PATTERN,
    LIVELINESS,
    MAX_RECENT,
    MAX_REQUEST_BYTES,
    MAX_TEXT,
    MAX_WAYPOINTS,
    PREFIX,
    PUBLICATIONS,
    QUERYABLES,
    ApiError,
    CellState,
    ErrorCode,
    PlanStart,
    RunState,
    check_cell_name,
    dumps,
    key,
    parse_payload,
)

__all__ = [
    "API_VERSION",
    "ERROR_DESCRIPTIONS",
    "ID_PATTERN",
    "LIVELINESS",
    "MAX_RECENT",
    "MAX_REQUEST_BYTES",
    "MAX_TEXT",
    "MAX_WAYPOINTS",
    "PREFIX",
    "PUBLICATIONS",
    "QUERYABLES",
    "SCHEMA_DIALECT",
    "SCHEMA_DOC_BEGIN",
    "SCHEMA_DOC_END",
    "ApiError",
    "CellState",
    "ErrorCode",
    "ExecuteRequest",
    "HomeRequest",
    "OverrideRequest",
    "PauseRequest",
    "PlanRequest",
    "PlanStart",
    "RecoverRequest",
    "ResumeRequest",
    "RunState",
    "StatusRequest",
    "StopMode",
    "StopRequest",
    "ValidateRequest",
    "check_cell_name",
    "check_limits",
    "check_schema",
    "dumps",
    "key",
    "parse_execute",
    "parse_home",
    "parse_override",
    "parse_pause",
    "parse_payload",
    "parse_plan",
    "parse_recover",
    "parse_resume",
    "parse_status",
    "parse_stop",
    "parse_validate",
    "reply_schema",
    "request_schema",
    "schema_document",
]
