"""Jerk-limited plans through the service at several budgets (issue 39 item 2): round trip, answers.

A pvtflow service for the arm6 cell (simulated EPOS2 drives, SYNC in lockstep, as bench/service_latency.py
runs it) behind a zenoh peer on a free 127.0.0.1 port; a zenoh client session in the same process sends
plan requests of N random 8-waypoint paths (bench/pvt_quality.py's drawing, seeded), each with
``max_jerk`` F x each joint's acceleration limit per second, at every budget of ``--budgets`` ("none":
60000 ms, the schema's largest). The very first request after the service opened is the first path at
the first budget (the first request after start). ``--planner-process``: the planner in its child
process, as ``pvtflow serve`` runs it on the wall clock.

Prints per budget: answers (ok / timeout / other), optimal, the reply's duration over the same path's
answer without a deadline (p50, max, share within 1.03x; the answer without a deadline is 1.0013x copp-py's
TOPP3 at 1000 stations at the median on these paths, bench/RESULTS.md), the solver's grid
(``details``-free: from the reply's ``gap``, duration / lower bound), round trip p50 / p99 / max.

Run:  python bench/jerk_service.py [--paths 20] [--budgets 20,50,100,none] [--factor 10] [--seed 1]
      [--planner-process]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from pvt_quality import random_waypoints

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.service.config import load_cell_config
from pvtflow.service.demo_cmd import free_port
from pvtflow.service.motion import MotionService
from pvtflow.service.request_cmd import Client
from pvtflow.service.server import Server, peer_config

NONE_MS = 60000.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--budgets", default="20,50,100,none")
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--planner-process", action="store_true")
    args = ap.parse_args(argv)
    budgets = [NONE_MS if b.strip() == "none" else float(b) for b in args.budgets.split(",")]
    cell = load_cell_config(None)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    service = MotionService(
        cell,
        journal_dir=tempfile.mkdtemp(prefix="pvtflow-bench-"),
        clock=Clock.LOCKSTEP,
        planner_process=args.planner_process,
    ).open()
    freeze_startup_objects()
    server = Server(service, peer_config(listen=[endpoint])).start()
    client = Client(connect=endpoint)
    rng = np.random.default_rng(args.seed)
    jerk = (args.factor * cell.joint_limits().acceleration).tolist()
    paths = [random_waypoints(cell, rng, 8).tolist() for _ in range(args.paths)]
    rows: dict[float, list[tuple[str, float, bool, float]]] = {b: [] for b in budgets}
    first: tuple[str, float] | None = None
    try:
        for wp in paths:
            for b in budgets:
                request = {"waypoints": wp, "start": "first", "max_jerk": jerk, "budget_ms": b}
                t0 = time.perf_counter()
                reply = client.request(cell.name, "plan", request, timeout=60)
                wall = 1000.0 * (time.perf_counter() - t0)
                code = "ok" if reply.ok else str(reply.error_code)
                optimal = bool(reply.data.get("optimal")) if reply.ok else False
                duration = float(reply.data["gap"]["duration_s"]) if reply.ok and "gap" in reply.data else np.nan
                rows[b].append((code, wall, optimal, duration))
                if first is None:
                    first = (code, wall)
    finally:
        client.close()
        server.close()
        service.close()
    ref = np.array([r[3] for r in rows[max(budgets)]])
    print(
        "arm6 through the service (zenoh loopback, lockstep drives"
        f"{', planner process' if args.planner_process else ''}),"
        f" {args.paths} paths of 8 waypoints, max_jerk {args.factor:g} x amax/s, seed {args.seed};"
        f" load average {os.getloadavg()[0]:.1f}"
    )
    assert first is not None
    print(f"  first request after start (budget {budgets[0]:g} ms): {first[0]}, {first[1]:.1f} ms")
    print("  budget     ok timeout other optimal  dur/none p50    max  within 1.03x   round trip p50    p99    max ms")
    for b, rs in rows.items():
        codes = [r[0] for r in rs]
        walls = np.array([r[1] for r in rs])
        ratio = np.array([r[3] for r in rs]) / ref
        ok = np.isfinite(ratio)
        within = float(np.mean(np.where(ok, ratio <= 1.03, False)))
        name = "none" if b == NONE_MS else f"{b:g} ms"
        print(
            f"  {name:8s} {codes.count('ok'):4d} {codes.count('timeout'):7d}"
            f" {len(codes) - codes.count('ok') - codes.count('timeout'):5d}"
            f" {sum(r[2] for r in rs):7d} {np.nanmedian(ratio):9.4f} {np.nanmax(ratio):6.4f} {100 * within:10.0f} %"
            f" {np.percentile(walls, 50):17.1f} {np.percentile(walls, 99):6.1f} {np.max(walls):6.1f}"
        )
    print(
        f"  command: python bench/jerk_service.py --paths {args.paths} --budgets {args.budgets}"
        f" --factor {args.factor:g} --seed {args.seed}{' --planner-process' if args.planner_process else ''}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
