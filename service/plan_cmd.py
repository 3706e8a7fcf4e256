"""``pvtflow plan --config FILE --waypoints FILE -o PROGRAM.json``: plan a motion, write its program.

Exit codes: 0 written, 1 the waypoints cannot be planned on this cell (the message says why),
2 unreadable input (configuration, waypoint file) or the output cannot be written.

The pipeline itself (:class:`CellPlanner`) is service/cell_planner.py's.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.limits import check_max_jerk, check_scale
from pvtflow.planner.plan import PlanInput
from pvtflow.service.api import ApiError, ErrorCode, check_limits, refusals
from pvtflow.service.cell_planner import TIMEOUT, CellPlan, CellPlanner
from pvtflow.service.cli_options import add_config, add_json
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config
from pvtflow.service.waypoints import (
    PoseTargets,
    SequenceTargets,
    WaypointError,
    dropped_times_warning,
    load_motion,
    load_sequence,
)

EXIT_OK, EXIT_NOT_PLANNED, EXIT_BAD_INPUT = 0, 1, 2
# A plan still running after this long is compiling numba's kernels (a new machine, or a kernel source
# edited): a plan with loaded kernels takes well under it (bench/RESULTS.md), so only a compile says so.
SLOW_PLAN_NOTICE_S = 2.0
COMPILE_S = 15  # what compiling them takes (docs/installing.md)


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "plan",
        help="plan a time-optimal motion through waypoints (or tool poses) and write its PVT program",
        description="Plan a time-optimal motion through the waypoints (or the tool poses: straight tool lines "
        "or joint moves, solved by inverse kinematics) on a cell and write the PVT program "
        "(validated: the drives' own reconstruction stays inside their limits). Exit 0 written, "
        "1 cannot be planned, 2 unreadable input.",
    )
    add_config(p)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--sequence",
        metavar="FILE",
        help='a motion sequence (JSON or YAML, the plan request\'s object): {"start": [joint values], '
        '"sequence": [{"motion": "ptp" | "lin" | "circ", "target" | "pose" | "via" | "center": ..., '
        '"blend_radius": m, "label": text}, ...]} (docs/planning.md, "Motion sequences")',
    )
    what.add_argument(
        "--waypoints",
        metavar="FILE",
        help="waypoints: pvtflow JSON, or a ROS JointTrajectory as JSON or YAML; or tool poses: "
        '{"poses": [[x, y, z, qx, qy, qz, qw], ...], "motion": "linear" or "joint", "start": [joint values]}',
    )
    p.add_argument("-o", "--output", metavar="PROGRAM.json", required=True, help="where to write the program")
    p.add_argument(
        "--start",
        choices=("first", "home"),
        default="first",
        help="first (default): the motion starts at the first waypoint (a pose file: at its start); home: at the "
        "cell's home position (where homing leaves the axes: each axis's 0x607C), then through every waypoint or pose",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        metavar="QC",
        help="position tolerance in counts (default: the cell's planning.position_tolerance_qc)",
    )
    p.add_argument(
        "--velocity-scale",
        type=float,
        default=1.0,
        metavar="F",
        help="speed override in (0, 1]: plan with the joint velocity limits times F (default 1)",
    )
    p.add_argument(
        "--acceleration-scale",
        type=float,
        default=1.0,
        metavar="F",
        help="the same for the joint acceleration limits (default 1)",
    )
    p.add_argument(
        "--max-jerk",
        metavar="J1,...,Jn",
        help="jerk limit per joint in joint units/s^3 (rad/s^3, m/s^3), in the cell's joint order, instead of "
        "the cell's axes' max_jerk: the timing is then solved jerk-limited (casadi) instead of by TOPP-RA alone",
    )
    p.add_argument(
        "--budget-ms",
        type=float,
        metavar="MS",
        help="the plan's deadline in ms (default: the cell's planning.budget_ms): a jerk-limited timing answers "
        "by then with its best so far (not optimal: said in the summary); a plan past it for another reason is "
        "refused (timeout). A jerk-limited plan's casadi program is built before the deadline starts",
    )
    add_json(p)
    p.set_defaults(run=run)


def _numbers(text: str) -> list[float] | str:
    """A comma-separated list of numbers; the text itself where it is not one (check_max_jerk words it)."""
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        return text


def from_home(
    motion: NDArray[np.float64] | PoseTargets | SequenceTargets, cell: CellConfig
) -> NDArray[np.float64] | PoseTargets | SequenceTargets:
    """The motion from the cell's home position: waypoints with it as their first row (a first row within
    a count of it is taken as it, as the service does for ``start: home``), poses with it as their start.
    ValueError for a cell without a home, or a pose file that names its own start."""
    home = cell.home_position()
    if isinstance(motion, PoseTargets | SequenceTargets):
        if motion.start is not None:
            raise ValueError('the file names its own start: leave it out (or "current") to start at home')
        return replace(motion, start=home)
    qc = [
        (a.scaling.position_to_qc(x), a.scaling.position_to_qc(h))
        for a, x, h in zip(cell.ordered_axes(), motion[0], home, strict=True)
    ]
    if max(abs(float(x) - float(h)) for x, h in qc) <= 1.0:
        return np.vstack([home, motion[1:]])
    return np.vstack([home, motion])


def _say_compiling() -> None:
    print(
        f"pvtflow plan: still planning (on a new machine the first plan compiles the planner's loops first: "
        f"numba, about {COMPILE_S} s, once; cached next to the sources afterwards)",
        file=sys.stderr,
        flush=True,
    )


def _not_optimal_reason(result: CellPlan, budget_ms: float) -> str:
    """Why a jerk-limited plan is not the optimum: its deadline, the torque between its rows, or both."""
    details = result.plan.details if result.plan is not None else {}
    reasons = []
    if not details.get("solver_finished", False):
        reasons.append(f"the {budget_ms:g} ms budget came first")
    torque = float(details.get("torque_scale", 1.0))  # type: ignore[arg-type]
    if details.get("solver_finished", False) and torque > 1.0:
        reasons.append(f"slowed {100.0 * (torque - 1.0):.1f} % to hold the torque limits between the solver's rows")
    return "; ".join(reasons)


def _fail(code: int, message: str) -> int:
    print(f"pvtflow plan: {message}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        return _fail(EXIT_BAD_INPUT, str(exc))
    source = args.sequence if args.sequence is not None else args.waypoints
    try:
        if args.sequence is not None:
            motion: NDArray[np.float64] | PoseTargets | SequenceTargets = load_sequence(args.sequence, cell.joint_names)
        else:
            motion = load_motion(args.waypoints, cell.joint_names, min_count=1 if args.start == "home" else 2)
    except WaypointError as exc:
        return _fail(EXIT_BAD_INPUT, str(exc))
    if args.start == "home":
        try:
            motion = from_home(motion, cell)
        except ValueError as exc:
            return _fail(EXIT_BAD_INPUT, f"--start home: {exc}")
    if isinstance(motion, PoseTargets | SequenceTargets) and motion.start is None:
        return _fail(
            EXIT_BAD_INPUT,
            f"{source}: start: planning offline needs the joint positions the motion starts from "
            '(a list of joint values; "current" is for a running service)',
        )
    if args.tolerance is not None and not args.tolerance >= 0.5:
        return _fail(EXIT_BAD_INPUT, f"--tolerance must be at least 0.5 count, got {args.tolerance}")
    for option, value in (("--velocity-scale", args.velocity_scale), ("--acceleration-scale", args.acceleration_scale)):
        try:
            check_scale(option, value)
        except ValueError as exc:
            return _fail(EXIT_BAD_INPUT, ApiError(ErrorCode.INVALID_REQUEST, str(exc)).line())

    max_jerk = None
    if args.max_jerk is not None:
        try:
            max_jerk = check_max_jerk("--max-jerk", _numbers(args.max_jerk), len(cell.joint_names))
        except ValueError as exc:
            return _fail(EXIT_BAD_INPUT, str(exc))

    budget_ms = cell.planning.budget_ms if args.budget_ms is None else args.budget_ms
    if not (math.isfinite(budget_ms) and budget_ms > 0):
        return _fail(EXIT_BAD_INPUT, f"--budget-ms must be a positive number of ms, got {args.budget_ms}")
    scales: dict[str, Any] = {
        "velocity_scale": args.velocity_scale,
        "acceleration_scale": args.acceleration_scale,
        "max_jerk": max_jerk,
    }
    if isinstance(motion, SequenceTargets):
        assert motion.start is not None
        inp = PlanInput(motion.start, sequence=motion.items, **scales)
    elif isinstance(motion, PoseTargets):
        assert motion.start is not None
        inp = PlanInput(motion.start, motion.poses, motion.motion, **scales)
    else:
        try:
            check_limits(motion, cell.joint_limits())
        except ApiError as exc:
            return _fail(EXIT_NOT_PLANNED, f"{exc.code.value}: {args.waypoints}: {exc.message}")
        inp = PlanInput(motion, **scales)
    notice = threading.Timer(SLOW_PLAN_NOTICE_S, _say_compiling)
    notice.daemon = True
    notice.start()
    try:
        planner = CellPlanner(cell)
        # the compiled loops, casadi and its program load here: the process's start, not the plan's budget
        planner.warm_up(jerk=max_jerk is not None or cell.planning.max_jerk is not None)
        result = planner.plan(inp, args.tolerance, None, budget_ms)
    finally:
        notice.cancel()
    if result.code == TIMEOUT:
        return _fail(EXIT_NOT_PLANNED, ApiError(ErrorCode.TIMEOUT, result.message).line())
    if not result.ok or result.program is None or result.build is None:
        return _fail(EXIT_NOT_PLANNED, refusals.plan_failed(cell.name, result.code, result.message).line())

    out = Path(args.output)
    try:
        out.write_text(result.program.dumps(indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        return _fail(EXIT_BAD_INPUT, f"cannot write {out}: {exc.strerror or exc}")

    knots = result.build.knots
    duration_s = (knots.duration_ms + 1) / 1000.0
    summary = {
        "output": str(out),
        "cell": cell.name,
        "duration_s": duration_s,
        "time_scale": knots.time_scale,
        "records": {a.name: len(a.records) for a in knots.axes},
        "deviation_qc": {a.name: round(a.deviation_qc, 4) for a in knots.axes},
        "velocity_scale": args.velocity_scale,
        "acceleration_scale": args.acceleration_scale,
        "max_jerk": result.program.metadata.get("max_jerk"),
        # of the drives' own 0x607F / 0x60C5 (knot placement held them to the scaled ones)
        "velocity_ratio": {a.name: round(a.velocity_ratio * args.velocity_scale, 5) for a in knots.axes},
        "acceleration_ratio": {a.name: round(a.acceleration_ratio * args.acceleration_scale, 5) for a in knots.axes},
        "timing_ms": {k: round(v * 1000.0, 2) for k, v in result.timing.items()},
        "budget_ms": budget_ms,
        "optimal": result.optimal,
    }
    if result.gap is not None:
        summary["gap"] = result.gap
    if result.speed_band is not None:  # motion time given for fewer records: how much, and why
        summary["speed_band"] = result.speed_band
    if isinstance(motion, SequenceTargets) and result.plan is not None:
        summary["items"] = result.plan.details.get("items")
    if isinstance(motion, PoseTargets) and result.waypoints is not None:
        summary["motion"] = motion.motion
        summary["joint_samples"] = len(result.waypoints)
    if isinstance(motion, np.ndarray) and (warning := dropped_times_warning(args.waypoints, duration_s)):
        print(f"pvtflow plan: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{out}: {len(knots.axes)} axes, {duration_s:.3f} s, worst deviation {knots.deviation_qc:.2f} qc, "
            f"planned in {result.timing['total'] * 1000:.1f} ms"
            + ("" if result.optimal else f" (not optimal: {_not_optimal_reason(result, budget_ms)})")
        )
        for a in knots.axes:
            print(
                f"  {a.name}: {len(a.records)} records, |v| {100 * a.velocity_ratio * args.velocity_scale:.1f}% of "
                f"0x607F, |a| {100 * a.acceleration_ratio * args.acceleration_scale:.1f}% of 0x60C5, "
                f"deviation {a.deviation_qc:.2f} qc"
            )
    return EXIT_OK
