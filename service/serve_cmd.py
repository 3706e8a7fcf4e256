"""``pvtflow serve [--config FILE] [--zenoh-config FILE] [--can-log FILE]``: the cell service (the main job).

Before it opens anything it checks who could reach it (``service/exposure.py``): a zenoh config that
listens, connects or scouts beyond this host without authentication and access control is refused,
unless ``--allow-unauthenticated`` says so, which the banner then repeats.

Brings the cell's bus up (with simulated drives when the cell is simulated: the default arm6 demo
cell), configures the drives, opens the zenoh session and serves the cell until Ctrl-C / SIGTERM,
then halts any motion and closes. It prints where it listens and how to talk to it. Exit codes:
0 stopped by a signal, 2 cannot start (configuration, bus, journal, zenoh endpoint, live port).

``--record DIR`` writes each motion and homing to ``DIR/<id>.mcap`` (service/recording) and names
it in the journal; ``--live [PORT]`` serves the same channels on 127.0.0.1 (service/live.py), started
before the bus so a port in use refuses the start with nothing opened.
"""

from __future__ import annotations

import argparse
import errno
import json
import signal
import socket
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.service.api import LIVELINESS, PUBLICATIONS, QUERYABLES, StopRequest, key
from pvtflow.service.cli import can_log_problem
from pvtflow.service.cli_options import add_can_log, add_config, add_real_time
from pvtflow.service.config import ConfigError, load_cell_config
from pvtflow.service.exposure import exposure
from pvtflow.service.journal import JournalError
from pvtflow.service.live import DEFAULT_PORT as DEFAULT_LIVE_PORT
from pvtflow.service.live import LiveError, LiveServer
from pvtflow.service.motion import MotionService
from pvtflow.service.planning import PlanningError, PlanningProcess
from pvtflow.service.server import (
    ZENOH_CONFIG_DIR,
    Server,
    ZenohConfigError,
    config_endpoints,
    load_zenoh_config,
    zenoh_message,
)

EXIT_OK, EXIT_CANNOT_START = 0, 2
PROG = "pvtflow serve"


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "serve",
        help="serve a cell over zenoh: plan, validate, execute, stop, status, recover, home (the main job)",
        description="Run the motion service of one cell. The default configuration is the arm6 demo cell on "
        "simulated drives, listening on tcp/127.0.0.1:7447 without scouting.",
    )
    add_config(p)
    p.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="zenoh JSON5 configuration, used as is "
        "(default: configs/zenoh/service.json5: peer on tcp/127.0.0.1:7447, no scouting)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--listen",
        metavar="ENDPOINT",
        action="append",
        help="listen on this zenoh endpoint (repeatable; e.g. tcp/127.0.0.1:7448) instead of the zenoh config's "
        "listen endpoints; one beyond loopback needs authentication or --allow-unauthenticated, as in a config",
    )
    where.add_argument("--port", type=int, metavar="P", help="listen on tcp/127.0.0.1:P (the same as --listen)")
    add_can_log(p)
    p.add_argument(
        "--allow-unauthenticated",
        action="store_true",
        help="serve even though the zenoh config reaches beyond this host (a non-loopback listen or connect "
        "endpoint, multicast scouting) without authentication and access control: anyone who reaches it can "
        "execute motions (the banner says so). Without it such a config is refused",
    )
    p.add_argument(
        "--journal",
        metavar="DIR",
        help="motion journal directory (default $XDG_STATE_HOME/pvtflow/<cell>, i.e. ~/.local/state/pvtflow/<cell>)",
    )
    p.add_argument(
        "--record",
        metavar="DIR",
        help="record every motion and homing as DIR/<motion id>.mcap (its journal entry names the file; "
        "pvtflow report FILE.mcap; Foxglove)",
    )
    p.add_argument(
        "--live",
        metavar="PORT",
        nargs="?",
        type=int,
        const=DEFAULT_LIVE_PORT,
        help=f"serve every motion's channels live on ws://127.0.0.1:PORT (default {DEFAULT_LIVE_PORT}; the "
        "Foxglove WebSocket protocol: Foxglove, PlotJuggler); the channels of --record",
    )
    p.add_argument(
        "--planner-process",
        choices=("auto", "on", "off"),
        default="auto",
        help="plan in a child process (service/planning.py), so that a plan requested during a motion never "
        "holds the interpreter the bus threads (SYNC, records, setpoints) run in; costs ~0.5-4 ms per plan and "
        "one more Python process. auto (default): on wherever SYNC runs on the wall clock (a real cell, "
        "--real-time), off for a lockstep simulation (its SYNC waits for the drives anyway)",
    )
    add_real_time(p)
    p.add_argument(
        "--telemetry-ms",
        type=float,
        default=20.0,
        metavar="MS",
        help="telemetry period during a motion (default 20 ms)",
    )
    p.set_defaults(run=run)


def _fail(message: str) -> int:
    print(f"{PROG}: {message}", file=sys.stderr)
    return EXIT_CANNOT_START


def banner(service: MotionService, server: Server, allow_unauthenticated: bool = False) -> str:
    cell = service.cell
    name = cell.name
    listen = server.listen_endpoints
    connect = config_endpoints(server.config, "connect")
    drives = "simulated " if service.simulate else ""
    profiles = sorted({a.profile for a in cell.axes})
    sync = "in lockstep with the simulated drives" if service.clock is Clock.LOCKSTEP else "real time"
    lines = [
        f"{PROG}: cell {name}: {len(cell.axes)} axes ({', '.join(service.joint_names)}), {drives}drives "
        f"{'/'.join(profiles)} on {cell.bus.interface}:{cell.bus.channel}, SYNC {cell.bus.sync_period_ms:g} ms "
        f"{sync}",
    ]
    if listen:
        lines.append(
            f"  zenoh: listening on {', '.join(listen)}" + (f", connected to {', '.join(connect)}" if connect else "")
        )
    else:
        lines.append(f"  zenoh: not listening; connecting to {', '.join(connect) or '(nothing: check the config)'}")
    if allow_unauthenticated:
        exposed = exposure(server.config)
        lines.append(
            "  --allow-unauthenticated: "
            + (
                f"anyone who reaches {', '.join(exposed.reachable)} can execute motions on this cell"
                if exposed.open
                else "given, but this zenoh config needs no exception (loopback only, or authenticated)"
            )
        )
    lines += [
        f"  queryables:   {key(name, '{' + ','.join(QUERYABLES) + '}')}",
        f"  publications: {key(name, '{' + ','.join(PUBLICATIONS) + '}')}   liveliness: {key(name, LIVELINESS)}",
        f"  journal:      {service.journal.path}",
        *([f"  recordings:   {service.record_dir}/<motion id>.mcap"] if service.record_dir is not None else []),
        *([f"  live:         {service.live.url} (Foxglove WebSocket)"] if service.live is not None else []),
        "  planner:      "
        + ("in a child process" if isinstance(service.planner, PlanningProcess) else "in this process"),
    ]
    endpoint = listen[0] if listen else (connect[0] if connect else "tcp/127.0.0.1:7447")
    endpoint = endpoint.replace("0.0.0.0", "127.0.0.1")
    target = ",".join(f"{x:g}" for x in example_target(service.limits.lower, service.limits.upper))
    observer = operator = f"--connect {endpoint}"
    dictionary = auth_dictionary(server.config)
    if dictionary is not None:
        observer, operator, note = _credentials(dictionary, endpoint)
        lines += [f"  clients must authenticate (zenoh user/password, users in {dictionary}):", f"    {note}"]
    lines += ["  talk to it:", f"    pvtflow request status --cell {name} {observer}"]
    if service.cell.requires_homing:  # incremental encoders: nothing moves (not_homed) before this
        lines.append(f"    pvtflow request home --cell {name} {operator} --wait")
    lines += [
        f"    pvtflow request plan --cell {name} {observer} --target {target}",
        f"    pvtflow request execute PLAN_ID --cell {name} {operator}",
        f"    pvtflow request stop --cell {name} {operator}",
        "  Ctrl-C stops the service (a running motion is halted first).",
    ]
    return "\n".join(lines)


def listen_option(args: argparse.Namespace) -> list[str] | None:
    """The endpoints of --listen / --port (None: the zenoh config's own); ValueError for one zenoh cannot take."""
    from pvtflow.service.request_cmd import check_endpoint

    if args.port is not None:
        if not 1 <= args.port <= 65535:
            raise ValueError(f"--port must be a TCP port 1..65535, got {args.port}")
        return [f"tcp/127.0.0.1:{args.port}"]
    if args.listen is None:
        return None
    try:
        return [check_endpoint(e) for e in args.listen]
    except ValueError as exc:
        raise ValueError(f"--listen: {exc}") from None


def endpoint_in_use(endpoints: Sequence[str]) -> str | None:
    """Why the service could not listen on ``endpoints`` (None: the TCP/UDP ones are free), judged before
    anything starts: the address taken (another ``pvtflow serve``?), with the way to another one."""
    for endpoint in endpoints:
        proto, _, address = endpoint.partition("/")
        host, _, port = address.split("#", 1)[0].rpartition(":")
        if proto not in ("tcp", "udp") or not port.isdigit() or int(port) == 0:
            continue
        kind = socket.SOCK_STREAM if proto == "tcp" else socket.SOCK_DGRAM
        family = socket.AF_INET6 if host.startswith("[") else socket.AF_INET
        with socket.socket(family, kind) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as zenoh binds: TIME_WAIT is no conflict
            try:
                s.bind((host.strip("[]"), int(port)))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return in_use_line(endpoint)
                return f"cannot listen on {endpoint}: {exc.strerror or exc}"
    return None


def in_use_line(endpoint: str) -> str:
    return (
        f"{endpoint} is in use (another pvtflow serve? `pvtflow request status --cell '*' --connect {endpoint}` "
        "says which cell): give this one another with --port P or --listen ENDPOINT"
    )


def example_target(lower: Sequence[float], upper: Sequence[float]) -> list[float]:
    """The banner's example goal: a tenth of each joint's range off its middle (alternately up and
    down), so that the printed plan command fits the cell, whatever its joints and units."""
    out = []
    for i, (lo, hi) in enumerate(zip(lower, upper, strict=True)):
        x = 0.5 * (lo + hi) + (0.1 if i % 2 == 0 else -0.1) * (hi - lo)
        short = round(float(x), 2)
        out.append(short if lo < short < hi else float(x))
    return out


def auth_dictionary(config: zenoh.Config) -> str | None:
    """The user/password dictionary of a session that requires clients to authenticate (None: it does not)."""
    try:
        usrpwd = json.loads(config.get_json("transport/auth/usrpwd"))
    except Exception:  # a zenoh without the key: no authentication
        return None
    dictionary = usrpwd.get("dictionary_file") if isinstance(usrpwd, dict) else None
    return str(dictionary) if dictionary else None


def _credentials(dictionary: str, endpoint: str) -> tuple[str, str, str]:
    """The request options of an observer and of an operator, and a note on where they come from: the
    shipped client configs when the service uses the shipped dictionary, a client config to write otherwise."""
    shipped = ZENOH_CONFIG_DIR / "credentials.txt"
    if Path(dictionary).resolve() == shipped.resolve():
        observer, operator = (_shown(ZENOH_CONFIG_DIR / f"{who}-client.json5") for who in ("observer", "operator"))
        note = (
            f"{observer} is user observer (plan, validate, status), {operator} user operator (also "
            "execute, stop, recover, home)"
        )
        return (
            f"--zenoh-config {observer} --connect {endpoint}",
            f"--zenoh-config {operator} --connect {endpoint}",
            note,
        )
    example = _shown(ZENOH_CONFIG_DIR / "operator-client.json5")
    note = f"CLIENT.json5 is a client config with one of those users (transport.auth.usrpwd; see {example})"
    both = f"--zenoh-config CLIENT.json5 --connect {endpoint}"
    return both, both, note


def _shown(path: Path) -> str:
    """``path`` relative to the working directory when it is below it (shorter to type), else absolute."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path.resolve())


def run(args: argparse.Namespace) -> int:
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        return _fail(str(exc))
    try:
        zconfig = load_zenoh_config(args.zenoh_config)
        listen = listen_option(args)
    except (ZenohConfigError, ValueError) as exc:
        return _fail(str(exc))
    if listen is not None:
        zconfig.insert_json5("listen/endpoints", json.dumps(listen))
    if problem := endpoint_in_use(config_endpoints(zconfig, "listen")):
        return _fail(problem)
    exposed = exposure(zconfig)
    if exposed.open and not args.allow_unauthenticated:
        return _fail(exposed.refusal(f"zenoh config {args.zenoh_config or 'default'}"))
    if not args.telemetry_ms > 0:
        return _fail(f"--telemetry-ms must be positive, got {args.telemetry_ms}")
    if args.can_log and (problem := can_log_problem(args.can_log)):
        return _fail(problem)
    if args.record:
        try:
            Path(args.record).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            return _fail(f"--record {args.record}: cannot create the directory: {exc.strerror or exc}")

    live = None
    if args.live is not None:
        if not 0 <= args.live <= 65535:
            return _fail(f"--live {args.live}: not a TCP port (0..65535)")
        try:
            live = LiveServer(args.live).start()
        except LiveError as exc:
            return _fail(str(exc))

    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        del signum, frame
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            clock = Clock.of(cell.simulated and not args.real_time)
            print(
                f"{PROG}: starting cell {cell.name}; the planner loads its compiled loops (on a new machine numba "
                "compiles them first: ~15 s, once)",
                file=sys.stderr,
                flush=True,
            )
            service = MotionService(
                cell,
                journal_dir=args.journal,
                clock=clock,
                can_log=args.can_log,
                telemetry_period_ms=args.telemetry_ms,
                planner_process=args.planner_process == "on"
                or (args.planner_process == "auto" and clock is Clock.WALL),
                record_dir=args.record,
                live=live,
                drives_process=True,
            )
        except JournalError as exc:
            return _fail(str(exc))
        except (ValueError, OSError) as exc:
            return _fail(f"cannot start cell {cell.name}: {exc}")
        try:
            service.open()
        except BusError as exc:
            return _fail(str(exc))
        except PlanningError as exc:  # the planning process did not start
            service.close()
            return _fail(f"cannot start cell {cell.name}: {exc}")
        except (ValueError, OSError) as exc:  # the CAN log cannot be opened after all (its checks passed)
            service.close()
            return _fail(f"cannot start cell {cell.name}: {exc}")
        freeze_startup_objects()  # planner warmed up, drives configured: start-up is over
        try:
            server = Server(service, zconfig).start()
        except Exception as exc:  # zenoh: endpoint in use (taken since the check), bad locator, ...
            service.close()
            message = zenoh_message(exc)
            if "in use" in message:
                return _fail(
                    endpoint_in_use(config_endpoints(zconfig, "listen")) or f"cannot open the zenoh session: {message}"
                )
            return _fail(f"cannot open the zenoh session: {message}")
        print(banner(service, server, args.allow_unauthenticated), flush=True)
        try:
            while not stop.wait(0.5):
                pass
        finally:
            print(f"{PROG}: stopping", flush=True)
            if service.running:  # halt first: a client waiting for the motion's end gets its reply
                service.stop(StopRequest("the service is shutting down"))
            server.close()
            service.close()
        return EXIT_OK
    finally:
        if live is not None:
            live.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
