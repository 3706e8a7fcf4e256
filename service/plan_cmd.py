"""``pvtflow plan --config FILE --waypoints FILE -o PROGRAM.json``: plan a motion, write its program.

Exit codes: 0 written, 1 the waypoints cannot be planned on this cell (the message says why),
2 unreadable input (configuration, waypoint file) or the output cannot be written.

:class:`CellPlanner` is the whole pipeline for one cell (waypoints -> TOPP-RA trajectory -> knots ->
validated program), built once per cell by the service; :func:`plan_cell_program` is a one-off call
of it, for this command.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from axes.program import PvtProgram
from planner.build import BuildError, BuildOutput, build_program
from planner.cartesian import placement_pose
from planner.knots import DriveAxis, KnotOptions
from planner.limits import check_max_jerk, check_scale
from planner.path import PlanResult
from planner.plan import PlanInput, Planner, PlanOutput
from service.config import CellConfig, ConfigError, load_cell_config
from service.waypoints import PoseTargets, WaypointError, load_motion

EXIT_OK, EXIT_NOT_PLANNED, EXIT_BAD_INPUT = 0, 1, 2


@dataclass(frozen=True)
class CellPlan:
    """The outcome of planning on a cell: a program, or the reason (``code``, ``message``)."""

    code: str  # "ok", a planner.plan.PlanOutcome value, or "program_error"
    message: str = ""
    program: PvtProgram | None = None
    plan: PlanOutput | None = None
    build: BuildOutput | None = None
    timing: dict[str, float] = field(default_factory=dict)  # s: plan (ik: its inverse kinematics), knots, total
    waypoints: NDArray[np.float64] | None = None  # the joint waypoints planned through (poses: the IK samples)
    details: dict[str, Any] = field(default_factory=dict)  # where it failed (PlanError details)

    @property
    def ok(self) -> bool:
        return self.program is not None


def plan_input_for_cell(cell: CellConfig, waypoints: ArrayLike, gridpoints: int | None = None) -> PlanInput:
    """The planner's input for ``cell``: its joint limits, model and planning options."""
    return PlanInput(
        waypoints=waypoints,
        limits=cell.joint_limits(),
        model=cell.model,
        tcp_frame=cell.planning.tcp_frame,
        max_tcp_speed=cell.planning.max_tcp_speed,
        torque_limits=cell.planning.torque_limits,
        gridpoints=gridpoints,
        max_tcp_angular_speed=cell.planning.max_tcp_angular_speed,
        max_jerk=cell.planning.max_jerk,
    )


class CellPlanner:
    """The planning pipeline of one cell, built once: its Planner (toppra constraints), drive axes
    and default tolerance. A service keeps one per cell, so a request pays for planning only.

    Not for concurrent use: the Planner's constraint objects are shared between calls (the service
    plans on one worker thread).
    """

    def __init__(self, cell: CellConfig, gridpoints: int | None = None) -> None:
        inp = plan_input_for_cell(cell, (), gridpoints)  # no waypoints yet: the cell's side of the input
        self.cell = cell
        self.limits = inp.limits
        self.axes = tuple(DriveAxis.from_config(a) for a in cell.ordered_axes())
        self.tolerance_qc = cell.planning.position_tolerance_qc
        self.planner: Planner | None = None
        self.setup_error = ""
        try:
            self.planner = Planner(
                inp.limits,
                inp.model,
                inp.tcp_frame,
                inp.max_tcp_speed,
                inp.torque_limits,
                inp.gridpoints,
                inp.max_tcp_angular_speed,
                inp.max_jerk,
            )
        except ValueError as exc:  # a planning option the planner refuses: every plan says so
            self.setup_error = str(exc)

    def warm_up(self, jerk: bool | None = None) -> None:
        """Plan a short move in the middle of the joint ranges and drop it.

        The first plan of a process loads the planner's compiled loops (numba's cache; on a new
        machine it compiles them first, some seconds, once). A service pays that at start, not
        with its first request. ``jerk`` (default: where the cell sets a jerk limit): the same move
        jerk-limited too, which loads casadi and builds its program for a short path (0.2-0.3 s).
        """
        if self.planner is None:
            return
        lo, hi = self.limits.lower, self.limits.upper
        a, b = lo + 0.45 * (hi - lo), lo + 0.55 * (hi - lo)
        self.plan(np.array([a, b]))
        if jerk or (jerk is None and self.planner.max_jerk is not None):
            self.plan(np.array([a, b]), max_jerk=10.0 * self.limits.acceleration)
        if self.planner.poses is not None:  # and the inverse kinematics' compiled steps
            self.plan_poses(a, [placement_pose(self.planner.poses.ik.fk(b))])

    def plan(
        self,
        waypoints: ArrayLike,
        tolerance_qc: float | None = None,
        metadata: dict[str, Any] | None = None,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
        max_jerk: ArrayLike | None = None,
    ) -> CellPlan:
        """Waypoints (N, dof, the cell's joint order) -> a validated PVT program for the cell's drives.

        ``velocity_scale``, ``acceleration_scale`` (0, 1]: the speed override, for the plan and for
        the knots (``build_program``); recorded in the program's metadata. ``max_jerk`` (one per
        joint, joint units / s^3): the jerk limit of this plan instead of the cell's; the one held is
        recorded in the metadata (``max_jerk``, null for a joint without one).

        ``timing`` (s): ``plan`` the timing (with a jerk limit, ``topp`` and ``jerk`` its two parts), ``knots``
        knot placement + validation, ``total``, and
        ``cpu`` the CPU time of this thread over the whole call (``total - cpu``: time the thread
        waited for the CPU or the GIL).
        """
        start, cpu = time.perf_counter(), time.thread_time()
        if self.planner is None:
            return CellPlan(PlanResult.INVALID_INPUT.value, self.setup_error, None, None, None, {"plan": 0.0})
        out = self.planner.plan(waypoints, velocity_scale, acceleration_scale, max_jerk)
        return self._build(out, start, cpu, tolerance_qc, metadata, velocity_scale, acceleration_scale)

    def plan_poses(
        self,
        start_joints: ArrayLike,
        poses: ArrayLike,
        motion: str = "linear",
        tolerance_qc: float | None = None,
        metadata: dict[str, Any] | None = None,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
        max_jerk: ArrayLike | None = None,
    ) -> CellPlan:
        """Tool poses (N, 7) from joint positions ``start_joints`` -> a validated PVT program, like
        ``plan`` (``timing["ik"]``: the inverse kinematics' part of ``plan``)."""
        start, cpu = time.perf_counter(), time.thread_time()
        if self.planner is None:
            return CellPlan(PlanResult.INVALID_INPUT.value, self.setup_error, None, None, None, {"plan": 0.0})
        out = self.planner.plan_poses(start_joints, poses, motion, velocity_scale, acceleration_scale, max_jerk)
        extra = {"motion": motion}
        return self._build(out, start, cpu, tolerance_qc, metadata, velocity_scale, acceleration_scale, extra)

    def _build(
        self,
        out: PlanOutput,
        start: float,
        cpu: float,
        tolerance_qc: float | None,
        metadata: dict[str, Any] | None,
        velocity_scale: float = 1.0,
        acceleration_scale: float = 1.0,
        extra: dict[str, Any] | None = None,
    ) -> CellPlan:
        """The program of a planned trajectory (or the planner's refusal as a CellPlan)."""
        t_plan = time.perf_counter() - start
        timing = {"plan": t_plan}
        for key, name in (("ik_s", "ik"), ("topp_s", "topp"), ("jerk_s", "jerk")):
            if key in out.details:
                timing[name] = float(out.details[key])  # type: ignore[arg-type]
        if not out.ok or out.trajectory is None:
            return CellPlan(out.result.value, out.message, None, out, None, timing, details=dict(out.details))
        points = out.trajectory.path.points
        tol = self.tolerance_qc if tolerance_qc is None else tolerance_qc
        meta = {**(extra or {}), **(metadata or {})}
        if "max_jerk" in out.details:
            meta["max_jerk"] = out.details["max_jerk"]
        try:
            built = build_program(
                out.trajectory,
                self.axes,
                self.cell.name,
                KnotOptions(tolerance_qc=tol),
                meta,
                float(velocity_scale),
                float(acceleration_scale),
            )
        except (BuildError, ValueError) as exc:
            return CellPlan("program_error", str(exc), None, out, None, timing, points)
        total = time.perf_counter() - start
        timing.update({"knots": total - t_plan, "total": total, "cpu": time.thread_time() - cpu})
        return CellPlan("ok", "", built.program, out, built, timing, points)


def plan_cell_program(
    cell: CellConfig,
    waypoints: ArrayLike,
    tolerance_qc: float | None = None,
    metadata: dict[str, Any] | None = None,
    velocity_scale: float = 1.0,
    acceleration_scale: float = 1.0,
    max_jerk: ArrayLike | None = None,
) -> CellPlan:
    """One-off planning on ``cell`` (the CLI): a CellPlanner built for this call."""
    return CellPlanner(cell).plan(waypoints, tolerance_qc, metadata, velocity_scale, acceleration_scale, max_jerk)


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "plan",
        help="plan a time-optimal motion through waypoints (or tool poses) and write its PVT program",
        description="Plan a time-optimal motion through the waypoints (or the tool poses: straight tool lines "
        "or joint moves, solved by inverse kinematics) on a cell and write the PVT program "
        "(validated: the drives' own reconstruction stays inside their limits). Exit 0 written, "
        "1 cannot be planned, 2 unreadable input.",
    )
    p.add_argument("--config", metavar="FILE", help="cell configuration YAML (default: the demo arm cell)")
    p.add_argument(
        "--waypoints",
        metavar="FILE",
        required=True,
        help="waypoints: pvtflow JSON, or a ROS JointTrajectory as JSON or YAML; or tool poses: "
        '{"poses": [[x, y, z, qx, qy, qz, qw], ...], "motion": "linear" or "joint", "start": [joint values]}',
    )
    p.add_argument("-o", "--output", metavar="PROGRAM.json", required=True, help="where to write the program")
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
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    p.set_defaults(run=run)


def _numbers(text: str) -> list[float] | str:
    """A comma-separated list of numbers; the text itself where it is not one (check_max_jerk words it)."""
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        return text


def _fail(code: int, message: str) -> int:
    print(f"pvtflow plan: {message}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        return _fail(EXIT_BAD_INPUT, str(exc))
    try:
        motion = load_motion(args.waypoints, cell.joint_names)
    except WaypointError as exc:
        return _fail(EXIT_BAD_INPUT, str(exc))
    if isinstance(motion, PoseTargets) and motion.start is None:
        return _fail(
            EXIT_BAD_INPUT,
            f"{args.waypoints}: start: planning offline needs the joint positions the motion starts from "
            '(a list of joint values; "current" is for a running service)',
        )
    if args.tolerance is not None and not args.tolerance >= 0.5:
        return _fail(EXIT_BAD_INPUT, f"--tolerance must be at least 0.5 count, got {args.tolerance}")
    for option, value in (("--velocity-scale", args.velocity_scale), ("--acceleration-scale", args.acceleration_scale)):
        try:
            check_scale(option, value)
        except ValueError as exc:
            return _fail(EXIT_BAD_INPUT, str(exc))

    max_jerk = None
    if args.max_jerk is not None:
        try:
            max_jerk = check_max_jerk("--max-jerk", _numbers(args.max_jerk), len(cell.joint_names))
        except ValueError as exc:
            return _fail(EXIT_BAD_INPUT, str(exc))

    scales: dict[str, Any] = {
        "velocity_scale": args.velocity_scale,
        "acceleration_scale": args.acceleration_scale,
        "max_jerk": max_jerk,
    }
    if isinstance(motion, PoseTargets):
        assert motion.start is not None
        result = CellPlanner(cell).plan_poses(motion.start, motion.poses, motion.motion, args.tolerance, **scales)
    else:
        result = plan_cell_program(cell, motion, args.tolerance, **scales)
    if not result.ok or result.program is None or result.build is None:
        why = f"({result.code}): {result.message}"
        return _fail(EXIT_NOT_PLANNED, f"cannot plan this motion on cell {cell.name!r} {why}")

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
    }
    if isinstance(motion, PoseTargets) and result.waypoints is not None:
        summary["motion"] = motion.motion
        summary["joint_samples"] = len(result.waypoints)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{out}: {len(knots.axes)} axes, {duration_s:.3f} s, worst deviation {knots.deviation_qc:.2f} qc, "
            f"planned in {result.timing['total'] * 1000:.1f} ms"
        )
        for a in knots.axes:
            print(
                f"  {a.name}: {len(a.records)} records, |v| {100 * a.velocity_ratio * args.velocity_scale:.1f}% of "
                f"0x607F, |a| {100 * a.acceleration_ratio * args.acceleration_scale:.1f}% of 0x60C5, "
                f"deviation {a.deviation_qc:.2f} qc"
            )
    return EXIT_OK
