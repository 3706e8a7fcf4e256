"""``pvtflow validate PROGRAM.json... [--config CELL] [--plot OUT.png] [--json]``: the offline validation tool.

With ``--config`` each program must also fit the cell file (``service/program_fit.py``: the cell it was
made for, the shipped file that fits, one line per differing field), so that a program is known to run
on a cell before any bus opens. Exit codes: 0 every program valid (and fits), 1 violations found (or a
program does not fit), 2 unreadable input
(missing file, not JSON, not a PVT program). A directory stands for every ``*.json`` in it; with
several programs a progress bar runs on stderr and a summary table closes the report.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TextIO

from pvtflow.axes.drive.program import ProgramFormatError, PvtProgram
from pvtflow.planner.validate import Rule, Severity, ValidationReport, validate_program
from pvtflow.service.cli_options import add_json

EXIT_VALID, EXIT_VIOLATIONS, EXIT_UNREADABLE = 0, 1, 2


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "validate",
        help="check PVT programs against their drives' rules (exit 0 valid, 1 violations, 2 unreadable)",
        description="Check PVT programs (files or folders of *.json) against the rules their drives enforce, "
        "on the drives' own reconstruction of the records.",
    )
    p.add_argument("programs", nargs="+", metavar="PROGRAM", help="program file(s) or folder(s) of *.json")
    add_json(p)
    p.add_argument(
        "--config",
        metavar="CELL",
        help="also check that every program fits this cell file, or shipped cell by name (node ids, profiles, "
        "scaling, drive limits): exit 0 only when each is valid and fits it",
    )
    p.add_argument(
        "--plot",
        metavar="OUT.png",
        help="write position, velocity and acceleration of every axis against its limits (one program only)",
    )
    p.set_defaults(run=run)


@dataclass(frozen=True)
class Outcome:
    """One input file: its report, or why it could not be read."""

    path: str
    report: ValidationReport | None = None
    program: PvtProgram | None = None
    problem: str | None = None
    cell_problems: tuple[str, ...] = ()  # why it does not fit the --config cell (empty: it fits, or no --config)

    @property
    def exit_code(self) -> int:
        if self.report is None:
            return EXIT_UNREADABLE
        return EXIT_VALID if self.report.ok and not self.cell_problems else EXIT_VIOLATIONS


class ProgramFileError(ValueError):
    """A program file that cannot be read; the message is the reason in one line, without the file's name."""


def read_program(path: Path) -> PvtProgram:
    """The program in ``path``, with record ranges unchecked (the validator reports them as violations).

    The one reader of program files for every command (validate, execute, request), so that each says
    the same about the same file: ``file not found``, ``is a directory``, ``not JSON: ...``,
    ``not a PVT program: ...`` (ProgramFileError).
    """
    if path.is_dir():
        raise ProgramFileError("is a directory, not a program file")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ProgramFileError("file not found") from None
    except OSError as exc:
        raise ProgramFileError(exc.strerror or str(exc)) from None
    try:
        return PvtProgram.loads(data, check_ranges=False)
    except ProgramFormatError as exc:
        raise ProgramFileError(str(exc)) from None


def check_file(path: Path) -> Outcome:
    if path.is_dir():  # a folder stands for its *.json: here it had none
        return Outcome(str(path), problem="is a directory with no *.json program in it")
    try:
        program = read_program(path)
    except ProgramFileError as exc:
        return Outcome(str(path), problem=str(exc))
    return Outcome(str(path), validate_program(program, source=str(path)), program)


def expand(inputs: list[str]) -> list[Path]:
    """Files as given; a folder stands for its *.json files (sorted)."""
    out: list[Path] = []
    for name in inputs:
        p = Path(name)
        if p.is_dir():
            found = sorted(x for x in p.glob("*.json") if x.is_file())
            out.extend(found if found else [p])  # an empty folder is reported as unreadable
        else:
            out.append(p)
    return out


class Progress:
    """A one-line progress bar on a terminal (nothing when stderr is not one)."""

    def __init__(self, total: int, stream: TextIO) -> None:
        self.total = total
        self.stream = stream
        self.enabled = total > 1 and stream.isatty()

    def update(self, done: int, name: str) -> None:
        if not self.enabled:
            return
        width = 30
        filled = int(width * done / self.total)
        self.stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{self.total} {name[-40:]:<40}")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * 80 + "\r")
            self.stream.flush()


def summary_table(outcomes: list[Outcome]) -> str:
    """One line per program: verdict, error and warning counts, worst |v| and |a| ratios."""
    rows = [("program", "result", "errors", "warnings", "max v/vmax", "max a/amax")]
    for o in outcomes:
        if o.report is None:
            rows.append((o.path, "UNREADABLE", "-", "-", "-", "-"))
            continue
        r = o.report
        v = max((a.velocity_ratio or 0.0 for a in r.axes), default=0.0)
        a = max((a.acceleration_ratio or 0.0 for a in r.axes), default=0.0)
        rows.append(
            (
                o.path,
                "INVALID" if not r.ok else ("NO FIT" if o.cell_problems else "valid"),
                str(len(r.errors)),
                str(len(r.warnings)),
                f"{100 * v:.1f}%",
                f"{100 * a:.1f}%",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True)))
        for row in rows
    ]
    lines.insert(1, "-" * len(lines[0]))
    n_valid = sum(o.exit_code == EXIT_VALID for o in outcomes)
    n_bad = sum(o.exit_code == EXIT_VIOLATIONS for o in outcomes)
    n_unread = sum(o.exit_code == EXIT_UNREADABLE for o in outcomes)
    lines.append(f"{len(outcomes)} program(s): {n_valid} valid, {n_bad} with violations, {n_unread} unreadable")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    paths = expand(list(args.programs))
    if args.plot and len(paths) != 1:
        print("pvtflow validate: --plot needs exactly one program", file=sys.stderr)
        return EXIT_UNREADABLE
    cell = None
    if args.config is not None:
        from pvtflow.service.config import ConfigError, load_cell_config

        try:
            cell = load_cell_config(args.config)
        except ConfigError as exc:
            print(f"pvtflow validate: {exc}", file=sys.stderr)
            return EXIT_UNREADABLE
    progress = Progress(len(paths), sys.stderr)
    outcomes: list[Outcome] = []
    for i, path in enumerate(paths):
        progress.update(i, str(path))
        outcome = check_file(path)
        if cell is not None and outcome.program is not None:
            from pvtflow.service.program_fit import mismatch_lines

            outcome = replace(outcome, cell_problems=tuple(mismatch_lines(outcome.program, cell)))
        outcomes.append(outcome)
    progress.update(len(paths), "")
    progress.close()

    for o in outcomes:
        if o.problem is not None:
            print(f"pvtflow validate: {o.path}: cannot read a PVT program: {o.problem}", file=sys.stderr)
    if args.json:
        reports = [
            _report_json(o, cell.name if cell is not None else None)
            if o.report
            else {"source": o.path, "ok": False, "unreadable": o.problem}
            for o in outcomes
        ]
        print(json.dumps(reports[0] if len(reports) == 1 else reports, indent=2))
    else:
        for o in outcomes:
            if o.report is not None:
                print(o.report.format_text())
            if cell is not None and o.report is not None:
                print(_fit_text(o, cell.name))
        if len(outcomes) > 1:
            print()
            print(summary_table(outcomes))

    if args.plot and outcomes[0].report is not None and outcomes[0].program is not None:
        try:
            plot_program(outcomes[0].program, outcomes[0].report, Path(args.plot))
        except OSError as exc:
            print(f"pvtflow validate: cannot write the plot {args.plot}: {exc.strerror or exc}", file=sys.stderr)
            return EXIT_UNREADABLE
        if not args.json:
            print(f"plot written to {args.plot}")
    return max(o.exit_code for o in outcomes)


def _fit_text(o: Outcome, cell: str) -> str:
    if not o.cell_problems:
        return f"{o.path}: fits cell {cell}"
    return "\n".join([f"{o.path}: does not fit cell {cell}:", *(f"  {line}" for line in o.cell_problems)])


def _report_json(o: Outcome, cell: str | None) -> dict[str, Any]:
    assert o.report is not None
    out = o.report.to_json()
    if cell is not None:
        out["fits"] = {"cell": cell, "ok": not o.cell_problems, "problems": list(o.cell_problems)}
    return out


def plot_program(program: PvtProgram, report: ValidationReport, out: Path) -> None:
    """PNG: per axis, position / velocity / acceleration of the drive's reconstruction against the
    limits, findings shaded red (errors) or orange (warnings), so a person sees where it goes wrong."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n = len(program.axes)
    fig, grid = plt.subplots(n, 3, figsize=(15, 2.6 * n + 0.8), squeeze=False, sharex=True)
    for row, axis in zip(grid, program.axes, strict=True):
        r = axis.records
        if len(r) < 2 or r[0, 2] < 1 or (r[:, 2] < 0).any():
            row[0].text(
                0.5, 0.5, f"{axis.joint}: no reconstruction (bad record times)", ha="center", transform=row[0].transAxes
            )
            continue
        recon = axis.reconstruction()
        t = np.linspace(0.0, recon.end_time, max(int(recon.end_time * 4), 2))
        s, lim = axis.scaling, axis.limits
        curves = (
            (recon.position(t), "position [qc]", (lim.min_position_qc, lim.max_position_qc), None),
            (
                s.qc_per_ms_to_rpm(recon.velocity(t)),
                "velocity [rpm]",
                lim.max_profile_velocity_rpm,
                lim.profile_velocity_rpm,
            ),
            (
                s.qc_per_ms2_to_rpm_s(recon.acceleration(t)),
                "acceleration [rpm/s]",
                lim.max_acceleration_rpm_s,
                lim.profile_acceleration_rpm_s,
            ),
        )
        rules = (
            {Rule.POSITION_LIMIT},
            {Rule.VELOCITY_LIMIT, Rule.PROFILE_VELOCITY},
            {Rule.ACCELERATION_LIMIT, Rule.PROFILE_ACCELERATION},
        )
        for ax, (y, label, limit, profile), shown in zip(row, curves, rules, strict=True):
            ax.plot(t, y, lw=1.0, color="tab:blue")
            if isinstance(limit, tuple):
                for v in limit:
                    ax.axhline(v, color="red", lw=0.8, ls="--")
            else:
                ax.axhline(limit, color="red", lw=0.8, ls="--", label="limit")
                ax.axhline(-limit, color="red", lw=0.8, ls="--")
                if profile is not None:
                    ax.axhline(profile, color="orange", lw=0.8, ls=":")
                    ax.axhline(-profile, color="orange", lw=0.8, ls=":")
            for f in report.findings:
                if f.axis != axis.joint or f.time_ms is None or f.record is None:
                    continue
                if f.rule not in shown:
                    continue
                k = f.record
                ax.axvspan(
                    recon.start[k],
                    recon.start[k] + recon.duration[k],
                    alpha=0.3,
                    color="red" if f.severity is Severity.ERROR else "orange",
                )
            ax.set_ylabel(label, fontsize=8)
            ax.tick_params(labelsize=7)
        row[0].set_title(f"{axis.joint} ({axis.profile}, node {axis.node_id})", fontsize=9, loc="left")
    for ax in grid[-1]:
        ax.set_xlabel("time from the start SYNC [ms]", fontsize=8)
    verdict = "VALID" if report.ok else f"INVALID: {len(report.errors)} error(s)"
    fig.suptitle(f"{report.source or program.cell}: {verdict}, {len(report.warnings)} warning(s)", fontsize=11)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)
