"""The on-path stop, pause + resume and the speed override on the shipped gantry cells (issue 37's figures).

Per cell, in lockstep on the simulated drives (the motions' program time is the drives' own; the
computation's wall time is measured around the change, the group's lock held): a straight move across 85 %
of every joint's range from 15 % (the tour of tests/service/test_stop_then_move.py), interrupted at 20-80 %
of its duration.

- ``stop`` (path): the joints' largest distance from the path of the program as started, on the drives'
  reconstruction of the records they ran (mm: the gantry's joints are the tool's x, y, z), against the
  quick stop's (each axis braking on its own 0x60C5 from the state at the request, the drives' halt);
  request -> braking begun and -> rest (program ms, p50 / p99) against ``max_lookahead_ms``; the peak
  |v| / 0x607F and |a| / 0x60C5 of the braking records; the change's computation (wall ms, p50 / p99).
- ``override 0.3`` at 30 %: request -> the new speed applies (``from_ms``, program ms).
- ``pause`` at 40 % + ``resume``: the two motions' time against the uninterrupted program.

Run:  PYTHONPATH=. python3 bench/onpath_service.py [--runs N]  (the planner alone: bench/onpath_stop.py)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.drive.program import PvtProgram  # noqa: E402
from pvtflow.service.api import (  # noqa: E402
    parse_execute,
    parse_home,
    parse_override,
    parse_pause,
    parse_plan,
    parse_resume,
    parse_stop,
)
from pvtflow.service.config import CONFIG_DIR, load_cell_config  # noqa: E402
from pvtflow.service.motion import MotionService, onpath  # noqa: E402

CELLS = ("gantry3", "gantry3-ip-linear", "gantry3-sync-setpoint", "gantry3-parker", "gantry3-mixed")
FRACTIONS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)


def cell_file(name: str):
    cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=f"bench-onpath-{name}-{time.time_ns()}"))
    axes = tuple(
        dataclasses.replace(a, simulation=dataclasses.replace(a.simulation, power_up_qc=a.homing.offset_qc))
        if a.homing is not None and a.simulation is not None
        else a
        for a in cell.axes
    )
    return dataclasses.replace(cell, axes=axes)


def at(cell, fraction: float) -> list[float]:
    lim = cell.joint_limits()
    return [lo + fraction * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)]


def move(svc: MotionService, fraction: float, wait: bool) -> None:
    req = parse_plan(
        {"waypoints": [at(svc.cell, fraction)], "start": "current", "budget_ms": 10000},
        svc.cell.joint_names,
        svc.cell.joint_limits(),
    )
    svc.execute(parse_execute({"plan_id": svc.plan(req)["plan_id"], "wait": wait}))


def running(svc: MotionService, fraction: float) -> PvtProgram:
    move(svc, 0.15, True)
    move(svc, 0.85, False)
    group = svc.group
    program = PvtProgram(svc.cell.name, group.programs)
    period = svc.cell.bus.sync_period_ms
    target = fraction * program.duration_ms
    while (group.elapsed_syncs() or 0) * period < target:
        time.sleep(0.0005)
    return program


def joints(program: PvtProgram, t: np.ndarray) -> np.ndarray:
    return np.column_stack([a.scaling.qc_to_position(a.reconstruction().position(t)) for a in program.axes])


def distance(points: np.ndarray, line: np.ndarray) -> float:
    a, ab = line[:-1], np.diff(line, axis=0)
    l2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30)
    worst = 0.0
    for p in points:
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / l2, 0.0, 1.0)
        worst = max(worst, float(np.min(np.linalg.norm(a + s[:, None] * ab - p, axis=1))))
    return worst


def quick_stop_distance(program: PvtProgram, t_ms: float, line: np.ndarray) -> float:
    """Each axis from its state at ``t_ms`` braking on its own 0x60C5 to rest (the halt), off the path."""
    pts = []
    tau = np.linspace(0.0, 1.0, 60)
    for a in program.axes:
        rec = a.reconstruction()
        p0, v0 = float(rec.position(np.array([t_ms]))[0]), float(rec.velocity(np.array([t_ms]))[0])
        amax = float(a.scaling.rpm_s_to_qc_per_ms2(a.limits.max_acceleration_rpm_s))
        tb = abs(v0) / amax
        tt = tau * tb
        pts.append(a.scaling.qc_to_position(p0 + v0 * tt - 0.5 * np.sign(v0) * amax * tt * tt))
    return distance(np.column_stack(pts), line)


def ratios(program: PvtProgram, t0: float, t1: float) -> tuple[float, float]:
    rv = ra = 0.0
    for a in program.axes:
        rec = a.reconstruction()
        seg = (rec.start + rec.duration > t0) & (rec.start < t1)
        if not seg.any():
            continue
        vmax = float(a.scaling.rpm_to_qc_per_ms(a.limits.max_profile_velocity_rpm))
        amax = float(a.scaling.rpm_s_to_qc_per_ms2(a.limits.max_acceleration_rpm_s))
        rv = max(rv, float(rec.max_abs_velocity()[seg].max()) / vmax)
        ra = max(ra, float(rec.max_abs_acceleration()[seg].max()) / amax)
    return rv, ra


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q)) if xs else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="passes over the stop fractions (default 1)")
    args = ap.parse_args()
    computed: list[float] = []
    real_splice = onpath.splice_run

    def timed(*a, **k):
        t = time.perf_counter()
        try:
            return real_splice(*a, **k)
        finally:
            computed.append((time.perf_counter() - t) * 1000.0)

    onpath.splice_run = timed
    why: list[str] = []
    print(
        "cell                  | path mm | quick mm | begun p50/p99 ms | rest p50/p99 ms | |v| |a| % "
        "| compute p50/p99 ms | override from ms | pause+resume / plan ms | fallbacks"
    )
    for name in CELLS:
        computed.clear()
        svc = MotionService(cell_file(name), journal_dir=tempfile.mkdtemp(), clock=Clock.LOCKSTEP).open()
        try:
            if svc.cell.requires_homing:
                svc.home(parse_home({"wait": True}))
            lookahead = svc.cell.bus.max_lookahead_ms
            path_mm, quick_mm, begun, rest, rv, ra, fallbacks = [], [], [], [], 0.0, 0.0, 0
            for _ in range(args.runs):
                for fraction in FRACTIONS:
                    before = running(svc, fraction)
                    reply = svc.stop(parse_stop({}))
                    b = reply["braking"]
                    if b is None:
                        fallbacks += 1
                        why.append(f"{name} at {fraction:g}: {reply['fallback'][:160]}")
                        continue
                    if b["begun_ms"] is None:  # braking would end where the motion does: it runs to its end
                        why.append(f"{name} at {fraction:g}: ran to its own end (the path ends before a braking would)")
                        continue
                    after = PvtProgram(svc.cell.name, svc.group.programs)
                    line = joints(before, np.arange(0.0, before.duration_ms + 0.05, 0.05))
                    path_mm.append(
                        1000.0 * distance(joints(after, np.arange(b["begun_ms"] - 20.0, after.duration_ms + 1.0)), line)
                    )
                    quick_mm.append(1000.0 * quick_stop_distance(before, b["requested_ms"], line))
                    begun.append(b["begun_ms"] - b["requested_ms"])
                    rest.append(b["ended_ms"] - b["requested_ms"])
                    v, a = ratios(after, b["begun_ms"], b["ended_ms"])
                    rv, ra = max(rv, v), max(ra, a)
            stops = list(computed)
            before = running(svc, 0.3)
            over = svc.override(parse_override({"scale": 0.3}))
            svc.motion.done.wait(60.0)
            before = running(svc, 0.4)
            paused = svc.pause(parse_pause({}))
            resumed = svc.resume(parse_resume({"wait": True}))
            total = paused["braking"]["ended_ms"] + resumed["duration_ms"]
            print(
                f"{name:21s} | {max(path_mm):7.4f} | {max(quick_mm):8.2f} "
                f"| {pct(begun, 50):6.1f} / {pct(begun, 99):6.1f} | {pct(rest, 50):6.1f} / {pct(rest, 99):6.1f} "
                f"| {100 * rv:4.1f} {100 * ra:4.1f} "
                f"| {pct(stops, 50):6.1f} / {pct(stops, 99):6.1f} | {over['from_ms'] - over['requested_ms']:6.1f} "
                f"| {total:7.1f} / {before.duration_ms} | {fallbacks} (look-ahead {lookahead:g} ms)"
            )
        finally:
            svc.close()
    for line in why:
        print("fallback:", line)
    print("command: PYTHONPATH=. python3 bench/onpath_service.py")


if __name__ == "__main__":
    main()
