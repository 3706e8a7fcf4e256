"""Whether a program fits a cell, said so that a user can act on it: the cell the program was made for,
the shipped cell file that fits it, and what differs (one line per field: ``axes.program_mismatch``).

``pvtflow execute`` and ``pvtflow validate --config`` both report a program for another cell this way.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.configs import CELLS_DIR
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config

SHOWN_PROBLEMS = 3  # a program for another cell differs on every axis: the first few say enough


def shown_path(path: Path) -> str:
    """``path`` relative to the working directory when it is below it (shorter to type), else absolute."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path.resolve())


def fitting_cell_files(program: PvtProgram, cells_dir: Path = CELLS_DIR) -> list[Path]:
    """The shipped cell files named like the program's cell that it fits (node ids, profiles, scaling, limits)."""
    out = []
    for file in sorted(cells_dir.glob("*.yaml")):
        try:
            name = (yaml.safe_load(file.read_text(encoding="utf-8")) or {}).get("name")
        except (OSError, yaml.YAMLError, AttributeError):
            continue
        if name != program.cell:
            continue
        try:
            cell = load_cell_config(file)
        except ConfigError:
            continue
        if not program_mismatch(program, cell.ordered_axes(), cell.name):
            out.append(file)
    return out


def mismatch_lines(program: PvtProgram, cell: CellConfig) -> list[str]:
    """Why ``program`` does not fit ``cell`` (empty: it fits): for a program of another cell, that cell and
    the ``--config`` that fits it first, then the first differences; else every difference."""
    problems = program_mismatch(program, cell.ordered_axes(), cell.name)
    if not problems or program.cell == cell.name:
        return problems
    lines = [f"the program was made for cell {program.cell}, this is cell {cell.name}"]
    fits = fitting_cell_files(program)
    if fits:
        lines.append(f"it fits {' and '.join('--config ' + shown_path(f) for f in fits)}")
    else:
        lines.append(f"no shipped cell file fits it: run it with the cell file of cell {program.cell}")
    lines += problems[:SHOWN_PROBLEMS]
    if len(problems) > SHOWN_PROBLEMS:
        lines.append(f"... and {len(problems) - SHOWN_PROBLEMS} more differences")
    return lines
