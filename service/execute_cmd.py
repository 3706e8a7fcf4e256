"""``pvtflow execute PROGRAM.json [--config FILE] [--can-log FILE] [--real-time] [--home]``: run a PVT program.

The program is read, validated (planner.validate, the one validator) and matched against the cell
(node ids, profiles, joints, the drive limits and scaling it was planned for) before anything is
sent. A simulated cell (the default arm6 demo: ``simulated: true``) gets its simulated drives on
the virtual bus first and runs in SYNC lockstep, faster than real time (``--real-time``: on the
wall clock, as a real cell always does). A cell that requires homing is refused (``not_homed``,
nothing sent) unless ``--home``: then its axes home first (axes/master/homing.py), and the program runs
only when every axis homed; a new master process cannot know whether a drive rebooted since an
earlier homing, so it homes itself. Exit codes: 0 the program ran to its end, 1 refused
(violations, wrong cell, not homed) or ended by a fault / stop / failed homing, 2 unreadable input
(program, configuration, log file or bus).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Event, EventKind, Progress, Result, RunResult
from pvtflow.service.api import refusals
from pvtflow.service.cell_bus import CellBusError, add_bus_options, open_cell_bus, record_problem, signals_stop
from pvtflow.service.cli import can_log_problem
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config
from pvtflow.service.home_cmd import describe_homing, home_cell
from pvtflow.service.program_fit import mismatch_lines
from pvtflow.service.recording import Recorder
from pvtflow.service.validate_cmd import ProgramFileError, read_program

EXIT_OK, EXIT_FAILED, EXIT_UNREADABLE = 0, 1, 2
PROG = "pvtflow execute"
# where a program that does not start where the axes stand comes from, offline
START_HINT = "give --approach to move there first, or plan from where they stand (pvtflow plan --start home)"


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "execute",
        help="run a PVT program on a cell's drives (exit 0 done, 1 refused or faulted, 2 unreadable input)",
        description="Validate a PVT program, configure the cell's drives, start every axis on one SYNC and "
        "feed the program to its end. The default configuration is the simulated arm6 demo cell.",
    )
    p.add_argument("program", metavar="PROGRAM.json", help="the PVT program (pvtflow.pvt-program JSON)")
    add_bus_options(p)
    p.add_argument(
        "--home",
        action="store_true",
        help="home the cell's axes first when the cell requires homing (without it such a cell refuses: not_homed)",
    )
    p.add_argument(
        "--approach",
        action="store_true",
        help="where the axes are not at the program's start (e.g. after --home): first move them there, a joint "
        "move within the limits planned by the cell's planner; without it such a program is refused (start_mismatch)",
    )
    p.set_defaults(run=run)


def _fail(message: str, code: int) -> int:
    print(f"{PROG}: {message}", file=sys.stderr)
    return code


def describe(result: RunResult) -> str:
    lines = [f"{result.result.value}: {result.message}"]
    if result.start_sync is not None and result.end_sync is not None:
        ms = (result.end_sync - result.start_sync) * result.sync_period_ms
        lines.append(
            f"  started on SYNC {result.start_sync}, {ms:.0f} ms of motion, "
            f"start skew {result.start_skew_syncs} SYNC(s)"
        )
    if result.halt_sync is not None:
        lines.append(
            f"  halt sent for SYNC {result.halt_sync} ({result.halt_latency_syncs} SYNC period(s) after the event)"
        )
    for a in result.axes:
        feed = a.feed
        # the drive's record buffer (FIFO) during the run: records queued and not yet executed, least..most
        levels = (
            ""
            if feed.max_level is None
            else f", {feed.min_level}..{feed.max_level} records queued in the drive's buffer during the run"
        )
        # the names of the outcome's JSON (RunResult.to_json): position in joint units, position_qc in counts
        position = "unknown" if a.joint_position is None else f"{a.joint_position:+.6g}"
        lines.append(
            f"  {a.joint} (node {a.node_id}, {a.profile}): {a.state}, position {position} ({a.position} qc; "
            f"program end {a.target_position} qc), {feed.sent}/{feed.records} records{levels}"
        )
    return "\n".join(lines)


def approach(cell: CellConfig, group: AxisGroup, program: PvtProgram, quiet: bool) -> int | None:
    """--approach: the joint move from where the axes stand to the program's start, run to its end
    (service/approach.py); None when the program may start (moved there, or already there), else the exit."""
    from pvtflow.service.api import ApiError
    from pvtflow.service.approach import away_from_start, plan_approach
    from pvtflow.service.cell_planner import CellPlanner

    by_joint = {s.joint: s.position for s in group.status(refresh=True).axes}
    positions = [by_joint[a.joint] for a in cell.ordered_axes()]
    if not away_from_start(positions, program, cell.ordered_axes(), group.start_tolerance_qc):
        return None
    try:
        move = plan_approach(CellPlanner(cell), cell, positions, program)
    except ApiError as exc:
        return _fail(f"{exc.line()}: the program was not sent", EXIT_FAILED)
    if not quiet:
        print(f"approach: a {move.duration_ms / 1000:.3f} s joint move to the program's start", flush=True)
    moved = group.run(move)
    if not moved.ok:
        print(describe(moved), flush=True)
        return _fail(f"the approach ended {moved.result.value}: the program was not sent", EXIT_FAILED)
    return None


def run(args: argparse.Namespace) -> int:
    path = Path(args.program)
    if args.can_log and (problem := can_log_problem(args.can_log)):
        return _fail(problem, EXIT_UNREADABLE)
    if args.record and (problem := record_problem(args.record)):
        return _fail(problem, EXIT_UNREADABLE)
    try:
        program = read_program(path)  # record ranges are left to the validator (a violation, exit 1)
    except ProgramFileError as exc:
        return _fail(f"{path}: {exc}", EXIT_UNREADABLE)
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        return _fail(str(exc), EXIT_UNREADABLE)

    from pvtflow.planner.validate import validate_program

    report = validate_program(program, source=str(path))
    if not report.ok:
        print(report.format_text(), file=sys.stderr)
        refusal = refusals.validation_failed([f.format() for f in report.errors], report.to_json())
        return _fail(f"{path}: {refusal.line()}", EXIT_FAILED)
    mismatch = program_mismatch(program, cell.ordered_axes(), cell.name)
    if mismatch:
        for line in mismatch_lines(program, cell):
            print(f"  {line}", file=sys.stderr)
        return _fail(f"{path}: {refusals.wrong_cell(cell.name, mismatch, program.cell).line()}", EXIT_FAILED)

    if cell.requires_homing and not args.home:
        joints = [a.joint for a in cell.ordered_axes()]
        return _fail(refusals.not_homed(cell.name, joints, "give --home; nothing was sent").line(), EXIT_FAILED)
    quiet = bool(args.quiet)
    recorder: Recorder | None = None

    def on_event(event: Event) -> None:
        if recorder is not None:
            recorder.event(event.kind, event.message, event.joint)
        if not quiet and event.kind is not EventKind.FINISHED:
            where = f" [{event.joint}]" if event.joint else ""
            print(f"{event.kind}{where}: {event.message}", flush=True)

    def on_progress(p: Progress) -> None:
        levels = " ".join("-" if lv is None else str(lv) for lv in p.levels)
        print(f"t={p.elapsed_ms / 1000:8.3f} s  SYNC {p.sync}  records queued per drive {levels}", flush=True)

    result: RunResult | None = None
    duration_syncs = max(1, int(program.duration_ms / cell.bus.sync_period_ms))
    try:
        with open_cell_bus(cell, args.real_time, args.can_log) as bus:
            group = AxisGroup(
                bus,
                cell.ordered_axes(),
                on_event=on_event,
                on_progress=None if quiet else on_progress,
                progress_every=max(1, duration_syncs // 10),
            )
            if args.record:
                recorder = Recorder(args.record, cell).attach(bus, group)
            try:
                if args.home and cell.homing_stages():  # (a cell with nothing to home takes --home as a no-op)
                    homing = home_cell(cell, group, None, quiet, recorder)
                    print(describe_homing(homing), flush=True)
                    if not homing.ok:
                        print(f"{PROG}: the homing failed: the program was not sent", file=sys.stderr)
                        return EXIT_FAILED
                with signals_stop(group.stop):  # Ctrl-C halts the motion, the run ends STOPPED
                    if args.approach and (refused := approach(cell, group, program, quiet)) is not None:
                        return refused
                    result = group.run(program)
            finally:
                group.close()
                if recorder is not None:
                    recorder.close(result.to_json() if result is not None else None)
    except CellBusError as exc:
        return _fail(str(exc), EXIT_UNREADABLE)
    assert result is not None  # every way out of the bus without a result has returned
    if result.result is Result.REJECTED:  # refused at the start, nothing moved: the service's words
        return _fail(refusals.run_refused(result, hint=START_HINT).line(), EXIT_FAILED)
    print(describe(result), flush=True)
    if args.can_log:
        print(f"CAN log: {args.can_log} ({bus.recorder.frames} frames)")
    if recorder is not None:
        print(f"recording: {args.record} ({recorder.messages} messages)")
    return EXIT_OK if result.ok else EXIT_FAILED
