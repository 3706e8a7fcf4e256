"""The options several ``pvtflow`` commands share, each declared once: one flag, one meaning, one help.

A command adds the ones it takes (``add_config(p)``); an option whose meaning differs from command to
command (``validate --config``: a cell to check a program against, no default; ``request --json``: a
raw payload) is no shared option and stays with its command.
"""

from __future__ import annotations

import argparse


def add_config(p: argparse.ArgumentParser) -> None:
    """``--config FILE``: the cell to work on, a file or a shipped cell's name (service.config.reader.cell_file)."""
    p.add_argument(
        "--config",
        metavar="FILE",
        help="cell configuration YAML, or a shipped cell's name (arm6, gantry3, ...: configs/cells) "
        "(default: the arm6 demo cell)",
    )


def add_can_log(p: argparse.ArgumentParser) -> None:
    """``--can-log FILE``: every frame on the cell's bus, in a format python-can writes."""
    p.add_argument("--can-log", metavar="FILE", help="record every CAN frame (.log candump, .asc or .blf)")


def add_real_time(p: argparse.ArgumentParser) -> None:
    """``--real-time``: a simulated cell's SYNC on the wall clock, as a real cell's always is."""
    p.add_argument(
        "--real-time",
        action="store_true",
        help="a simulated cell runs SYNC on the wall clock, as a real cell does (default there: lockstep with "
        "the simulated drives, as fast as they answer, so that a busy machine slows the simulation down "
        "instead of faulting it)",
    )


def add_json(p: argparse.ArgumentParser) -> None:
    """``--json``: the command's answer as one JSON document on stdout, for tools."""
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout instead of text")
