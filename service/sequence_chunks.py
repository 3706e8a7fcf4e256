"""A motion sequence with exact stops: planned as rest-to-rest chunks, joined into one program (issue 38).

An item with ``blend_radius`` 0 stops at its goal. Timed as one path with the items around it, that
stop is the spline through the goal, slowed to a near stop, and one grid and one knot slow-down for the
whole path: the blend-0 sequence ran +3.4 % slower than the same items as separate motions
(bench/RESULTS.md). So a sequence is cut after every exact stop but the last item; each chunk (the items
up to and including the stop) is planned as a sequence of its own from where the one before ends (the
goal's joints, the same inverse kinematics as the whole), rest to rest, and their programs are joined
(``axes.drive.program.joined``): one program, one plan id, executed and stopped like any other; its items'
spans are on the program's time line (``time_scale`` 1: each chunk's own slow-down is in ``chunks``).
The whole sequence is checked first as one (fields, goals, blend spheres), so a refusal names the same
item it would name without chunks; one failing chunk refuses the whole sequence with its item's index.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from pvtflow.axes.drive.program import joined
from pvtflow.planner.build import BuildOutput
from pvtflow.planner.knots.types import AxisKnots, KnotResult
from pvtflow.planner.path import PlanError, PlanResult
from pvtflow.planner.plan import PlanInput, PlanOutput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import CellPlan

if TYPE_CHECKING:
    from pvtflow.service.cell_planner import CellPlanner

_ITEM = re.compile(r"^sequence item (\d+):")


def chunks(items: object) -> list[tuple[int, list[Any]]]:
    """(index of its first item, its items) of every chunk: the sequence cut after each item but the
    last whose ``blend_radius`` is 0 (one chunk: no cut). A radius that is not a number cuts nothing:
    the sequence's check refuses it."""
    if not isinstance(items, Sequence) or isinstance(items, str):
        return [(0, list(items) if isinstance(items, Sequence) else [])]
    out, first = [], 0
    for i, item in enumerate(items[:-1]):
        r = item.get("blend_radius", 0.0) if isinstance(item, dict) else None
        if isinstance(r, int | float) and not isinstance(r, bool) and r == 0:
            out.append((first, list(items[first : i + 1])))
            first = i + 1
    out.append((first, list(items[first:])))
    return out


def _renumbered(plan: CellPlan, offset: int) -> CellPlan:
    """A chunk's refusal with its item's index in the whole sequence."""
    details = dict(plan.details)
    if "item" in details:
        details["item"] = int(details["item"]) + offset
    if "items" in details:
        details["items"] = [int(i) + offset for i in details["items"]]
    message = _ITEM.sub(lambda m: f"sequence item {int(m.group(1)) + offset}:", plan.message)
    return replace(plan, message=message, details=details)


def plan_in_chunks(
    planner: CellPlanner,
    inp: PlanInput,
    tolerance_qc: float | None,
    metadata: dict[str, Any] | None,
    budget_ms: float | None,
) -> CellPlan:
    """The sequence of ``inp`` (from joint positions ``inp.waypoints``) in its chunks, as one plan."""
    t0, cpu = time.perf_counter(), time.thread_time()
    assert planner.planner is not None and planner.planner.sequences is not None
    items = list(inp.sequence or [])
    try:
        planner.planner.sequences.check(inp.waypoints, items)
    except PlanError as exc:
        return CellPlan(exc.result.value, exc.message, None, None, None, {"plan": 0.0}, details=dict(exc.details))
    here = np.asarray(inp.waypoints, dtype=float)
    parts: list[tuple[int, list[Any], CellPlan]] = []
    for first, chunk in chunks(items):
        left = None if budget_ms is None else budget_ms - 1000.0 * (time.perf_counter() - t0)  # one budget for all
        part = planner.plan(replace(inp, waypoints=here, sequence=chunk), tolerance_qc, metadata, left)
        if part.code == PlanResult.REPEATED_WAYPOINT.value:  # a chunk that does not move: its items take no time
            parts.append((first, chunk, part))
            continue
        if not part.ok or part.program is None or part.build is None or part.waypoints is None:
            return _renumbered(part, first)
        parts.append((first, chunk, part))
        here = part.waypoints[-1]
    moving = [p for _, _, p in parts if p.ok]
    if not moving:
        return _renumbered(parts[0][2], 0)
    return _joined(parts, moving, t0, cpu)


def _joined(parts: list[tuple[int, list[Any], CellPlan]], moving: list[CellPlan], t0: float, cpu: float) -> CellPlan:
    programs = [p.program for p in moving if p.program is not None]
    builds = [p.build for p in moving if p.build is not None]
    spans: list[dict[str, Any]] = []
    summary: list[dict[str, Any]] = []
    offset_s = 0.0
    for first, chunk, part in parts:
        if part.program is None:
            spans.extend(
                {"index": first + k, "label": _label(it), "start_s": offset_s, "end_s": offset_s}
                for k, it in enumerate(chunk)
            )
            continue
        meta = part.program.metadata
        scale = float(meta.get("time_scale", 1.0))
        end_s = offset_s + part.program.duration_ms / 1000.0
        for span in meta["items"]:
            spans.append(
                {
                    "index": first + int(span["index"]),
                    "label": span["label"],
                    "start_s": offset_s + float(span["start_s"]) * scale,
                    "end_s": min(end_s, offset_s + float(span["end_s"]) * scale),
                }
            )
        spans[-1]["end_s"] = end_s
        summary.append(
            {"items": [first, first + len(chunk) - 1], "duration_ms": part.program.duration_ms, "time_scale": scale}
        )
        offset_s = end_s
    first_meta = dict(programs[0].metadata)
    deviation = {
        name: max(float(p.metadata["deviation_qc"][name]) for p in programs) for name in first_meta["deviation_qc"]
    }
    metadata = {
        **first_meta,
        "planned_duration_ms": round(sum(float(p.metadata["planned_duration_ms"]) for p in programs), 3),
        "time_scale": 1.0,
        "deviation_qc": deviation,
        "items": spans,
        "chunks": summary,
    }
    program = joined(programs, metadata)
    metadata["duration_ms"] = program.duration_ms
    program = replace(program, metadata=metadata)
    t_valid = time.perf_counter()
    report = validate_program(program, sample_period_ms=None)  # the joined program, as every program is
    if not report.ok:
        why = "; ".join(f.format() for f in report.errors[:3])
        return CellPlan("program_error", f"the joined chunks do not validate: {why}", None, None, None, {})
    dwell = builds[0].program.duration_ms - builds[0].knots.duration_ms
    knots = KnotResult(
        tuple(
            AxisKnots(
                axis.joint,
                axis.records,
                max(b.knots.axes[i].deviation_qc for b in builds),
                max(b.knots.axes[i].velocity_ratio for b in builds),
                max(b.knots.axes[i].acceleration_ratio for b in builds),
                max(b.knots.axes[i].jerk_ratio for b in builds),
            )
            for i, axis in enumerate(program.axes)
        ),
        max(b.knots.time_scale for b in builds),
        program.duration_ms - dwell,
        sum(b.knots.rounds for b in builds),
    )
    timing: dict[str, float] = {}
    for part in moving:
        for key, value in part.timing.items():
            timing[key] = timing.get(key, 0.0) + value
    total = time.perf_counter() - t0
    timing.update({"validation": time.perf_counter() - t_valid, "total": total, "cpu": time.thread_time() - cpu})
    waypoints = np.vstack([moving[0].waypoints[:1], *[p.waypoints[1:] for p in moving]])  # type: ignore[index]
    gaps = [p.gap for p in moving]
    gap = None
    if all(g is not None for g in gaps):
        gap = {k: math.fsum(g[k] for g in gaps if g is not None) for k in ("duration_s", "lower_bound_s")}
    return CellPlan(
        "ok",
        "",
        program,
        PlanOutput(PlanResult.OK, "", None, total, {"items": spans, "chunks": summary}),
        BuildOutput(program, knots, report, {"validation": timing["validation"]}),
        timing,
        waypoints,
        optimal=all(p.optimal for p in moving),
        gap=gap,
        speed_band=next((p.speed_band for p in moving if p.speed_band is not None), None),
    )


def _label(item: object) -> str | None:
    label = item.get("label") if isinstance(item, dict) else None
    return label if isinstance(label, str) else None
