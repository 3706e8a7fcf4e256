"""Full-speed time-optimal tours on the wall clock, every shipped cell, drives in a process of their own.

Per cell (homing sections left out: a copy of its file without them, a simulated machine standing
at its encoder's 0 at power-up, as if homed there), a tour through the whole range
is planned as ``pvtflow plan`` plans it (``CellPlanner``, the cell's joint limits, so a fixed-period
drive's ``bus.fixed_period_headroom``): from where the drives stand to 90 % of each joint's range,
to 30 %, back (``lower + f * (upper - lower)``). It runs ``--runs`` times on the wall clock with the
master (CellBus + AxisGroup, SYNC on the wall clock) here and the drives and the simulated wire in a
child process (axes.sim.process), as ``pvtflow execute --real-time`` runs them.

Figures per cell: runs finished; the SYNC intervals on the wire (the medium's own accounting of each
SYNC's start), p50 / p99 / max in periods; each fixed-period setpoint's time after its SYNC (the end of
its frame on the wire after the start of the SYNC before it, the medium's ``rpdo_after_sync``) p50 /
p99 / max in periods; the plan's worst demand velocity and acceleration as a
fraction of 0x607F / 0x60C5 (the program's points, as the validator reconstructs them; a drive that
met more would have faulted the run); the first failure's message.

    python3 bench/fullspeed.py [--cells gantry3,gantry3-ip-linear,...] [--runs 20] [--cpu-load 2]
                               [--period-ms MS]

``--cpu-load N``: N CPU-bound processes beside the run (started here, ended at the end).
``--service``: each tour through the service (``MotionService`` as ``pvtflow serve --real-time --record``
runs it: drives in their own process, the planner in its child, an MCAP file per motion) with a plan
request every 100 ms beside it; the worst fractions and the tour's length are then not shown.
``--period-ms``: every cell at another SYNC period (a copy of its file, as ``bench/stall.py`` makes).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pvtflow.axes.canbus.clock import Clock  # noqa: E402
from pvtflow.axes.drive.objects import PdoRole  # noqa: E402
from pvtflow.axes.drive.program import PvtProgram  # noqa: E402
from pvtflow.axes.master.bus.cell_bus import CellBus  # noqa: E402
from pvtflow.axes.master.group.axis_group import AxisGroup  # noqa: E402
from pvtflow.axes.sim.process import start_simulated_drives  # noqa: E402
from pvtflow.planner.plan import PlanInput  # noqa: E402
from pvtflow.service.cell_planner import CellPlanner  # noqa: E402
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config  # noqa: E402

CELLS = ("gantry3", "gantry3-ip-linear", "gantry3-sync-setpoint", "gantry3-parker", "gantry3-mixed", "arm6")


def without_homing(
    name: str,
    directory: Path,
    period_ms: float | None,
    headroom: float | None,
    status_every: int | None = None,
    cyclic: bool = False,
    interface_sync: bool = False,
    in_master: bool = False,
) -> Path:
    """A copy of the cell's file without its homing sections (at ``period_ms``, with ``headroom`` if given)."""
    source = CONFIG_DIR / "cells" / f"{name}.yaml"
    data = yaml.safe_load(source.read_text())
    for axis in data.get("axes", []):
        axis.pop("homing", None)
        if "simulation" in axis:  # not homed: the machine stands where its encoder counts 0
            axis["simulation"]["power_up_qc"] = 0
    data.pop("homing_order", None)
    data.pop("requires_homing", None)
    if period_ms is not None:
        data["bus"]["sync_period_ms"] = period_ms
        for axis in data["axes"]:
            if "period_ms" in axis:
                axis["period_ms"] = int(period_ms)
    if headroom is not None:
        data["bus"]["fixed_period_headroom"] = headroom
    if status_every is not None:
        data["bus"]["status_every_syncs"] = status_every
    if cyclic:
        data["bus"]["cyclic_process"] = True
    if interface_sync:
        data["bus"]["interface_sync"] = True
    if in_master:
        data["bus"]["cyclic_process"] = False
    robot = data.get("robot", {})
    if "urdf" in robot:
        robot["urdf"] = str((source.parent / robot["urdf"]).resolve())
    copy = directory / f"{name}.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return copy


def tour(cell: CellConfig, here: np.ndarray) -> PvtProgram:
    limits = cell.joint_limits()
    span = limits.upper - limits.lower
    points = np.vstack([here, limits.lower + 0.9 * span, limits.lower + 0.3 * span, here])
    result = CellPlanner(cell).plan(PlanInput(points), None, None, 5000.0)
    if not result.ok or result.program is None:
        raise RuntimeError(f"{cell.name}: not planned: {result.code} {result.message}")
    return result.program


def fractions(cell: CellConfig, program: PvtProgram) -> tuple[float, float]:
    """The program's worst |v| / 0x607F and |a| / 0x60C5 over all axes, as its drives reconstruct it:
    the velocity in each segment's middle, the acceleration within segments and, for the linear
    reconstructions, the change of velocity from one segment to the next over the time between."""
    worst_v = worst_a = 0.0
    for axis, prog in zip(cell.ordered_axes(), program.axes, strict=True):
        s = axis.scaling
        vmax = float(s.rpm_to_qc_per_ms(axis.limits.max_profile_velocity_rpm))
        amax = float(s.rpm_s_to_qc_per_ms2(axis.limits.max_acceleration_rpm_s))
        curve = prog.reconstruction()
        middle = curve.start + curve.duration / 2.0
        v = curve.velocity(middle)
        a = np.diff(v) / np.diff(middle) if len(v) > 1 else np.zeros(1)
        worst_v = max(worst_v, float(np.max(curve.max_abs_velocity())) / vmax)
        worst_a = max(worst_a, float(np.max(np.abs(a))) / amax, float(np.max(curve.max_abs_acceleration())) / amax)
    return worst_v, worst_a


def run(cell: CellConfig, program_for) -> dict[str, object]:
    drives = start_simulated_drives(cell, "wall")
    bus = CellBus(drives.bus, clock=Clock.WALL).open()
    group = AxisGroup(bus, cell.ordered_axes())
    try:
        group.refresh()
        here = np.array(
            [
                float(a.scaling.qc_to_position(link.position or 0))
                for a, link in zip(cell.ordered_axes(), group.links, strict=True)
            ]
        )
        program = program_for(here)
        medium = bus.network.bus.medium
        before = medium.stats()
        result = group.run(program, timeout_s=program_seconds(program) + 30)
        after = medium.stats()
        late = cyclic_late(bus)
        motion = after.sync_intervals[len(before.sync_intervals) :]
        after_sync = []
        for cob_id in setpoint_cob_ids(cell):
            key = f"0x{cob_id:03X}"
            after_sync += after.rpdo_after_sync.get(key, [])[len(before.rpdo_after_sync.get(key, [])) :]
    finally:
        group.close()
        bus.close()
        drives.stop()
    return {
        "result": result.result.name,
        "message": result.message,
        "intervals": motion,
        "after_sync": after_sync,
        "program": program,
        "late": late,
    }


def cyclic_late(bus: CellBus) -> list[float]:
    """Each SYNC's send after its deadline in the cyclic process, us (empty: SYNC sent in this process);
    where the interface sends SYNC (``--interface-sync``), each SYNC's setpoints sent after it was due."""
    cyclic = bus.sync.cyclic
    if cyclic is None:
        return []
    deadline = time.monotonic() + 1.0
    while cyclic.last_timing is None and time.monotonic() < deadline:
        time.sleep(0.01)
    timing, cyclic.last_timing = cyclic.last_timing, None
    if timing is None:
        return []
    if timing.held:
        late = sum(1 for us in timing.followed_us if us > 0.75 * 1000 * bus.sync.period_ms)
        print(
            f"  (the cyclic process heard {timing.held} SYNC(s) before their setpoints were on the wire; "
            f"it sent {late} period(s) of setpoints later than 3/4 of a period after their SYNC was due)"
        )
    return list(timing.late_us) or list(timing.followed_us)


def run_service(cell: CellConfig, directory: Path) -> dict[str, object]:
    """The tour through the service as ``pvtflow serve --real-time --record DIR`` runs it (drives in
    their own process, plans in the planner's child process, one MCAP file per motion), with a plan
    request every 100 ms beside it (a random single-target move from the current position)."""
    from pvtflow.service.api import ApiError, parse_execute, parse_plan
    from pvtflow.service.motion import MotionService

    svc = MotionService(
        cell,
        journal_dir=directory / "journal",
        clock=Clock.WALL,
        planner_process=True,
        record_dir=directory / "rec",
        drives_process=True,
    ).open()
    rng = np.random.default_rng(34)
    stop = threading.Event()
    plans = [0, 0, 0]  # answered, refused, raised
    errors: list[str] = []

    def plan_every_100_ms() -> None:
        due = time.monotonic()
        while not stop.wait(max(0.0, due - time.monotonic())):
            due += 0.1
            target = limits.lower + rng.uniform(0.1, 0.9, len(limits.lower)) * (limits.upper - limits.lower)
            try:
                svc.plan(parse_plan({"waypoints": [target.tolist()], "start": "current"}, cell.joint_names, limits))
                plans[0] += 1
            except ApiError:
                plans[1] += 1
            except Exception as exc:  # what the service lets through is a figure here, not the bench's end
                plans[2] += 1
                errors.append(f"{type(exc).__name__}: {exc}"[:160])

    try:
        limits = cell.joint_limits()
        span = limits.upper - limits.lower
        here = [
            float(a.scaling.qc_to_position(link.position or 0))
            for a, link in zip(cell.ordered_axes(), svc.group.links, strict=True)
        ]
        tour = [(limits.lower + 0.9 * span).tolist(), (limits.lower + 0.3 * span).tolist(), here]
        plan_id = svc.plan(parse_plan({"waypoints": tour, "start": "current"}, cell.joint_names, limits))["plan_id"]
        medium = svc.bus.network.bus.medium
        before = medium.stats()
        planner = threading.Thread(target=plan_every_100_ms, name="bench-plans", daemon=True)
        planner.start()
        try:
            outcome = svc.execute(parse_execute({"plan_id": plan_id, "wait": True}))["outcome"]
        finally:
            stop.set()
            planner.join()
        after = medium.stats()
        late = cyclic_late(svc.bus)
    finally:
        svc.close()
    after_sync = []
    for cob_id in setpoint_cob_ids(cell):
        key = f"0x{cob_id:03X}"
        after_sync += after.rpdo_after_sync.get(key, [])[len(before.rpdo_after_sync.get(key, [])) :]
    return {
        "result": "FINISHED" if outcome["result"] == "finished" else outcome["result"],
        "message": f"{outcome['message']} ({plans[0]} plans beside it, {plans[1]} refused, {plans[2]} raised"
        + (f": {errors[0]}" if errors else "")
        + ")",
        "intervals": after.sync_intervals[len(before.sync_intervals) :],
        "after_sync": after_sync,
        "program": None,
        "late": late,
    }


def setpoint_cob_ids(cell: CellConfig) -> list[int]:
    """The COB-IDs of the fixed-period axes' setpoint RPDOs (the EPOS2's records have no SYNC to keep)."""
    return [
        layout.cob_id(axis.node_id, receive=True)
        for axis in cell.ordered_axes()
        for layout in axis.profile.spec.rpdos
        if layout.role is PdoRole.SETPOINT
    ]


def program_seconds(program: PvtProgram) -> float:
    return max(a.duration_ms for a in program.axes) / 1000.0


def figures(x: np.ndarray) -> str:
    return f"{np.percentile(x, 50):.3f} / {np.percentile(x, 99):.3f} / {np.max(x):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", default=",".join(CELLS))
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--cpu-load", type=int, default=0, help="CPU-bound processes beside the runs")
    parser.add_argument("--period-ms", type=float, default=None)
    parser.add_argument(
        "--service", action="store_true", help="through the service, a plan request every 100 ms, recording"
    )
    parser.add_argument("--status-every", type=int, default=None, help="bus.status_every_syncs (default: the file's)")
    parser.add_argument("--headroom", type=float, default=None, help="bus.fixed_period_headroom (default: the file's)")
    parser.add_argument(
        "--cyclic", action="store_true", help="bus.cyclic_process: SYNC and the feed in a process of their own"
    )
    parser.add_argument(
        "--interface-sync",
        action="store_true",
        help="with --cyclic: bus.interface_sync, the interface (the served medium) sends SYNC, the process follows",
    )
    parser.add_argument(
        "--in-master",
        action="store_true",
        help="bus.cyclic_process false: SYNC and the feed from the master's process (by default, auto: the drives "
        "served in their own process, the cyclic process runs and the interface sends SYNC)",
    )
    args = parser.parse_args()
    kept = tempfile.TemporaryDirectory()
    files = Path(kept.name)
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.cpu_load)]
    try:
        print(
            f"python3 bench/fullspeed.py --cells {args.cells} --runs {args.runs} --cpu-load {args.cpu_load}"
            + (f" --period-ms {args.period_ms:g}" if args.period_ms is not None else "")
            + (f" --headroom {args.headroom:g}" if args.headroom is not None else "")
            + (" --service" if args.service else "")
            + (f" --status-every {args.status_every}" if args.status_every is not None else "")
            + (" --cyclic" if args.cyclic else "")
            + (" --interface-sync" if args.interface_sync else "")
            + (" --in-master" if args.in_master else "")
        )
        print(
            "| cell | SYNC ms | finished | SYNC interval p50 / p99 / max (periods) | setpoint after its SYNC "
            "p50 / p99 / max (periods) | worst v / 0x607F, a / 0x60C5 | tour s | "
            + ("SYNC late in the master" if args.in_master else "setpoints sent after their SYNC was due")
            + " p50 / p99 / max (us) | first failure |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for name in args.cells.split(","):
            # the copy stays for the run: the service's planner child reads the cell's file again
            cell = load_cell_config(
                without_homing(
                    name,
                    files,
                    args.period_ms,
                    args.headroom,
                    args.status_every,
                    args.cyclic,
                    args.interface_sync,
                    args.in_master,
                )
            )
            plans: dict[bytes, PvtProgram] = {}

            def program_for(here: np.ndarray, cell: CellConfig = cell, plans: dict = plans) -> PvtProgram:
                key = np.round(here, 6).tobytes()
                if key not in plans:
                    plans[key] = tour(cell, here)
                return plans[key]

            done, intervals, after_sync, failure, worst, seconds, late = 0, [], [], "", (0.0, 0.0), 0.0, []
            for _ in range(args.runs):
                if args.service:
                    with tempfile.TemporaryDirectory() as directory:
                        r = run_service(cell, Path(directory))
                else:
                    r = run(cell, program_for)
                done += r["result"] == "FINISHED"
                intervals += r["intervals"]
                after_sync += r["after_sync"]
                late += r["late"]
                if r["program"] is not None:
                    worst = max(worst, fractions(cell, r["program"]))
                    seconds = program_seconds(r["program"])
                if r["result"] != "FINISHED" and not failure:
                    failure = f"{r['result']}: {r['message']}"[:240]
                time.sleep(0.3)
            period = cell.bus.sync_period_ms / 1000.0
            iv = np.array(intervals) / period if intervals else np.array([np.nan])
            sp = np.array(after_sync) / period if after_sync else np.array([np.nan])
            print(
                f"| {name} | {cell.bus.sync_period_ms:g} | {done}/{args.runs} | {figures(iv)} | {figures(sp)} "
                f"| {worst[0]:.3f} / {worst[1]:.3f} | {seconds:.2f} "
                f"| {figures(np.array(late)) if late else '-'} | {failure} |",
                flush=True,
            )
    finally:
        for b in burners:
            b.kill()
            b.wait()
        kept.cleanup()


if __name__ == "__main__":
    main()
