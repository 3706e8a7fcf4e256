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
- ``override 0.5`` at 20 %, then ``override 1.0`` 150 ms after it applied: request -> the program's own records
  run again (program ms, the first record from which every axis's records are the program's, that much later),
  how much later the motion ends, the drives' violations.
- a jerk-limited plan (``max_jerk`` 10 x each joint's acceleration limit /s) on gantry3, ``stop`` (path) at 20-80 %:
  the drives' 10-ms-window jerk of the braking's records against the limit (the knot placement holds 1.2 x), the
  braking's time, and the same with the braking not jerk-limited (as before: the greedy deceleration).

- ``--part transitions``: per cell at 20-80 %, override 0.3 (request -> new speed, |v| |a| peaks in the 300 ms
  after it applies) and pause + resume (the total motion time against the uninterrupted plan, the braking's and the
  resume ramp's peaks, the ramp's length before every axis runs the program's own records again).
- ``--part jerk-changes``: the jerk-limited plan's override 0.5 -> 1.0 and pause + resume: the records' window jerk;
  the same late on a path of two waypoints off one line in joint space (gantry3, arm6): 1.0 reached, its call's time.
- ``--part cyclic``: gantry3 with ``bus.cyclic_process`` on the wall clock (SYNC 3 and 10 ms, the drives in their
  own process): path stop, override, pause + resume through the cyclic process's feeders.

Run:  PYTHONPATH=. python3 bench/onpath_service.py [--runs N] [--part all|stops|back|jerk|transitions|jerk-changes]
(the planner alone: bench/onpath_stop.py)
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
from pvtflow.axes.drive.program import PvtProgram, split_long_records  # noqa: E402
from pvtflow.axes.master.group import axis_group  # noqa: E402
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk_profile  # noqa: E402
from pvtflow.service.api import (  # noqa: E402
    ApiError,
    ErrorCode,
    parse_execute,
    parse_home,
    parse_override,
    parse_pause,
    parse_plan,
    parse_recover,
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
    return distance(quick_stop_joints(program, t_ms), line)


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


def open_cell(name: str) -> MotionService:
    svc = MotionService(cell_file(name), journal_dir=tempfile.mkdtemp(), clock=Clock.LOCKSTEP).open()
    if svc.cell.requires_homing:
        svc.home(parse_home({"wait": True}))
    return svc


def wait_ms(svc: MotionService, t_ms: float) -> None:
    while (svc.group.elapsed_syncs() or 0) * svc.cell.bus.sync_period_ms < t_ms and not svc.motion.done.is_set():
        time.sleep(0.0005)


def back_to_plan() -> None:
    """override 0.5 at 20 %, 1.0 150 ms after it applied: when the program's own records run again."""
    print(
        "cell                  | 0.5 from ms | 1.0 from ms (scale) | own records from ms (request ->) | later ms "
        "| 0.99 applied | faults"
    )
    for name in CELLS:
        svc = open_cell(name)
        try:
            before = running(svc, 0.2)
            slow = svc.override(parse_override({"scale": 0.5}))
            wait_ms(svc, slow["from_ms"] + 150.0)
            back = svc.override(parse_override({"scale": 1.0}))
            svc.motion.done.wait(60.0)
            after = PvtProgram(svc.cell.name, svc.group.programs)
            half = max(1, int(svc.cell.bus.max_lookahead_ms / 2))
            own = 0.0
            for a, b in zip(after.axes, before.axes, strict=True):
                fed = split_long_records(b, half)
                n = 0  # the records at the end that are the program's own
                while n < min(len(fed), len(a.records)) and (a.records[-1 - n] == fed[-1 - n]).all():
                    n += 1
                own = max(own, float(np.sum(a.records[: len(a.records) - n, 2])))
            running(svc, 0.3)
            near = svc.override(parse_override({"scale": 0.99}))  # the limits' room below the plan's speed
            svc.motion.done.wait(60.0)
            faults = sum(len(d.faults) for d in svc.sim)
            print(
                f"{name:21s} | {slow['from_ms']:11.1f} | {back['from_ms']:11.1f} ({back['scale']:.4g}) "
                f"| {own:7.1f} ({own - back['requested_ms']:6.1f}) "
                f"| {after.duration_ms - before.duration_ms:8d} | {near['scale']:.4g} "
                f"| {faults} ({svc.motion.outcome['result']})"
            )
        finally:
            svc.close()


def jerk_ratio(program: PvtProgram, max_jerk: list[float], from_ms: float) -> float:
    worst = 0.0
    for a, jmax in zip(program.axes, max_jerk, strict=True):
        t, jerk = window_jerk_profile(a.reconstruction())
        worst = max(
            worst, float(jerk[t >= from_ms - WINDOW_MS].max()) / (jmax * abs(a.scaling.qc_per_joint_unit) * 1e-9)
        )
    return worst


def jerk_limited_stops(runs: int) -> None:
    """A jerk-limited plan stopped on its path: the records' window jerk, jerk-limited braking against greedy."""
    real = onpath.planned_jerk
    print("gantry3, jerk-limited plan | braking    | window jerk / limit max | begun -> rest p50 / max ms | path mm")
    for braking in ("jerk-limited", "greedy"):
        onpath.planned_jerk = real if braking == "jerk-limited" else (lambda metadata: None)
        svc = open_cell("gantry3")
        ratios_, rest, path_mm, quick, to_end = [], [], [], [], 0
        try:
            limits = svc.cell.joint_limits()
            max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]
            for _ in range(runs):
                for fraction in FRACTIONS:
                    for to in (0.15, 0.85):
                        req = {"waypoints": [at(svc.cell, to)], "start": "current", "max_jerk": max_jerk}
                        plan = svc.plan(parse_plan(req, svc.cell.joint_names, limits))
                        svc.execute(parse_execute({"plan_id": plan["plan_id"], "wait": to == 0.15}))
                    before = PvtProgram(svc.cell.name, svc.group.programs)
                    wait_ms(svc, fraction * before.duration_ms)
                    reply = svc.stop(parse_stop({}))
                    b = reply["braking"]
                    if b is None:
                        quick.append(f"{fraction:g}: {reply['fallback'][:120]}")
                        continue
                    if b["begun_ms"] is None:  # the path ends before the braking would: the motion's own end
                        to_end += 1
                        continue
                    after = PvtProgram(svc.cell.name, svc.group.programs)
                    ratios_.append(jerk_ratio(after, max_jerk, b["begun_ms"]))
                    rest.append(b["ended_ms"] - b["begun_ms"])
                    line = joints(before, np.arange(0.0, before.duration_ms + 0.05, 0.05))
                    pts = joints(after, np.arange(b["begun_ms"] - 20.0, after.duration_ms + 1.0))
                    path_mm.append(1000.0 * distance(pts, line))
        finally:
            svc.close()
            onpath.planned_jerk = real
        print(
            f"{'':26s} | {braking:10s} | {max(ratios_):23.2f} | {pct(rest, 50):9.1f} / {max(rest):6.1f} "
            f"| {max(path_mm):.4f} ({len(rest)} stops, {to_end} ran to their end, {len(quick)} quick)"
        )
        for why in quick:
            print(f"{'':26s} | quick at {why}")


def own_tail(after, before, half: int) -> tuple[int, float]:
    """(how many records at the end of ``after`` are the program's own, as its feeder held them, at least over
    the axes; the time before them, ms, at most): where a resumed or re-joined motion runs the planned records."""
    n_min, lead = 10**9, 0.0
    for a, b in zip(after.axes, before.axes, strict=True):
        fed = split_long_records(b, half)
        n = 0
        while n < min(len(fed), len(a.records)) and (a.records[-1 - n] == fed[-1 - n]).all():
            n += 1
        n_min = min(n_min, n)
        lead = max(lead, float(np.sum(a.records[: len(a.records) - n, 2])))
    return n_min, lead


def transitions(runs: int) -> None:
    """Per cell, at 20-80 % of the move: ``override 0.3`` (request -> new speed, the peaks in the 300 ms after it
    applies), and ``pause`` + ``resume`` (the total motion time against the uninterrupted plan, the braking's
    and the resume ramp's peaks, how long the ramp takes before the planned records run again)."""
    print(
        "cell                  | override 0.3: request->speed p50/p99 ms, |v| |a| % | pause+resume: extra ms "
        "p50/max (plan ms), braking |v| |a| %, ramp ms p50/max, ramp |v| |a| %, own records from | resumes"
    )
    refused: list[str] = []
    for name in CELLS:
        svc = open_cell(name)
        to_speed, extra, ramp, plans = [], [], [], []
        orv = ora = brv = bra = rrv = rra = 0.0
        done, own_min = 0, 10**9
        half = max(1, int(svc.cell.bus.max_lookahead_ms / 2))
        try:
            for _ in range(runs):
                for fraction in FRACTIONS:
                    running(svc, fraction)
                    try:
                        over = svc.override(parse_override({"scale": 0.3}))
                    except ApiError as exc:  # too close to the end: refused, nothing changed
                        refused.append(f"{name} at {fraction:g}: {exc}")
                    else:
                        to_speed.append(over["from_ms"] - over["requested_ms"])
                        after = PvtProgram(svc.cell.name, svc.group.programs)
                        v, a = ratios(after, over["from_ms"], over["from_ms"] + 300.0)
                        orv, ora = max(orv, v), max(ora, a)
                    svc.motion.done.wait(60.0)
                    before = running(svc, fraction)
                    paused = svc.pause(parse_pause({}))
                    if not paused["paused"]:
                        refused.append(f"{name} at {fraction:g}: pause ran to the motion's end")
                        continue  # ran to its end (the path ends before a braking would) or quick
                    b = paused["braking"]
                    v, a = ratios(PvtProgram(svc.cell.name, svc.group.programs), b["begun_ms"], b["ended_ms"])
                    brv, bra = max(brv, v), max(bra, a)
                    resumed = svc.resume(parse_resume({"wait": True}))
                    after = PvtProgram(svc.cell.name, svc.group.programs)
                    n, lead = own_tail(after, before, half)
                    own_min = min(own_min, n)
                    ramp.append(lead)
                    v, a = ratios(after, 0.0, lead)
                    rrv, rra = max(rrv, v), max(rra, a)
                    extra.append(b["ended_ms"] + resumed["duration_ms"] - before.duration_ms)
                    plans.append(before.duration_ms)
                    done += resumed["outcome"]["result"] == "finished"
            faults = sum(len(d.faults) for d in svc.sim)
            lookahead = svc.cell.bus.max_lookahead_ms
            print(
                f"{name:21s} | {pct(to_speed, 50):6.1f} / {pct(to_speed, 99):6.1f}, {100 * orv:4.1f} {100 * ora:4.1f} "
                f"| {pct(extra, 50):6.1f} / {max(extra):6.1f} ({int(np.median(plans))}), "
                f"{100 * brv:4.1f} {100 * bra:4.1f}, "
                f"{pct(ramp, 50):6.1f} / {max(ramp):6.1f}, {100 * rrv:4.1f} {100 * rra:4.1f}, >= {own_min} records "
                f"| {done}/{len(extra)} finished, {faults} drive faults (look-ahead {lookahead:g} ms)"
            )
        finally:
            svc.close()
    for why in refused:
        print("not made:", why)
    print("command: PYTHONPATH=. python3 bench/onpath_service.py --part transitions")


# a path off one line in joint space: two waypoints, the joints' shares of their ranges differing (gantry3's x, y, z;
# arm6's six joints), from 15 % of every range
BENT = ((0.5, 0.8, 0.3, 0.5, 0.5, 0.5), (0.85, 0.3, 0.8, 0.7, 0.3, 0.6))


def jerk_changes() -> None:
    """A jerk-limited plan on gantry3: override 0.5 then 1.0, pause + resume at 20-80 %: the records' window jerk;
    then the same late ones on paths off one line in joint space (gantry3, arm6)."""
    print("gantry3, jerk-limited plan | override 0.5 / 1.0 window jerk / limit max | resume: window jerk max, extra ms")
    svc = open_cell("gantry3")
    try:
        limits = svc.cell.joint_limits()
        max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]

        def go(fraction: float) -> PvtProgram:
            for to in (0.15, 0.85):
                req = {"waypoints": [at(svc.cell, to)], "start": "current", "max_jerk": max_jerk, "budget_ms": 10000}
                plan = svc.plan(parse_plan(req, svc.cell.joint_names, limits))
                svc.execute(parse_execute({"plan_id": plan["plan_id"], "wait": to == 0.15}))
            before = PvtProgram(svc.cell.name, svc.group.programs)
            wait_ms(svc, fraction * before.duration_ms)
            return before

        slow_j, back_j, res_j, extra, scales, limited, later = [], [], [], [], [], [], []
        placed = 0
        for fraction in FRACTIONS[:4]:
            before = go(fraction)
            slow = svc.override(parse_override({"scale": 0.5}))
            slow_j.append(jerk_ratio(PvtProgram(svc.cell.name, svc.group.programs), max_jerk, slow["from_ms"]))
            wait_ms(svc, slow["from_ms"] + 150.0)
            began = time.perf_counter()
            back = svc.override(parse_override({"scale": 1.0}))
            call_ms = (time.perf_counter() - began) * 1000.0
            scales.append(back["scale"])
            if back["limited"]:
                limited.append(f"at {fraction:g}: {back['limited']}")
            back_j.append(jerk_ratio(PvtProgram(svc.cell.name, svc.group.programs), max_jerk, back["from_ms"]))
            svc.motion.done.wait(60.0)
            later.append(
                f"at {fraction:g}: 1.0 from {back['from_ms']:.0f} ms, scale {back['scale']:.4g}, ends "
                f"{back['duration_ms'] - before.duration_ms} ms after the plan, the call {call_ms:.0f} ms (wall)"
            )
        for fraction in FRACTIONS:
            before = go(fraction)
            paused = svc.pause(parse_pause({}))
            if not paused["paused"]:
                continue
            out = svc.resume(parse_resume({"wait": True}))
            res_j.append(jerk_ratio(PvtProgram(svc.cell.name, svc.group.programs), max_jerk, 0.0))
            extra.append(paused["braking"]["ended_ms"] + out["duration_ms"] - before.duration_ms)
            placed += not svc.motion.program.metadata["resumed_on_planned_records"]
        faults = sum(len(d.faults) for d in svc.sim)
        print(
            f"{'':26s} | {max(slow_j):.2f} / {max(back_j):.2f} (1.0 applied as {min(scales):g}) "
            f"| {max(res_j):.2f}, {pct(extra, 50):.0f} / {max(extra):.0f} ({len(res_j)} resumes, {placed} placed from "
            f"rest, {faults} faults)"
        )
        for why in limited:
            print(f"{'':26s} | override 1.0 {why}")
        for line in later:
            print(f"{'':26s} | override 0.5 then {line}")
    finally:
        svc.close()
    for name, fractions in (("gantry3", (0.4, 0.5, 0.55, 0.6)), ("arm6", (0.6, 0.7, 0.75))):
        bent_changes(name, fractions)
    print("command: PYTHONPATH=. python3 bench/onpath_service.py --part jerk-changes")


def bent_changes(name: str, fractions: tuple[float, ...]) -> None:
    """A jerk-limited plan along ``BENT`` on ``name``: override 0.5 at each fraction, 1.0 150 ms after it applied
    (scale applied, why not 1, how much after the plan the motion ends, the call's wall time, the records' window
    jerk of the limit from the 1.0 on); pause at each fraction + resume (on the plan's records or placed from rest,
    the extra ms against the plan, the window jerk); the drives' faults."""
    svc = open_cell(name)
    try:
        limits = svc.cell.joint_limits()
        dof = len(limits.lower)
        max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]
        bent = [
            [lo + f * (hi - lo) for f, lo, hi in zip(fs[:dof], limits.lower, limits.upper, strict=True)] for fs in BENT
        ]

        def go(fraction: float) -> PvtProgram:
            for wps, wait in (([at(svc.cell, 0.15)], True), (bent, False)):
                req = {"waypoints": wps, "start": "current", "max_jerk": max_jerk, "budget_ms": 10000}
                plan = svc.plan(parse_plan(req, svc.cell.joint_names, limits))
                out = svc.execute(parse_execute({"plan_id": plan["plan_id"], "wait": wait}))
                if wait and out["outcome"]["result"] != "finished":
                    raise ApiError(ErrorCode.NOT_ALLOWED, f"the move to 15 % ended {out['outcome']['result']}")
            before = PvtProgram(svc.cell.name, svc.group.programs)
            wait_ms(svc, fraction * before.duration_ms)
            return before

        def started(fraction: float) -> PvtProgram | None:
            """``go``; None where the cell faulted on the way (a loaded host starves the lockstep wire: noted)."""
            try:
                return go(fraction)
            except ApiError as exc:
                print(f"  at {fraction:g}: not started ({exc}); recovered")
                svc.recover(parse_recover({}))
                return None

        print(f"{name}, jerk-limited, two waypoints off one line:")
        for fraction in fractions:
            if (before := started(fraction)) is None:
                continue
            try:
                slow = svc.override(parse_override({"scale": 0.5}))
            except ApiError as exc:
                print(f"  override 0.5 at {fraction:g}: refused ({exc})")
                svc.motion.done.wait(60.0)
                continue
            wait_ms(svc, slow["from_ms"] + 150.0)
            began = time.perf_counter()
            back = svc.override(parse_override({"scale": 1.0}))
            call_ms = (time.perf_counter() - began) * 1000.0
            jerk = jerk_ratio(PvtProgram(svc.cell.name, svc.group.programs), max_jerk, back["from_ms"])
            svc.motion.done.wait(60.0)
            print(
                f"  override 0.5 at {fraction:g}, 1.0 from {back['from_ms']:.0f} of {before.duration_ms} ms: scale "
                f"{back['scale']:.4g}{' (' + back['limited'] + ')' if back['limited'] else ''}, ends "
                f"{back['duration_ms'] - before.duration_ms} ms after the plan, the call {call_ms:.0f} ms (wall), "
                f"window jerk {jerk:.2f}, {svc.motion.outcome['result']}"
            )
        for fraction in fractions:
            if (before := started(fraction)) is None:
                continue
            paused = svc.pause(parse_pause({}))
            if not paused["paused"]:
                svc.motion.done.wait(60.0)
                continue
            out = svc.resume(parse_resume({"wait": True}))
            how = "on the plan's records" if svc.motion.program.metadata["resumed_on_planned_records"] else "from rest"
            print(
                f"  pause at {fraction:g} (rest at {paused['braking']['ended_ms']:.0f} of {before.duration_ms} ms) + "
                f"resume: {how}, "
                f"+{paused['braking']['ended_ms'] + out['duration_ms'] - before.duration_ms:.0f} ms, window jerk "
                f"{jerk_ratio(PvtProgram(svc.cell.name, svc.group.programs), max_jerk, 0.0):.2f}, "
                f"{out['outcome']['result']}"
            )
        print(f"  faults: {sum(len(d.faults) for d in svc.sim)}")
    finally:
        svc.close()


ALL_CELLS = (*CELLS, "arm6")


def tool_points(cell, program: PvtProgram, q: np.ndarray) -> np.ndarray:
    """The tool's position (m, the cell's TCP frame) at each row of ``q`` (joint units, in ``program``'s axis
    order): the gantry's joints are its tool's x, y, z, the arm's through its kinematics."""
    model, frame = cell.model, cell.planning.tcp_frame
    order = np.array([model.index(a.joint) for a in program.axes])
    full = np.zeros((len(q), len(order)))
    full[:, order] = q
    return np.array([model.frame_placement(row, frame)[:3, 3] for row in full])


def quick_stop_joints(program: PvtProgram, t_ms: float) -> np.ndarray:
    """Each axis from its state at ``t_ms`` braking on its own 0x60C5 to rest (the halt), joint units."""
    pts = []
    tau = np.linspace(0.0, 1.0, 60)
    for a in program.axes:
        rec = a.reconstruction()
        p0, v0 = float(rec.position(np.array([t_ms]))[0]), float(rec.velocity(np.array([t_ms]))[0])
        amax = float(a.scaling.rpm_s_to_qc_per_ms2(a.limits.max_acceleration_rpm_s))
        tt = tau * abs(v0) / amax
        pts.append(a.scaling.qc_to_position(p0 + v0 * tt - 0.5 * np.sign(v0) * amax * tt * tt))
    return np.column_stack(pts)


def speed_reached_ms(svc: MotionService, over: dict) -> float:
    """Program ms at which the overridden motion runs at its new speed (its path speed the scale's, the motion's
    path and timing as the service re-timed it)."""
    path = svc.changes.paths[over["motion_id"]]
    running, scale = path.running, path.scale
    i = int(np.searchsorted(running.breakpoints, over["from_ms"] / 1000.0))
    if i >= len(running.gridpoints) - 1:
        return float("nan")  # the motion ends where the change would begin
    s_from = float(running.gridpoints[i])
    at = np.nonzero((running.gridpoints >= s_from) & (np.abs(running.sd - scale) < 1e-6))[0]
    return float(running.breakpoints[at[0]]) * 1000.0 if len(at) else float("nan")


def per_cell(runs: int) -> None:
    """Every figure the issue asks, per cell (the five gantry profiles and arm6), lockstep: at each of 20-80 % of
    the move a path stop, an ``override 0.3`` and a ``pause`` + ``resume``, each on a motion of its own."""
    print(
        "cell                  | tool mm path / quick | stop begun p50/p99 ms | rest p50/p99 ms | look-ahead ms "
        "| braking |v| |a| % | override 0.3 begins -> at speed p50/p99 ms, |v| |a| % "
        "| pause+resume extra p50/max ms (plan), ramp |v| |a| %, placed from rest | not made | faults"
    )
    notes: list[str] = []
    for name in ALL_CELLS:
        svc = open_cell(name)
        cell = svc.cell
        path_mm, quick_mm, begun, rest, to_speed, extra, plans = [], [], [], [], [], [], []
        reached: list[float] = []
        brv = bra = orv = ora = rrv = rra = 0.0
        placed = not_made = svc_faults = lost_faults = 0
        half = max(1, int(cell.bus.max_lookahead_ms / 2))
        try:
            for _ in range(runs):
                for fraction in FRACTIONS:
                    faulted = sum(len(d.faults) for d in svc.sim)
                    try:
                        before = running(svc, fraction)
                        b = svc.stop(parse_stop({}))["braking"]
                        if b is None or b["begun_ms"] is None:
                            not_made += 1
                            notes.append(
                                f"{name} stop at {fraction:g}: " + ("quick" if b is None else "ran to its end")
                            )
                        else:
                            after = PvtProgram(cell.name, svc.group.programs)
                            line = tool_points(
                                cell, before, joints(before, np.arange(0.0, before.duration_ms + 0.1, 0.1))
                            )
                            t = np.arange(b["begun_ms"] - 20.0, after.duration_ms + 1.0)
                            path_mm.append(1000.0 * distance(tool_points(cell, after, joints(after, t)), line))
                            quick = tool_points(cell, before, quick_stop_joints(before, b["requested_ms"]))
                            quick_mm.append(1000.0 * distance(quick, line))
                            begun.append(b["begun_ms"] - b["requested_ms"])
                            rest.append(b["ended_ms"] - b["requested_ms"])
                            v, a = ratios(after, b["begun_ms"], b["ended_ms"])
                            brv, bra = max(brv, v), max(bra, a)
                        svc.motion.done.wait(60.0)
                        running(svc, fraction)
                        try:
                            over = svc.override(parse_override({"scale": 0.3}))
                        except ApiError as exc:
                            not_made += 1
                            notes.append(f"{name} override at {fraction:g}: {str(exc)[:140]}")
                        else:
                            to_speed.append(over["from_ms"] - over["requested_ms"])
                            reached.append(speed_reached_ms(svc, over) - over["requested_ms"])
                            v, a = ratios(
                                PvtProgram(cell.name, svc.group.programs), over["from_ms"], over["from_ms"] + 300.0
                            )
                            orv, ora = max(orv, v), max(ora, a)
                        svc.motion.done.wait(60.0)
                        before = running(svc, fraction)
                        paused = svc.pause(parse_pause({}))
                        if not paused["paused"]:
                            not_made += 1
                            notes.append(f"{name} pause at {fraction:g}: ran to its end")
                            svc.motion.done.wait(60.0)
                            continue
                        pb = paused["braking"]
                        v, a = ratios(PvtProgram(cell.name, svc.group.programs), pb["begun_ms"], pb["ended_ms"])
                        brv, bra = max(brv, v), max(bra, a)
                        resumed = svc.resume(parse_resume({"wait": True}))
                        after = PvtProgram(cell.name, svc.group.programs)
                        _, lead = own_tail(after, before, half)
                        if not svc.motion.program.metadata["resumed_on_planned_records"]:  # placed from rest
                            placed += 1
                            lead = float(after.duration_ms)
                        v, a = ratios(after, 0.0, lead)
                        rrv, rra = max(rrv, v), max(rra, a)
                        extra.append(pb["ended_ms"] + resumed["duration_ms"] - before.duration_ms)
                        plans.append(before.duration_ms)
                        if resumed["outcome"]["result"] != "finished":
                            notes.append(f"{name} resume at {fraction:g}: {resumed['outcome']}")
                    except ApiError as exc:  # the host stalled the lockstep bus past a heartbeat (load): noted
                        notes.append(f"{name} at {fraction:g}: {str(exc)[:160]}")
                        svc_faults += 1
                        lost_faults += sum(len(d.faults) for d in svc.sim) - faulted
                        svc.recover(parse_recover({}))
                        if svc.cell.requires_homing:
                            svc.home(parse_home({"wait": True}))
            faults = sum(len(d.faults) for d in svc.sim)
            reached_ = [r for r in reached if np.isfinite(r)]  # nan: the motion ended before the new speed
            print(
                f"{name:21s} | {max(path_mm):7.4f} / {max(quick_mm):6.2f} "
                f"| {pct(begun, 50):6.1f} / {pct(begun, 99):6.1f} | {pct(rest, 50):6.1f} / {pct(rest, 99):6.1f} "
                f"| {cell.bus.max_lookahead_ms:5.0f} (SYNC {cell.bus.sync_period_ms:g}) "
                f"| {100 * brv:5.1f} {100 * bra:5.1f} "
                f"| {pct(to_speed, 50):6.1f} / {pct(to_speed, 99):6.1f} "
                f"-> {pct(reached_, 50):6.1f} / {pct(reached_, 99):6.1f} ({len(reached) - len(reached_)} ended first), "
                f"{100 * orv:5.1f} {100 * ora:5.1f} "
                f"| {pct(extra, 50):6.1f} / {max(extra):6.1f} ({int(np.median(plans))}), "
                f"{100 * rrv:5.1f} {100 * rra:5.1f}, {placed}/{len(extra)} "
                f"| {not_made} | {faults - lost_faults} "
                f"({svc_faults} runs lost to a stalled host, {lost_faults} faults in them)"
            )
        finally:
            svc.close()
    for line in notes:
        print("note:", line)
    print(f"command: PYTHONPATH=. python3 bench/onpath_service.py --part cells --runs {runs}")


def cyclic_cell(period_ms: float):
    """gantry3 with ``bus.cyclic_process`` (the drives served in a process of their own), not homed."""
    import yaml

    source = CONFIG_DIR / "cells" / "gantry3.yaml"
    data = yaml.safe_load(source.read_text())
    for axis in data["axes"]:
        axis.pop("homing", None)
        axis.setdefault("simulation", {})["power_up_qc"] = 0
    data.pop("homing_order", None)
    data.pop("requires_homing", None)
    data["bus"].update(cyclic_process=True, sync_period_ms=period_ms)
    if "urdf" in data.get("robot", {}):
        data["robot"]["urdf"] = str((source.parent / data["robot"]["urdf"]).resolve())
    copy = Path(tempfile.mkdtemp()) / "gantry3.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_cell_config(copy)


def cyclic(runs: int) -> None:
    """gantry3 (EPOS2) with ``bus.cyclic_process`` on the wall clock, the drives in their own process: path stop
    at 20-60 %, override 0.3 at 30 %, pause + resume at 40 %: request -> braking begun / rest and -> new speed
    (program ms on the drives' clock), what was made or refused, the resumed motion's end against the plan."""
    from pvtflow.axes.canbus.clock import Clock as _Clock

    for period in (3.0, 10.0):  # the cell's own period, and the tests' 10 ms
        cell = cyclic_cell(period)
        svc = MotionService(cell, journal_dir=tempfile.mkdtemp(), clock=_Clock.WALL, drives_process=True).open()
        begun, rest, over, extra, quick = [], [], [], [], []
        try:
            for _ in range(runs):
                for fraction in (0.2, 0.3, 0.4, 0.5, 0.6):
                    running(svc, fraction)
                    reply = svc.stop(parse_stop({}))
                    b = reply["braking"]
                    if b is None:
                        quick.append(f"stop at {fraction:g}: {reply['fallback'][:100]}")
                    elif b["begun_ms"] is not None:
                        begun.append(b["begun_ms"] - b["requested_ms"])
                        rest.append(b["ended_ms"] - b["requested_ms"])
                running(svc, 0.3)
                try:
                    o = svc.override(parse_override({"scale": 0.3}))
                    over.append(o["from_ms"] - o["requested_ms"])
                except ApiError as exc:
                    quick.append(f"override: {exc}")
                svc.motion.done.wait(60.0)
                before = running(svc, 0.4)
                paused = svc.pause(parse_pause({}))
                if paused["paused"]:
                    out = svc.resume(parse_resume({"wait": True}))
                    if out["outcome"]["result"] == "finished":
                        extra.append(paused["braking"]["ended_ms"] + out["duration_ms"] - before.duration_ms)
                else:
                    quick.append(f"pause: {paused['fallback']}")
        finally:
            svc.close()
        print(
            f"SYNC {period:g} ms | stop begun p50/max {pct(begun, 50):.1f} / {max(begun, default=float('nan')):.1f} "
            f"| rest p50/max {pct(rest, 50):.1f} / {max(rest, default=float('nan')):.1f} "
            f"| override from {pct(over, 50):.1f} | pause+resume extra {pct(extra, 50):.0f} ms "
            f"| {len(begun)} path stops, {len(quick)} not made (look-ahead {cell.bus.max_lookahead_ms:g} ms)"
        )
        for why in quick:
            print("  not made:", why)
    print("command: PYTHONPATH=. python3 bench/onpath_service.py --part cyclic")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="passes over the stop fractions (default 1)")
    parts = ("all", "cells", "stops", "back", "jerk", "transitions", "jerk-changes", "cyclic")
    ap.add_argument("--part", choices=parts, default="all")
    args = ap.parse_args()
    if args.part in ("all", "cells"):
        per_cell(args.runs)
    if args.part in ("all", "transitions"):
        transitions(args.runs)
    if args.part in ("all", "jerk-changes"):
        jerk_changes()
    if args.part in ("all", "cyclic"):
        cyclic(args.runs)
    if args.part in ("all", "back"):
        back_to_plan()
    if args.part in ("all", "jerk"):
        jerk_limited_stops(args.runs)
    if args.part in ("all", "stops"):
        stops(args)


def stops(args: argparse.Namespace) -> None:
    computed: list[float] = []
    real_splice = axis_group.splice_run  # the change's computation: what AxisGroup.splice runs, lock held

    def timed(*a, **k):
        t = time.perf_counter()
        try:
            return real_splice(*a, **k)
        finally:
            computed.append((time.perf_counter() - t) * 1000.0)

    axis_group.splice_run = timed
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
    print("command: PYTHONPATH=. python3 bench/onpath_service.py --part stops")


if __name__ == "__main__":
    main()
