"""``pvtflow commission [--config CELL] [--json] [--can-log FILE] [--real-time]``: what each drive is.

Opens the cell's bus as ``pvtflow execute`` does (its simulated drives first where the cell is
simulated), reads every drive over SDO (axes/master/commission.py: identity, supported modes, encoder,
polarity, motor speed, the limit objects as stored, heartbeat, PDO mappings, error history) and
prints, per axis, each check with what the cell expects and what the drive holds. Nothing is
written to any drive and nothing moves. Each check is ok, mismatch or not checked (the drive lacks
the object, named; never counted as ok). Exit codes: 0 every drive agrees with the cell, 1 a
mismatch or a check the cell requires (``commission_requires``, a setting such as the TPDO event
timer) that cannot be made (each named: object, expected, found), 2 it cannot start (cell file, log
file, bus).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from pvtflow.axes.master.commission import Check, CheckKind, CommissionReport, Status, commission
from pvtflow.axes.master.link import AxisLink, DriveError
from pvtflow.axes.master.profiles import profile_for
from pvtflow.service.cell_bus import CellBusError, open_cell_bus
from pvtflow.service.cli import can_log_problem
from pvtflow.service.cli_options import add_can_log, add_config, add_json, add_real_time
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config

EXIT_OK, EXIT_MISMATCH, EXIT_CANNOT_START = 0, 1, 2
PROG = "pvtflow commission"


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "commission",
        help="read what each drive is and compare it with the cell (exit 0 agree, 1 mismatch, 2 cannot start)",
        description="Read identity, supported modes, encoder, polarity, motor speed, limit objects, heartbeat, "
        "PDO mappings and error history from every drive of the cell over SDO and compare them with the cell "
        "file. Nothing is written, nothing moves.",
    )
    add_config(p)
    add_json(p)
    add_can_log(p)
    add_real_time(p)
    p.set_defaults(run=run)


def commission_cell(cell: CellConfig, real_time: bool = False, can_log: str | None = None) -> CommissionReport:
    """The report of the cell's drives (CellBusError: the bus cannot open)."""
    with open_cell_bus(cell, real_time, can_log) as bus:
        links = [AxisLink(bus, axis) for axis in cell.ordered_axes()]
        return commission(links, [profile_for(link) for link in links])


def format_report(cell: CellConfig, report: CommissionReport) -> str:
    bad = sum(1 for a in report.axes if not a.ok)
    lines = [
        f"cell {cell.name}: {len(report.axes)} drives, "
        + ("every one as the cell expects" if report.ok else f"{bad} not as the cell expects")
        + f" ({report.sdo_transfers} SDO round trips)"
    ]
    for a in report.axes:
        wrong = sum(1 for c in a.mismatches if c.status is Status.MISMATCH)
        parts = [f"{wrong} mismatch" + ("es" if wrong > 1 else "")] if wrong else []
        if a.not_checked:
            required = sum(1 for c in a.not_checked if c.required)
            parts.append(f"{len(a.not_checked)} not checked" + (f" ({required} required)" if required else ""))
        state = ("ok" if a.ok else "FAILED") + (": " + ", ".join(parts) if parts else "")
        lines.append(f"{a.joint} (node {a.node_id}, {a.profile}): {state}")
        for c in a.checks:
            lines.append(f"  {_mark(c):11} {c.object} {c.name}: expected {c.expected}; found {c.found}")
    return "\n".join(lines)


def _mark(c: Check) -> str:
    """MISMATCH / NOT CHECKED (the drive lacks the object; upper case where the cell requires it) / ok / info."""
    if c.status is Status.NOT_CHECKED:
        return "NOT CHECKED" if c.required else "not checked"
    if c.status is Status.MISMATCH and c.kind is not CheckKind.INFO:
        return "MISMATCH"
    return "info" if c.kind is CheckKind.INFO else "ok"


def run(args: argparse.Namespace) -> int:
    if args.can_log and (problem := can_log_problem(args.can_log)):
        print(f"{PROG}: {problem}", file=sys.stderr)
        return EXIT_CANNOT_START
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    try:
        report = commission_cell(cell, args.real_time, args.can_log)
    except (CellBusError, DriveError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    if args.json:
        print(json.dumps({"cell": cell.name, **report.to_json()}, indent=2))
    else:
        print(format_report(cell, report))
        for a in report.axes:
            for c in a.mismatches:
                print(f"{PROG}: {a.joint} (node {a.node_id}): {c}", file=sys.stderr)
    return EXIT_OK if report.ok else EXIT_MISMATCH
