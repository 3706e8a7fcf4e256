"""The ``pvtflow`` command: one sub-command per job, each in its own module.

Every sub-command module exposes ``add_parser(subparsers)`` and ``run(args) -> int``. Errors a
user can cause end as one clear line on stderr and a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

# The planner's matrices are small: a multi-threaded BLAS gains nothing on them, and its workers
# spin on the other cores after every call, taking them from the bus, simulated drives and zenoh
# threads of a service (a controller has few cores). Set before numpy is loaded; the user's own
# setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# sub-command name -> module implementing it
COMMANDS: dict[str, str] = {
    "plan": "pvtflow.service.plan_cmd",
    "validate": "pvtflow.service.validate_cmd",
    "execute": "pvtflow.service.execute_cmd",
    "home": "pvtflow.service.home_cmd",
    "demo": "pvtflow.service.demo_cmd",
    "serve": "pvtflow.service.serve_cmd",
    "request": "pvtflow.service.request_cmd",
    "sim": "pvtflow.service.sim_cmd",
    "report": "pvtflow.service.report_cmd",
    "commission": "pvtflow.service.commission_cmd",
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or (``only``) one sub-command's: each sub-command's module loads
    what it runs on, so ``pvtflow validate`` does not load the robot model, zenoh or the bus."""
    parser = argparse.ArgumentParser(
        prog="pvtflow",
        description="Time-optimal multi-axis PVT motion for CANopen CiA 402 drives.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        if only is None or name == only:
            importlib.import_module(module_name).add_parser(sub)
    return parser


# A token that starts like a negative number ("-0.3,0.2", "-.5", "-1e-3") is a value: no option of
# pvtflow starts with a digit or a dot.
_NEGATIVE_VALUE = re.compile(r"-\.?\d")


def one_value_options(parser: argparse.ArgumentParser) -> set[str]:
    """The option strings of ``parser`` that take exactly one value (``--target Q1,...``, ``--config FILE``)."""
    return {s for a in parser._actions if a.option_strings and a.nargs is None for s in a.option_strings}


def subcommand_parsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Sub-command name -> its parser (aliases included)."""
    out: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            out.update(action.choices)
    return out


def join_negative_values(argv: Sequence[str], parser: argparse.ArgumentParser) -> list[str]:
    """``--target -0.3,0.2`` -> ``--target=-0.3,0.2`` for every option of the sub-command that takes one value.

    argparse reads a token that starts with ``-`` as an option unless it is one plain negative number,
    so a comma list that starts with a negative value ended in "expected one argument".
    """
    out = list(argv)
    subs = subcommand_parsers(parser)
    start = next((i for i, tok in enumerate(out) if tok in subs), None)
    if start is None:
        return out
    takes_value = one_value_options(subs[out[start]])
    i = start + 1
    while i < len(out) - 1:
        if out[i] == "--":
            break
        if out[i] in takes_value and _NEGATIVE_VALUE.match(out[i + 1]):
            out[i : i + 2] = [f"{out[i]}={out[i + 1]}"]
        i += 1
    return out


def can_log_problem(path: str) -> str | None:
    """Why python-can could not write a CAN log to ``path`` (None: it can), judged before anything starts.

    python-can picks the writer by the suffix (``.gz`` compresses the one before it); its own table
    of writers decides which suffixes exist.
    """
    from can.io.logger import MESSAGE_WRITERS

    file = Path(path)
    suffixes = [s.lower() for s in file.suffixes]
    suffix = suffixes[-2] if len(suffixes) >= 2 and suffixes[-1] == ".gz" else (suffixes[-1] if suffixes else "")
    if suffix not in MESSAGE_WRITERS:
        what = repr(suffix) if suffix else "(no extension)"
        known = ", ".join(sorted(MESSAGE_WRITERS))
        return f"cannot write the CAN log {path}: unknown log format {what} (python-can writes {known})"
    if file.is_dir():
        return f"cannot write the CAN log {path}: it is a directory"
    if not file.parent.is_dir():
        return f"cannot write the CAN log {path}: {file.parent} is not a directory"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(only=argv[0] if argv and argv[0] in COMMANDS else None)
    args = parser.parse_args(join_negative_values(argv, parser))
    try:
        return int(args.run(args))
    except KeyboardInterrupt:
        print("pvtflow: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
