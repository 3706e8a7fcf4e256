"""``pvtflow request plan|validate|execute|stop|status|recover|home ...``: talk to a running service over zenoh.

Also :class:`Client`, the small Python client the demo, the benchmarks and the tests use: one
zenoh session, ``request(cell, op, payload)`` -> :class:`Reply` (``ok``, ``data``, ``cell``), and
``follow(cell, on_sample)`` for the publications. Exit codes of the command: 0 the service
answered with a result, 1 it answered with an error (code and message on stderr), 2 no answer
(nobody serves the cell, unreachable endpoint) or unusable input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from pvtflow.planner.limits import check_scale
from pvtflow.service.api import QUERYABLES, key
from pvtflow.service.server import (
    DEFAULT_ENDPOINT,
    ZenohConfigError,
    client_config,
    config_endpoints,
    load_zenoh_config,
    zenoh_message,
)
from pvtflow.service.validate_cmd import ProgramFileError, read_program
from pvtflow.service.waypoints import PoseTargets, WaypointError, dropped_times_warning, load_motion

EXIT_OK, EXIT_ERROR_REPLY, EXIT_NO_ANSWER = 0, 1, 2
PROG = "pvtflow request"


@dataclass(frozen=True)
class Reply:
    ok: bool
    data: Any  # the reply JSON, or {"error": {...}} for an error reply
    cell: str | None  # from the reply's key expression pvtflow/<cell>/<op>

    @property
    def error_code(self) -> str | None:
        if self.ok or not isinstance(self.data, dict):
            return None
        return str(self.data.get("error", {}).get("code"))


class Client:
    """A zenoh session that talks to pvtflow services (default: a client of tcp/127.0.0.1:7447).

    zenoh.open fails (ZError) when a client cannot reach any of its endpoints or is refused; a ``connect``
    that is no endpoint at all is a ValueError (:func:`check_endpoint`).
    """

    def __init__(self, config: zenoh.Config | None = None, *, connect: str | None = None) -> None:
        if config is None:
            config = client_config([check_endpoint(connect or DEFAULT_ENDPOINT)])
        self.session = zenoh.open(config)

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def replies(self, cell: str, op: str, payload: Any = None, timeout: float = 10.0) -> list[Reply]:
        """Every reply to one request (several with ``cell="*"``). ``payload``: JSON value or raw bytes."""
        return list(self._replies(cell, op, payload, timeout))

    def _replies(self, cell: str, op: str, payload: Any, timeout: float) -> Iterator[Reply]:
        """The replies as they arrive (zenoh's FIFO handler: the loop blocks in Rust, without the GIL)."""
        if payload is None:
            body: bytes | None = None
        elif isinstance(payload, bytes | bytearray):
            body = bytes(payload)
        else:
            body = json.dumps(payload).encode()
        for r in self.session.get(
            key(cell, op),
            payload=body,
            timeout=timeout,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
        ):
            if r.ok is not None:
                sample = r.ok
                yield Reply(True, _json(sample.payload.to_bytes()), _cell_of(str(sample.key_expr)))
            else:
                assert r.err is not None
                yield Reply(False, _json(r.err.payload.to_bytes()), None)

    def request(self, cell: str, op: str, payload: Any = None, timeout: float = 10.0) -> Reply:
        """The first reply (one cell: its reply, returned as soon as it arrives, without waiting for
        the end of the query); a Reply(False, {"error": {"code": "no_reply", ...}}) when none came."""
        for reply in self._replies(cell, op, payload, timeout):
            return reply
        return Reply(
            False,
            {
                "error": {
                    "code": "no_reply",
                    "message": no_reply_reason(self, cell, op, timeout),
                    "details": {},
                }
            },
            None,
        )

    def follow(self, cell: str, topic: str, callback: Callable[[str, dict[str, Any]], None]) -> Any:
        """Subscribe to ``pvtflow/<cell>/<topic>``; callback(cell, payload). Keep the result alive."""

        def on_sample(sample: zenoh.Sample) -> None:
            callback(_cell_of(str(sample.key_expr)) or cell, _json(sample.payload.to_bytes()))

        return self.session.declare_subscriber(key(cell, topic), on_sample)

    def alive(self, cell: str = "*", timeout: float = 2.0) -> list[str]:
        """The cells whose liveliness token is up."""
        cells = []
        for r in self.session.liveliness().get(key(cell, "alive"), timeout=timeout):
            if r.ok is not None:
                name = _cell_of(str(r.ok.key_expr))
                if name:
                    cells.append(name)
        return sorted(cells)


def no_reply_reason(client: Client, cell: str, op: str, timeout: float) -> str:
    """Why nothing answered ``pvtflow/<cell>/<op>``, from the liveliness tokens of the services the
    session reaches: another cell's service (named, with the ``--cell`` that reaches it), none at all,
    or this cell's service up but silent."""
    here = client.alive("*", timeout=min(2.0, timeout))
    waited = f"no reply from {key(cell, op)} within {timeout:g} s"
    if "*" not in cell and cell not in here and here:
        cells = ", ".join(here)
        hint = f"--cell {here[0]}" if len(here) == 1 else "--cell NAME"
        return f"{waited}: no service of cell {cell} is reachable; the services reachable serve {cells} ({hint})"
    if here:
        return f"{waited}: the service of {', '.join(here)} is up but did not answer in time (busy? a longer timeout)"
    return f"{waited}: no pvtflow service is reachable: is `pvtflow serve` running, reachable at the endpoint given?"


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` when zenoh takes it as one (judged by zenoh's own parser); else a ValueError saying the
    form, so that ``127.0.0.1:7447`` is one clear line instead of a zenoh traceback."""
    try:
        client_config([endpoint])
    except Exception:  # zenoh.ZError
        hint = f" (did you mean tcp/{endpoint}?)" if endpoint and "/" not in endpoint else ""
        raise ValueError(
            f"{endpoint!r} is not a zenoh endpoint: PROTOCOL/ADDRESS:PORT, e.g. {DEFAULT_ENDPOINT}{hint}"
        ) from None
    return endpoint


def _json(data: bytes) -> Any:
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return {"error": {"code": "malformed_reply", "message": repr(data[:200]), "details": {}}}


def _cell_of(key_expr: str) -> str | None:
    parts = key_expr.split("/")
    return parts[1] if len(parts) >= 3 and parts[0] == "pvtflow" else None


# --- the command -----------------------------------------------------------------------------------
def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "request",
        help="send a request to a pvtflow service over zenoh (plan, validate, execute, stop, status, recover, home, "
        "pause, resume, override)",
        description="Talk to `pvtflow serve` over zenoh. Exit 0 answered, 1 error reply, 2 no answer or bad input.",
    )
    p.add_argument("op", choices=QUERYABLES, help="the request")
    p.add_argument(
        "plan_id", nargs="?", help="validate / execute: the plan id from a plan reply; override: the SCALE (0.05..1)"
    )
    p.add_argument("--cell", default="arm6", help="the cell (default arm6; '*' asks every cell: status)")
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        help=f"the service's endpoint (default {DEFAULT_ENDPOINT}); with --zenoh-config, it replaces the file's "
        "connect endpoints",
    )
    p.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="a zenoh JSON5 client configuration, used as is (credentials, TLS, a router)",
    )
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the reply (default 30)")
    p.add_argument(
        "--waypoints",
        metavar="FILE",
        help="plan: waypoint file (pvtflow JSON or ROS JointTrajectory; one waypoint or more), or a pose file "
        '{"poses": [[x, y, z, qx, qy, qz, qw], ...], "motion": "linear" or "joint", "start": "current" or joints}',
    )
    p.add_argument(
        "--target", metavar="Q1,Q2,...", help="plan: one goal in joint units, comma separated (not with --waypoints)"
    )
    p.add_argument(
        "--start",
        choices=("current", "first", "home"),
        help="plan: where the motion starts. first: at the first waypoint (the default for a --waypoints file of "
        "two rows or more, as pvtflow plan reads it: execute then refuses unless the axes are there); current: "
        "at the axes, then through every waypoint (the default for --target and a one-row file); home: at the "
        "cell's home position, then through every waypoint or pose",
    )
    p.add_argument(
        "--approach",
        action="store_true",
        help="execute: where the axes are not at the program's start, move them there first (a joint move within "
        "the limits, planned by the cell's planner); without it such a program is refused (start_mismatch)",
    )
    p.add_argument(
        "--queue",
        action="store_true",
        help="execute: while a motion runs, run this one after it with no stop in between (it must start where "
        "that one ends); with nothing running it starts at once",
    )
    p.add_argument(
        "--velocity-scale",
        type=float,
        metavar="F",
        help="plan: speed override in (0, 1], the joint velocity limits times F (default 1)",
    )
    p.add_argument(
        "--acceleration-scale",
        type=float,
        metavar="F",
        help="plan: the same for the joint acceleration limits (default 1)",
    )
    p.add_argument(
        "--max-jerk",
        metavar="J1,...,Jn",
        help="plan: jerk limit per joint in joint units/s^3, in the cell's joint order (default: the cell's)",
    )
    p.add_argument(
        "--budget-ms",
        type=float,
        metavar="MS",
        help="plan: the plan's deadline in ms (default: the cell's planning.budget_ms)",
    )
    p.add_argument("--program", metavar="FILE", help="validate / execute: a PVT program file instead of a plan id")
    p.add_argument(
        "--wait",
        action="store_true",
        help="execute / home / resume: reply at the end of the motion or homing, with its outcome",
    )
    p.add_argument(
        "--joints",
        metavar="J1,J2,...",
        help="home: the axes to home, comma separated (default: every axis with homing)",
    )
    p.add_argument("--reason", help="stop / pause: why (journaled with the outcome)")
    p.add_argument(
        "--mode",
        choices=("path", "quick"),
        help="stop: path (default: every axis at rest on the planned path, on the same SYNC) or quick (the "
        "fastest, off the path)",
    )
    p.add_argument("--recent", type=int, help="status: how many recent motions to list")
    p.add_argument("--json", dest="raw", metavar="PAYLOAD", help="send this JSON payload as is (overrides the rest)")
    p.set_defaults(run=run)


class _InputError(ValueError):
    pass


# option (argparse dest) -> the requests it belongs to: given to another one, it would be silently ignored
_FOR_OPS: dict[str, tuple[str, ...]] = {
    "plan_id": ("validate", "execute"),
    "waypoints": ("plan",),
    "target": ("plan",),
    "start": ("plan",),
    "velocity_scale": ("plan",),
    "acceleration_scale": ("plan",),
    "max_jerk": ("plan",),
    "budget_ms": ("plan",),
    "program": ("validate", "execute"),
    "wait": ("execute", "home", "resume"),
    "approach": ("execute",),
    "queue": ("execute",),
    "joints": ("home",),
    "reason": ("stop", "pause"),
    "mode": ("stop",),
    "recent": ("status",),
}


def _option_name(dest: str) -> str:
    return "PLAN_ID" if dest == "plan_id" else "--" + dest.replace("_", "-")


def _local_payload(args: argparse.Namespace) -> Any:
    """The request as far as it needs no service (the waypoints need the cell's joint names): every mistake
    in the command line is refused here, before a session opens."""
    if args.raw is not None:
        return args.raw.encode()
    op = args.op
    out: dict[str, Any] = {}
    if op == "override":  # its one positional is the scale
        try:
            scale = float(args.plan_id) if args.plan_id is not None else math.nan
        except ValueError:
            scale = math.nan
        if not (math.isfinite(scale) and 0.05 <= scale <= 1.0):
            raise _InputError(
                f"override takes a SCALE in [0.05, 1.0] (the share of the planned speed), got {args.plan_id!r}"
            )
        out["scale"] = scale
        args.plan_id = None
    for dest, ops in _FOR_OPS.items():
        if getattr(args, dest, None) not in (None, False) and op not in ops:
            raise _InputError(f"{_option_name(dest)} is for {' / '.join(ops)}, not {op}")
    if op == "plan":
        if args.target is not None and args.waypoints is not None:
            raise _InputError("plan takes --target Q1,Q2,... or --waypoints FILE, not both")
        if args.target is not None:
            try:
                target = [float(x) for x in args.target.split(",")]
            except ValueError:
                target = []
            if not target or not all(math.isfinite(x) for x in target):
                raise _InputError(f"--target: not a comma-separated list of finite numbers: {args.target!r}")
            out["target"] = target
        elif args.waypoints is None:
            raise _InputError("plan needs --waypoints FILE or --target Q1,Q2,...")
        if args.start:
            out["start"] = args.start
        for dest in ("velocity_scale", "acceleration_scale"):
            value = getattr(args, dest)
            if value is not None:
                try:
                    out[dest] = check_scale(_option_name(dest), value)
                except ValueError as exc:
                    raise _InputError(str(exc)) from None
        if args.max_jerk is not None:
            out["max_jerk"] = _max_jerk(args.max_jerk)
        if args.budget_ms is not None:
            if not (math.isfinite(args.budget_ms) and 0 < args.budget_ms <= 60000):
                raise _InputError(f"--budget-ms must be a number of ms in (0, 60000], got {args.budget_ms:g}")
            out["budget_ms"] = args.budget_ms
    elif op in ("validate", "execute"):
        if args.program is not None and args.plan_id is not None:
            raise _InputError(f"{op} takes a PLAN_ID or --program FILE, not both")
        if args.program is not None:
            path = Path(args.program)
            try:
                read_program(path)  # the reader of every command: the same words for the same file
            except ProgramFileError as exc:
                raise _InputError(f"{path}: {exc}") from None
            out["program"] = json.loads(path.read_bytes())
        elif args.plan_id is not None:
            out["plan_id"] = args.plan_id
        else:
            raise _InputError(f"{op} needs a PLAN_ID or --program FILE")
        if op == "execute" and args.wait:
            out["wait"] = True
        if op == "execute" and args.approach:
            out["approach"] = True
        if op == "execute" and args.queue:
            out["queue"] = True
    elif op == "home":
        if args.joints is not None:
            joints = [j.strip() for j in args.joints.split(",")]
            if not all(joints):
                raise _InputError(f"--joints: not a comma-separated list of axis names: {args.joints!r}")
            out["joints"] = joints
        if args.wait:
            out["wait"] = True
    elif op in ("stop", "pause"):
        if args.reason:
            out["reason"] = args.reason
        if args.mode:
            out["mode"] = args.mode
    elif op == "resume" and args.wait:
        out["wait"] = True
    elif op == "status" and args.recent is not None:
        out["recent"] = args.recent
    return out


def _max_jerk(text: str) -> list[float]:
    """--max-jerk: positive numbers, comma separated (the service checks that there is one per joint)."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise _InputError(f"--max-jerk: not a comma-separated list of positive numbers: {text!r}")
    return values


def _add_waypoints(args: argparse.Namespace, client: Client, payload: dict[str, Any]) -> None:
    """plan --waypoints: the file read in the cell's joint order (asked of the service). A file starts at
    its first row, as ``pvtflow plan`` reads it (``start: first``): never a silent detour from where the
    axes stand through that row; ``--start current`` asks for that motion. One row is a goal from where
    the axes are, as ``--target``; a pose file becomes a poses request."""
    status = client.request(args.cell, "status", {"recent": 0}, args.timeout)
    if not status.ok:
        raise _InputError(f"cannot learn the joints of cell {args.cell}: {status.data['error']['message']}")
    try:
        motion = load_motion(args.waypoints, status.data["joint_names"], min_count=1)
    except WaypointError as exc:
        raise _InputError(str(exc)) from None
    if isinstance(motion, PoseTargets):
        if args.start not in (None, "home") or (args.start == "home" and motion.start is not None):
            raise _InputError(
                "a pose file says where it starts (its start field); --start home only where it names none"
            )
        payload["poses"] = motion.poses.tolist()
        payload["motion"] = motion.motion
        if motion.start is not None:
            payload["start"] = motion.start.tolist()
    else:
        payload["waypoints"] = motion.tolist()
        if args.start is None and len(motion) >= 2:  # a file starts at its first row, as in pvtflow plan
            payload["start"] = "first"
        if warning := dropped_times_warning(args.waypoints):
            print(f"{PROG}: {warning}", file=sys.stderr)


def _client_config(args: argparse.Namespace) -> zenoh.Config:
    """The user's config file as is (with --connect: its connect endpoints replaced), or a client of the
    endpoint; ZenohConfigError / ValueError (an endpoint zenoh cannot take) otherwise."""
    if args.connect is not None:
        check_endpoint(args.connect)
    if not args.zenoh_config:
        return client_config([args.connect or DEFAULT_ENDPOINT])
    config = load_zenoh_config(args.zenoh_config)
    if args.connect is not None:
        config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    return config


def _print_replies(replies: Iterator[Reply] | list[Reply], many: bool) -> int:
    code = EXIT_OK
    for r in replies:
        if r.ok:
            text = json.dumps({r.cell: r.data} if many else r.data, indent=2)
            print(text)
        else:
            err = r.data.get("error", {}) if isinstance(r.data, dict) else {}
            print(f"{PROG}: {err.get('code')}: {err.get('message')}", file=sys.stderr)
            if err.get("details"):
                print(json.dumps(err["details"], indent=2)[:4000], file=sys.stderr)
            code = EXIT_ERROR_REPLY
    return code


def run(args: argparse.Namespace) -> int:
    try:
        payload = _local_payload(args)
        config = _client_config(args)
    except (_InputError, ZenohConfigError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_NO_ANSWER
    except ValueError as exc:  # an endpoint zenoh cannot take
        print(f"{PROG}: --connect: {exc}", file=sys.stderr)
        return EXIT_NO_ANSWER
    try:
        client = Client(config)
    except Exception as exc:  # zenoh cannot open the session: nobody at the endpoint, refused, bad syntax
        print(
            f"{PROG}: cannot reach the service ({', '.join(config_endpoints(config, 'connect')) or 'no endpoint'}): "
            f"{zenoh_message(exc)}",
            file=sys.stderr,
        )
        return EXIT_NO_ANSWER
    try:
        if args.op == "plan" and isinstance(payload, dict) and args.waypoints is not None:
            _add_waypoints(args, client, payload)
        replies = client.replies(args.cell, args.op, payload, args.timeout)
        if not replies:
            print(f"{PROG}: {no_reply_reason(client, args.cell, args.op, args.timeout)}", file=sys.stderr)
            return EXIT_NO_ANSWER
        return _print_replies(replies, "*" in args.cell)
    except _InputError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_NO_ANSWER
    finally:
        client.close()
