"""The refusals the service and the command line share: one condition, one :class:`ErrorCode`, one wording.

``pvtflow request`` prints a service's refusal as ``CODE: MESSAGE``; ``pvtflow plan`` and ``pvtflow
execute`` meet the same conditions without a service and print them the same way (:meth:`ApiError.line`),
built here, so that a user reads the same code and the same words whichever way they went.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pvtflow.axes.master.group.outcome import Result, RunResult
from pvtflow.service.api.wire import ApiError, ErrorCode

PLAN_AGAIN = "plan again from the current position"


def start_mismatch(joint: str, position_qc: int, start_qc: int, hint: str = PLAN_AGAIN) -> ApiError:
    """The axes are not where the program starts."""
    return ApiError(
        ErrorCode.START_MISMATCH,
        f"axis {joint} is at {position_qc} qc, the program starts at {start_qc} qc: {hint}",
        {"joint": joint, "position_qc": position_qc, "start_qc": start_qc},
    )


def run_refused(early: RunResult, details: dict[str, Any] | None = None, hint: str = PLAN_AGAIN) -> ApiError:
    """A run the axis group refused at its start (nothing moved): the drives answered elsewhere than the
    program starts (``start_mismatch``), the program does not fit the drives (``wrong_cell``), or they
    did not start (``drive_fault``)."""
    details = {"outcome": early.to_json(), **(details or {})}
    if early.result is Result.REJECTED and early.joint is not None:
        return ApiError(ErrorCode.START_MISMATCH, f"{early.message}: {hint}", details)
    if early.result is Result.REJECTED:
        return ApiError(ErrorCode.WRONG_CELL, early.message, details)
    return ApiError(ErrorCode.DRIVE_FAULT, f"the drives did not start: {early.message}", details)


def not_homed(cell: str, joints: Sequence[str], how: str = "call home") -> ApiError:
    """A cell that requires homing, with axes not homed since their drives booted."""
    joints = list(joints)
    return ApiError(
        ErrorCode.NOT_HOMED,
        f"cell {cell} must home first: {', '.join(joints)} not homed since "
        f"{'its drive' if len(joints) == 1 else 'their drives'} last booted: {how}",
        {"joints": joints},
    )


def wrong_cell(cell: str, problems: Sequence[str], program_cell: str | None = None) -> ApiError:
    """A program made for another cell, or for other drives: its own cell named, and the first problems."""
    if program_cell and program_cell != cell:  # every axis differs: the cell says it (details list them)
        message = f"the program was not made for cell {cell}: it was made for cell {program_cell}"
    else:
        message = f"the program was not made for cell {cell}: " + "; ".join(problems[:3])
    return ApiError(
        ErrorCode.WRONG_CELL,
        message,
        {"problems": list(problems), **({"program_cell": program_cell} if program_cell else {})},
    )


def validation_failed(errors: Sequence[str], report: dict[str, Any]) -> ApiError:
    """A program that breaks its drives' rules."""
    return ApiError(
        ErrorCode.VALIDATION_FAILED,
        "the program breaks its drives' rules: nothing was sent: " + "; ".join(errors[:3]),
        {"report": report},
    )


def plan_failed(cell: str, code: str, message: str, details: dict[str, Any] | None = None) -> ApiError:
    """The planner found no motion (``code``: its PlanResult or CartesianResult)."""
    return ApiError(
        ErrorCode.PLAN_FAILED,
        f"cannot plan this motion on cell {cell} ({code}): {message}",
        {"result": code, **(details or {})},
    )


def invalid_value(path: str, problem: ValueError) -> ApiError:
    """A value the request's schema allows in type but not in range (a speed override, a jerk limit):
    the check's own words (planner.limits), after the field's path."""
    return ApiError(ErrorCode.INVALID_REQUEST, f"{path}: {problem}", {"path": path})
