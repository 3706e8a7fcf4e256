"""``pvtflow demo``: a service on simulated drives, a move planned and run through zenoh, a plot.

Everything goes the way a cell's software would go: the service (the arm6 demo cell on simulated
EPOS2 drives, a zenoh peer on a free loopback port) and a client session in this process talk
only over zenoh. The client plans a tour through a few waypoints, executes it, shows a progress
bar from the telemetry while the axes move, prints the drives' final state from ``status``, then
moves the tool on a straight line (a joint move off the middle of the ranges, where the wrist is
straight, then a poses request with motion linear) and writes a plot of the telemetry (joint
positions and buffer levels of the tour over time; the tool's path during the line). A cell that
requires homing (gantry3: incremental encoders) homes first, through zenoh too, and says so.
Exit codes: 0 the motion finished, 1 it did not (the reason is printed), 2 cannot start.
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import pinocchio as pin

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.planner.cartesian import placement_pose
from pvtflow.service.api import key
from pvtflow.service.cli_options import add_config, add_real_time
from pvtflow.service.config import CellConfig, ConfigError, load_cell_config
from pvtflow.service.demo_sequence import PICK_AND_PLACE, run_sequence
from pvtflow.service.journal import JournalError
from pvtflow.service.motion import MotionService
from pvtflow.service.request_cmd import Client
from pvtflow.service.server import Server, peer_config, zenoh_message

EXIT_OK, EXIT_FAILED, EXIT_CANNOT_START = 0, 1, 2
PROG = "pvtflow demo"


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "demo",
        help="start a service on simulated drives, plan and run a move through zenoh, plot it",
        description="Start the arm6 demo cell's service on simulated drives, plan a tour through waypoints and "
        "run it through zenoh with a progress bar, then write a plot of the telemetry.",
    )
    add_config(p)
    p.add_argument("--plot", metavar="OUT.png", default="pvtflow-demo.png", help="plot file (default %(default)s)")
    p.add_argument("--port", type=int, default=0, help="loopback TCP port of the service (default: a free one)")
    add_real_time(p)
    p.add_argument(
        "--journal", metavar="DIR", help="motion journal directory (default: a temporary one, removed at the end)"
    )
    p.add_argument(
        "--tour-points",
        type=int,
        default=4,
        metavar="N",
        help="how many waypoints the tour goes through after its start, 1..20 (default 4)",
    )
    p.add_argument(
        "--sequence",
        nargs="?",
        const=str(PICK_AND_PLACE),
        metavar="FILE",
        help="run a motion sequence instead of the tour (default: the shipped arm6 pick and place): planned as "
        "the file says, run twice, the second cycle queued while the first runs (no stop in between)",
    )
    # the option's first name, kept working: it is a count, not a waypoint file as in plan and request
    p.add_argument("--waypoints", type=int, dest="tour_points", help=argparse.SUPPRESS)
    p.set_defaults(run=run)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tour(lower: np.ndarray, upper: np.ndarray, n: int, seed: int = 7) -> list[list[float]]:
    """``n`` waypoints inside the middle 40 % of every joint's range, ending back at the middle."""
    rng = np.random.default_rng(seed)
    mid, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
    pts = [mid + 0.4 * half * rng.uniform(-1.0, 1.0, len(mid)) for _ in range(max(1, n - 1))]
    pts.append(mid)
    return [[float(x) for x in p] for p in pts]


# where the linear move starts: off the middle of the ranges (the arm's wrist is straight there, a
# singularity), as fractions of each joint's half range
LIFT = (0.2, 0.5, 0.5, 0.2, 1.0, 0.2)
LINE = (-0.12, 0.0, 0.08)  # m: the linear move's offset of the tool in the base frame


@dataclass(frozen=True)
class ToolTrace:
    """The linear move as the plot shows it: the commanded line and the tool's positions."""

    motion_id: str
    start: np.ndarray
    end: np.ndarray
    positions: np.ndarray  # (n, 3), from the telemetry's joint positions
    worst_mm: float  # the largest distance of those from the line, m


class _Follower:
    """Collects telemetry and events of one cell, and shows the progress: a bar redrawn in place on a
    terminal; into a pipe or a file (no terminal to redraw on), one plain line per tenth of the motion."""

    def __init__(self, width: int = 40, stream: TextIO | None = None) -> None:
        self.width = width
        self.stream = stream if stream is not None else sys.stdout
        self.tty = self.stream.isatty()
        self._tenths = -1  # the last tenth of the motion a plain line was written for
        self.telemetry: list[dict[str, Any]] = []  # of the present motion
        self.by_motion: dict[str, list[dict[str, Any]]] = {}
        self.events: list[dict[str, Any]] = []
        self.states: list[str] = []
        self.ended = threading.Event()
        self.outcome: dict[str, Any] | None = None
        self.motion_id: str | None = None
        self._t0: float | None = None

    def follow(self, motion_id: str) -> None:
        """From now on, collect the telemetry and wait for the end of ``motion_id``."""
        self.telemetry = self.by_motion.setdefault(motion_id, [])
        self._tenths = -1
        self.outcome = None
        self.ended.clear()
        self.motion_id = motion_id

    def on_telemetry(self, cell: str, d: dict[str, Any]) -> None:
        del cell
        if d.get("motion_id") is None or d.get("motion_id") != self.motion_id:
            return
        self.telemetry.append(d)
        progress = d.get("progress") or 0.0
        filled = round(progress * self.width)
        levels = " ".join("-" if lv is None else f"{lv:2d}" for lv in d["buffer_levels"])
        what = f"{100 * progress:5.1f}%  t={d['elapsed_ms'] / 1000:6.3f} s  buffers {levels}"
        if self.tty:
            self.stream.write(f"\r  [{'#' * filled}{'.' * (self.width - filled)}] {what} ")
        elif int(10 * progress) > self._tenths:
            self._tenths = int(10 * progress)
            self.stream.write(f"  {what}\n")
        else:
            return
        self.stream.flush()

    def end_line(self) -> None:
        """End the bar's line (a terminal only: plain lines end themselves)."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()

    def on_event(self, cell: str, d: dict[str, Any]) -> None:
        del cell
        self.events.append(d)
        if d.get("kind") == "motion_ended" and d.get("motion_id") == self.motion_id:
            self.outcome = d.get("outcome")
            self.ended.set()

    def on_state(self, cell: str, d: dict[str, Any]) -> None:
        del cell
        self.states.append(d["state"])


def write_plot(
    path: Path, tel: list[dict[str, Any]], joint_names: list[str], title: str, tool: ToolTrace | None = None
) -> None:
    """Joint positions and buffer levels of the tour over time; with ``tool``, a third panel: the
    tool's path during the linear move (forward kinematics of its telemetry) against the line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([d["elapsed_ms"] / 1000.0 for d in tel])
    q = np.array([[np.nan if x is None else x for x in d["positions"]] for d in tel])
    lv = np.array([[np.nan if x is None else x for x in d["buffer_levels"]] for d in tel])
    if tool is not None:
        fig = plt.figure(figsize=(13, 6.5))
        grid = fig.add_gridspec(3, 2, width_ratios=(3, 2))
        ax1 = fig.add_subplot(grid[:2, 0])
        ax2 = fig.add_subplot(grid[2, 0], sharex=ax1)
        ax3 = fig.add_subplot(grid[:, 1])
        a, b, xyz = tool.start, tool.end, tool.positions
        ax3.plot([a[0], b[0]], [a[2], b[2]], "--", color="0.5", label="commanded line")
        ax3.plot(xyz[:, 0], xyz[:, 2], ".", ms=3, label="tool (telemetry, forward kinematics)")
        ax3.set_xlabel("x (m)")
        ax3.set_ylabel("z (m)")
        ax3.set_aspect("equal", adjustable="datalim")
        ax3.set_title(f"linear move, {tool.motion_id}: worst {1000 * tool.worst_mm:.3f} mm off the line", fontsize=9)
        ax3.legend(fontsize=8)
        ax3.grid(alpha=0.3)
    else:
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, height_ratios=(2, 1))
    for j, name in enumerate(joint_names):
        ax1.plot(t, q[:, j], label=name)
        ax2.plot(t, lv[:, j], label=name)
    ax1.set_ylabel("joint position (rad / m)")
    ax1.set_title(title)
    ax1.legend(ncol=3, fontsize=8)
    ax1.grid(alpha=0.3)
    ax2.set_ylabel("buffer level (records)")
    ax2.set_xlabel("program time (s), from pvtflow/<cell>/telemetry")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _run_motion(client: Client, name: str, request: dict[str, Any], follower: _Follower, what: str) -> str | None:
    """Plan ``request``, execute it and wait for its end: its motion id, or None (said why)."""
    plan = client.request(name, "plan", request)
    if not plan.ok:
        err = plan.data["error"]
        print(f"{PROG}: {what}: plan refused: {err['code']}: {err['message']}", file=sys.stderr)
        return None
    p = plan.data
    ex = client.request(name, "execute", {"plan_id": p["plan_id"]})
    if not ex.ok:
        err = ex.data["error"]
        print(f"{PROG}: {what}: execute refused: {err['code']}: {err['message']}", file=sys.stderr)
        return None
    follower.follow(ex.data["motion_id"])
    if not follower.ended.wait(max(30.0, 10 * p["duration_s"])):
        print(f"\n{PROG}: {what}: the motion did not end in time: stopping it", file=sys.stderr)
        client.request(name, "stop", {"reason": "demo timeout"})
        return None
    follower.end_line()
    outcome = follower.outcome or {}
    print(
        f"  {what}: plan {p['plan_id']}, {p['waypoints']} joint waypoints, {p['duration_s']:.3f} s; "
        f"outcome {outcome.get('result')}"
    )
    return ex.data["motion_id"] if outcome.get("result") == "finished" else None


def _linear_move(
    client: Client, name: str, service: MotionService, follower: _Follower
) -> tuple[bool, ToolTrace | None]:
    """A joint move off the middle of the ranges, then a straight line of the tool (a poses request,
    motion linear, from where the axes are): whether both finished, and the tool's path from the
    telemetry (None for a cell without a tool frame: no linear move there)."""
    frame = service.cell.planning.tcp_frame
    if frame is None:
        print("  (no robot.tcp_frame in the cell: no linear move)")
        return True, None
    limits = service.limits
    mid, half = 0.5 * (limits.lower + limits.upper), 0.5 * (limits.upper - limits.lower)
    lift = mid + 0.3 * half * np.resize(np.array(LIFT), limits.dof)
    if _run_motion(client, name, {"target": [float(x) for x in lift]}, follower, "joint move") is None:
        return False, None
    model = service.cell.model
    start = pin.SE3(model.frame_placement(lift, frame))
    end = start.copy()
    end.translation = start.translation + np.array(LINE)
    request = {"poses": [[float(x) for x in placement_pose(end)]], "motion": "linear", "label": "demo line"}
    motion_id = _run_motion(client, name, request, follower, "linear move")
    if motion_id is None:
        return False, None
    q = np.array([d["positions"] for d in follower.by_motion.get(motion_id, []) if None not in d["positions"]])
    xyz = np.array([model.frame_placement(x, frame)[:3, 3] for x in q]).reshape(-1, 3)
    a, b = start.translation, end.translation
    u = np.clip((xyz - a) @ (b - a) / float((b - a) @ (b - a)), 0.0, 1.0)
    off = np.linalg.norm(xyz - (a + u[:, None] * (b - a)), axis=1)
    worst = float(off.max()) if len(off) else 0.0
    print(f"  the tool stayed within {1000 * worst:.3f} mm of the line ({len(xyz)} telemetry samples)")
    return True, ToolTrace(motion_id, a.copy(), b.copy(), xyz, worst)


def run(args: argparse.Namespace) -> int:
    try:
        cell = load_cell_config(args.config)
    except ConfigError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    if not cell.simulated:
        print(
            f"{PROG}: cell {cell.name} has real drives (simulated: false): the demo only runs simulated cells",
            file=sys.stderr,
        )
        return EXIT_CANNOT_START
    if not 1 <= args.tour_points <= 20:
        print(f"{PROG}: --tour-points must be 1..20, got {args.tour_points}", file=sys.stderr)
        return EXIT_CANNOT_START
    plot = Path(args.plot)
    if not plot.parent.is_dir():
        print(f"{PROG}: cannot write {plot}: {plot.parent} is not a directory", file=sys.stderr)
        return EXIT_CANNOT_START
    endpoint = f"tcp/127.0.0.1:{args.port or free_port()}"
    if args.journal:
        return _serve_and_demo(args, cell, plot, endpoint, args.journal)
    with tempfile.TemporaryDirectory(prefix="pvtflow-demo-") as journal_dir:  # gone on every way out
        return _serve_and_demo(args, cell, plot, endpoint, journal_dir)


def _serve_and_demo(args: argparse.Namespace, cell: CellConfig, plot: Path, endpoint: str, journal_dir: str) -> int:
    try:
        service = MotionService(cell, journal_dir=journal_dir, clock=Clock.of(not args.real_time)).open()
        freeze_startup_objects()
    except (BusError, JournalError, OSError) as exc:
        print(f"{PROG}: cannot start the cell: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    try:
        server = Server(service, peer_config(listen=[endpoint])).start()
    except Exception as exc:
        service.close()
        print(f"{PROG}: cannot open zenoh on {endpoint}: {zenoh_message(exc)}", file=sys.stderr)
        return EXIT_CANNOT_START
    client = None
    try:
        client = Client(connect=endpoint)
        sequence = Path(args.sequence) if args.sequence is not None else None
        return _demo(client, cell.name, plot, endpoint, service, journal_dir, args.tour_points, sequence)
    finally:
        if client is not None:
            client.close()
        server.close()
        service.close()


def _home(client: Client, name: str) -> bool:
    """A cell with incremental encoders homes before anything else moves (``not_homed`` otherwise)."""
    print(f"  homing first: cell {name} requires it (incremental encoders; its axes powered up anywhere)")
    t0 = time.perf_counter()
    reply = client.request(name, "home", {"wait": True}, timeout=120.0)
    if not reply.ok:
        err = reply.data["error"]
        print(f"{PROG}: home refused: {err['code']}: {err['message']}", file=sys.stderr)
        return False
    outcome = reply.data["outcome"]
    stages = " then ".join(" + ".join(stage) for stage in reply.data["stages"])
    print(f"  homed {stages} in {time.perf_counter() - t0:.2f} s: {outcome['result']}: {outcome['message']}")
    for a in outcome["axes"]:
        took = "-" if a["time_s"] is None else f"{a['time_s']:.3f} s"
        print(f"    {a['joint']}: method {a['method']}, {took} of drive time, now at {a['position_qc']} qc")
    if outcome["result"] != "homed":
        print(f"{PROG}: the homing failed: {outcome['message']}", file=sys.stderr)
    return bool(outcome["result"] == "homed")


def _demo(
    client: Client,
    name: str,
    plot: Path,
    endpoint: str,
    service: MotionService,
    journal_dir: str,
    n_waypoints: int,
    sequence: Path | None = None,
) -> int:
    print(
        f"{PROG}: service for cell {name} on simulated drives, zenoh peer on {endpoint} "
        f"(SYNC {'lockstep' if service.clock is Clock.LOCKSTEP else 'real time'}); journal in {journal_dir}"
    )
    follower = _Follower()
    subs = [
        client.follow(name, "telemetry", follower.on_telemetry),
        client.follow(name, "events", follower.on_event),
        client.follow(name, "state", follower.on_state),
    ]
    deadline = time.monotonic() + 5.0
    while name not in client.alive(name, timeout=1.0):
        if time.monotonic() > deadline:
            print(f"{PROG}: the service's liveliness token {key(name, 'alive')} did not appear", file=sys.stderr)
            return EXIT_FAILED
    status = client.request(name, "status", {"recent": 0})
    if not status.ok:
        print(f"{PROG}: status failed: {status.data['error']['message']}", file=sys.stderr)
        return EXIT_FAILED
    joints = status.data["joint_names"]
    print(
        f"  {key(name, 'alive')} is up; axes: "
        + ", ".join(f"{a['joint']} {a['state'].lower()}" for a in status.data["axes"])
    )
    if status.data.get("requires_homing") and not status.data.get("homed") and not _home(client, name):
        return EXIT_FAILED
    if sequence is not None:  # the sequence instead of the tour (service/demo_sequence.py)
        period_ms = service.cell.bus.sync_period_ms
        ok = run_sequence(client, name, joints, sequence, follower, plot, period_ms)
        del subs
        return EXIT_OK if ok else EXIT_FAILED
    limits = service.limits
    waypoints = tour(limits.lower, limits.upper, n_waypoints)
    t0 = time.perf_counter()
    plan = client.request(name, "plan", {"waypoints": waypoints, "label": "pvtflow demo tour"})
    dt = time.perf_counter() - t0
    if not plan.ok:
        err = plan.data["error"]
        print(f"{PROG}: plan refused: {err['code']}: {err['message']}", file=sys.stderr)
        return EXIT_FAILED
    p = plan.data
    print(
        f"  plan {p['plan_id']}: {p['waypoints']} waypoints, {p['duration_s']:.3f} s of motion, "
        f"{sum(p['records'].values())} PVT records, validated; reply in {1000 * dt:.1f} ms "
        f"(planning {p['timing_ms'].get('total', 0):.1f} ms)"
    )
    ex = client.request(name, "execute", {"plan_id": p["plan_id"]})
    if not ex.ok:
        err = ex.data["error"]
        print(f"{PROG}: execute refused: {err['code']}: {err['message']}", file=sys.stderr)
        return EXIT_FAILED
    follower.follow(ex.data["motion_id"])
    print(f"  motion {follower.motion_id} started on SYNC {ex.data['start_sync']}")
    if not follower.ended.wait(max(30.0, 10 * p["duration_s"])):
        print(f"\n{PROG}: the motion did not end in time: stopping it", file=sys.stderr)
        client.request(name, "stop", {"reason": "demo timeout"})
        return EXIT_FAILED
    follower.end_line()
    final = client.request(name, "status", {"recent": 1})
    outcome = follower.outcome or {}
    print(f"  outcome: {outcome.get('result')}: {outcome.get('message')}")
    if not final.ok:
        print(f"  status failed: {final.data['error']['code']}: {final.data['error']['message']}")
    else:  # what the drives say now (status), next to where the program ended them (the outcome)
        ends = {a["joint"]: a.get("target_position_qc") for a in outcome.get("axes", [])}
        for a in final.data["axes"]:
            print(
                f"    {a['joint']}: {a['state'].lower()}, statusword {a['statusword_hex']}, position "
                f"{a['position']:+.4f} ({a['position_qc']} qc; program end {ends.get(a['joint'])} qc)"
            )
    events = [e["kind"] for e in follower.events if e.get("motion_id") == follower.motion_id]
    print(f"  events: {', '.join(events)}; states: {' -> '.join(dict.fromkeys(follower.states))}")
    tour_tel, tour_id = list(follower.telemetry), follower.motion_id
    if outcome.get("result") != "finished":
        return EXIT_FAILED
    ok, tool = _linear_move(client, name, service, follower)
    if not ok:
        return EXIT_FAILED
    if tour_tel:
        write_plot(plot, tour_tel, joints, f"pvtflow demo: cell {name}, motion {tour_id}", tool)
        line = "; the tool's path on the line" if tool is not None else ""
        print(f"  plot: {plot} ({len(tour_tel)} telemetry samples of the tour{line})")
    del subs
    return EXIT_OK
