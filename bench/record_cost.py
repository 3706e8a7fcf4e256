"""What recording costs the motion: SYNC on the wall clock and plan latency with and without --record / --live.

The service as ``pvtflow serve --real-time`` runs it (MotionService, SYNC on the wall clock, plans in
the child process) on a simulated cell (every axis on one drive behaviour, without homing:
bench/realtime.py's ``variant``) plans and executes ``--moves`` random single-target moves, in three
cases: nothing recorded; ``--record DIR`` (one MCAP file per motion, service/recording); and
``--record DIR --live PORT`` with one WebSocket client (another process, the Foxglove protocol)
subscribed to every channel. Figures per case: moves finished / faulted, the SYNC interval as the
drives see it (bench/realtime.py's ``SyncArrivals``) p50 / p99 / max, plan latency p50 / p99 / max (a
plan request between motions), the CPU this process (master, simulated drives, recorder) used per
second of wall time, the wall time per SYNC of motion, the recorder's writer thread's CPU time per
SYNC of motion, the time the recorder's callbacks took in the bus's own threads per SYNC (what
the SYNC thread, the receive thread and the feeders pay: appending to the writer's queue), and the
bytes recorded. ``--lockstep``: SYNC in lockstep with the simulated drives
(as ``pvtflow serve`` on a simulated cell), where a SYNC comes as soon as the previous one is
answered, so the wall time per SYNC is what a SYNC costs the machine, load or not.

    python3 bench/record_cost.py [--moves 8] [--robot gantry3] [--profile epos2_pvt] [--period-ms 3] [--seed 1]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from realtime import SyncArrivals, variant  # noqa: E402

import pvtflow.service.motion.execution as execution_module  # noqa: E402
from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.service.api import ApiError, parse_execute, parse_plan  # noqa: E402
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config  # noqa: E402
from pvtflow.service.live import LiveServer  # noqa: E402
from pvtflow.service.motion import MotionService  # noqa: E402
from pvtflow.service.recording import Recorder  # noqa: E402


class TimedRecorder(Recorder):
    """The recorder with its bus-thread callbacks timed: what recording costs the SYNC thread, the
    receive thread and the feeders themselves (``hot_s``), apart from the writer thread."""

    hot_s = 0.0

    def _on_frame(self, msg: Any) -> None:
        t = time.perf_counter()
        super()._on_frame(msg)
        TimedRecorder.hot_s += time.perf_counter() - t

    def _on_sync(self, n: int) -> None:
        t = time.perf_counter()
        super()._on_sync(n)
        TimedRecorder.hot_s += time.perf_counter() - t


execution_module.Recorder = TimedRecorder  # type: ignore[misc]

CLIENT = textwrap.dedent(
    """
    import json, sys
    from websockets.sync.client import connect
    with connect(sys.argv[1], subprotocols=["foxglove.sdk.v1"]) as ws:
        subs = 0
        while True:
            frame = ws.recv()
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    s = []
                    for ch in msg["channels"]:
                        subs += 1
                        s.append({"id": subs, "channelId": ch["id"]})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": s}))
    """
)


def run_case(cell: CellConfig, moves: int, seed: int, record: bool, live: bool, lockstep: bool) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {"finished": 0, "faulted": [], "plan_ms": []}
    with tempfile.TemporaryDirectory() as tmp:
        server = LiveServer(0).start() if live else None
        client = (
            subprocess.Popen([sys.executable, "-c", CLIENT, server.url], stderr=subprocess.DEVNULL)
            if server is not None
            else None
        )
        svc = MotionService(
            cell,
            journal_dir=Path(tmp) / "journal",
            clock=Clock.of(lockstep),
            planner_process=not lockstep,
            record_dir=Path(tmp) / "rec" if record else None,
            live=server,
        ).open()
        arrivals = SyncArrivals(svc.sim.network)
        cpu0, wall0, motion_s = time.process_time(), time.perf_counter(), 0.0
        TimedRecorder.hot_s = 0.0
        try:
            lim = cell.joint_limits()
            for _ in range(moves):
                target = [
                    lo + f * (hi - lo)
                    for lo, hi, f in zip(lim.lower, lim.upper, rng.uniform(0.1, 0.9, len(lim.lower)), strict=True)
                ]
                req = parse_plan({"waypoints": [target], "start": "current"}, cell.joint_names, lim)
                t0 = time.perf_counter()
                try:
                    plan_id = svc.plan(req)["plan_id"]
                except ApiError as exc:
                    out["faulted"].append(f"plan refused: {exc}"[:140])
                    continue
                out["plan_ms"].append((time.perf_counter() - t0) * 1000.0)
                t1 = time.perf_counter()
                outcome = svc.execute(parse_execute({"plan_id": plan_id, "wait": True}))["outcome"]
                recorder = svc.motion.recorder if svc.motion is not None else None
                if outcome["result"] == "finished":  # the per-SYNC figures: runs that went to their end
                    out["finished"] += 1
                    motion_s += time.perf_counter() - t1
                    out["syncs"] = out.get("syncs", 0) + outcome["end_sync"] - outcome["start_sync"]
                    if recorder is not None and recorder.writer_cpu_s is not None:
                        out["writer_cpu_s"] = out.get("writer_cpu_s", 0.0) + recorder.writer_cpu_s
                else:
                    out["faulted"].append(f"{outcome['result']}: {outcome['message']}"[:160])
                    break
        finally:
            out["cpu_share"] = (time.process_time() - cpu0) / max(time.perf_counter() - wall0, 1e-9)
            out["motion_s"] = motion_s
            out["hot_s"] = TimedRecorder.hot_s
            svc.close()
            if client is not None:
                client.terminate()
                client.wait(5)
            if server is not None:
                server.stop()
        files = list((Path(tmp) / "rec").glob("*.mcap")) if record else []
        out["bytes"] = sum(f.stat().st_size for f in files)
    d = arrivals.intervals_ms()
    out["sync_ms"] = (float(np.percentile(d, 50)), float(np.percentile(d, 99)), float(d.max())) if len(d) else None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--moves", type=int, default=8)
    ap.add_argument("--robot", default="gantry3")
    ap.add_argument("--profile", default="epos2_pvt")
    ap.add_argument("--period-ms", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--lockstep",
        action="store_true",
        help="SYNC in lockstep with the simulated drives: the wall time per SYNC is then what the run costs",
    )
    args = ap.parse_args()
    print(
        f"python3 bench/record_cost.py --moves {args.moves} --robot {args.robot} --profile {args.profile} "
        f"--period-ms {args.period_ms:g} --seed {args.seed}" + (" --lockstep" if args.lockstep else "")
    )
    print(
        "| case | finished | faulted | SYNC interval p50/p99/max ms | plan ms p50/p99/max | CPU s per s "
        "(this process) | wall ms per SYNC | recorder CPU ms per SYNC | bus threads' share us per SYNC | recorded |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    base = load_cell_config(CONFIG_DIR / "cells" / f"{args.robot}.yaml")
    for name, record, live in (("nothing", False, False), ("--record", True, False), ("--record --live", True, True)):
        cell = variant(base, args.profile, None, args.period_ms)
        r = run_case(cell, args.moves, args.seed, record, live, args.lockstep)
        sync = "-" if r["sync_ms"] is None else "{:.3f} / {:.3f} / {:.3f}".format(*r["sync_ms"])
        plan = np.asarray(r["plan_ms"])
        plans = "-"
        if len(plan):
            plans = f"{np.percentile(plan, 50):.0f} / {np.percentile(plan, 99):.0f} / {plan.max():.0f}"
        recorded = f"{r['bytes'] / 1e6:.1f} MB" if record else "-"
        syncs = r.get("syncs", 0)
        per_sync = f"{r['motion_s'] * 1000 / syncs:.3f}" if syncs else "-"
        writer = f"{r['writer_cpu_s'] * 1000 / syncs:.3f}" if syncs and "writer_cpu_s" in r else "-"
        hot = f"{r['hot_s'] * 1e6 / syncs:.1f}" if syncs and record else "-"
        print(
            f"| {name} | {r['finished']}/{args.moves} | {len(r['faulted'])} | {sync} | {plans} "
            f"| {r['cpu_share']:.2f} | {per_sync} | {writer} | {hot} | {recorded} |",
            flush=True,
        )
        for why in r["faulted"][:2]:
            print(f"|   | {why} | | | | | | | | |")


if __name__ == "__main__":
    main()
