"""``pvtflow home [--config FILE] [--joints J1,...] [--can-log FILE] [--quiet] [--real-time]``: home a cell.

Without the service, as ``pvtflow execute`` runs a program: the cell's drives are configured (their
homing settings written), then the axes home in CiA 402 homing mode 6 in the cell's ``homing_order``
(axes/master/homing.py). A simulated cell gets its simulated drives first (each axis powered up somewhere
on its machine, seeded) and runs in SYNC lockstep (``--real-time``: on the wall clock). Exit codes:
0 every axis asked for is homed, 1 refused (nothing to home) or the homing failed (homing error,
timeout, fault: every axis halted), 2 unreadable input (configuration, an axis the cell does not
have, log file or bus).

The homing holds for the drives of this process only: a master that starts afresh cannot know that
a drive has not rebooted since, so ``pvtflow execute`` on a cell that requires homing homes it
itself (``--home``).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.homing import CellHoming, HomingEventKind, HomingOutcome, HomingRequestError
from pvtflow.service.cell_bus import CellBusError, add_bus_options, open_cell_bus, record_problem
from pvtflow.service.cli import can_log_problem
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config
from pvtflow.service.recording import Recorder

EXIT_OK, EXIT_FAILED, EXIT_UNREADABLE = 0, 1, 2
PROG = "pvtflow home"


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "home",
        help="home a cell's axes without the service (exit 0 homed, 1 refused or failed, 2 unreadable input)",
        description="Configure the cell's drives and home its axes (CiA 402 homing mode 6) in the cell's "
        "homing_order. The default configuration is the simulated arm6 demo cell (nothing to home).",
    )
    p.add_argument("--joints", metavar="J1,J2,...", help="the axes to home (default: every axis with homing)")
    add_bus_options(p)
    p.set_defaults(run=run)


def describe_homing(outcome: HomingOutcome) -> str:
    """The outcome in a few lines: the result, then each axis's method, time and position."""
    lines = [f"{outcome.result.value}: {outcome.message}"]
    for a in outcome.axes:
        took = "-" if a.time_s is None else f"{a.time_s:.3f} s"
        lines.append(
            f"  {a.joint} (node {a.node_id}, method {a.method}): {'homed' if a.homed else 'not homed'}, "
            f"{took}, position {a.position_qc} qc"
        )
    return "\n".join(lines)


def home_cell(
    cell: CellConfig, group: AxisGroup, joints: list[str] | None, quiet: bool, recorder: Recorder | None = None
) -> HomingOutcome:
    """Home ``joints`` (None: all with homing) of the cell on an open group, printing what happens
    (and recording it). Raises HomingRequestError for an axis the cell does not have or that has nothing to home."""
    stages = cell.homing_stages(joints)

    def on_event(kind: HomingEventKind, message: str, joint: str | None) -> None:
        if recorder is not None:
            recorder.event(str(kind), message, joint)
        if not quiet:
            where = f" [{joint}]" if joint else ""
            print(f"{kind}{where}: {message}", flush=True)

    return CellHoming(group, on_event=on_event).run(stages)


def run(args: argparse.Namespace) -> int:
    if args.can_log and (problem := can_log_problem(args.can_log)):
        print(f"{PROG}: {problem}", file=sys.stderr)
        return EXIT_UNREADABLE
    if args.record and (problem := record_problem(args.record)):
        print(f"{PROG}: {problem}", file=sys.stderr)
        return EXIT_UNREADABLE
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    joints = [j.strip() for j in args.joints.split(",")] if args.joints else None
    try:
        stages = cell.homing_stages(joints)
    except HomingRequestError as exc:
        print(f"{PROG}: cell {cell.name}: {exc}: nothing moved", file=sys.stderr)
        return EXIT_UNREADABLE
    if not stages:
        print(f"{PROG}: cell {cell.name} has no axis to home (no homing section): nothing moved", file=sys.stderr)
        return EXIT_FAILED
    try:
        with open_cell_bus(cell, args.real_time, args.can_log) as bus:
            group = AxisGroup(bus, cell.ordered_axes())
            recorder = Recorder(args.record, cell, kind="homing").attach(bus, group) if args.record else None
            outcome: HomingOutcome | None = None
            try:
                # Ctrl-C: every axis halted, then exit 130
                outcome = home_cell(cell, group, joints, args.quiet, recorder)
            finally:
                group.close()
                if recorder is not None:
                    recorder.close(outcome.to_json() if outcome is not None else None)
    except CellBusError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    print(describe_homing(outcome), flush=True)
    if args.can_log:
        print(f"CAN log: {args.can_log} ({bus.recorder.frames} frames)")
    if recorder is not None:
        print(f"recording: {args.record} ({recorder.messages} messages)")
    return EXIT_OK if outcome.ok else EXIT_FAILED
