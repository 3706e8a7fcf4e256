"""The ``pvtflow`` command: one sub-command per job, each in its own module.

Every sub-command module exposes ``add_parser(subparsers)`` and ``run(args) -> int``. Errors a
user can cause end as one clear line on stderr and a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

# The planner's matrices are small: a multi-threaded BLAS gains nothing on them, and its workers
# spin on the other cores after every call, taking them from the bus, simulated drives and zenoh
# threads of a service (on a 2-core controller, one whole core). Set before numpy is loaded; the
# user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# sub-command name -> module implementing it
COMMANDS: dict[str, str] = {
    "plan": "service.plan_cmd",
    "validate": "service.validate_cmd",
    "execute": "service.execute_cmd",
    "demo": "service.demo_cmd",
    "serve": "service.serve_cmd",
    "request": "service.request_cmd",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pvtflow",
        description="Time-optimal multi-axis PVT motion for CANopen CiA 402 drives.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in COMMANDS.values():
        importlib.import_module(module_name).add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args))
    except KeyboardInterrupt:
        print("pvtflow: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
