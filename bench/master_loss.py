"""The master dies or hangs mid-motion: how long until every axis stands still by itself.

For each drive behaviour (every axis of arm6 on it), a MotionService on simulated drives plans a long
move, executes it, and its master side is killed ``--kill-at-ms`` into the motion, in-process on
the virtual bus: "dead" closes the master's CAN connection (nothing in or out, as after SIGKILL),
"hung" blocks its receive thread in a SYNC listener (the threads that supervise the motion wait on
it; the process lives on). The drives are not told: each notices the master's heartbeat stopping
(0x1016) and reacts (0x6007 quick stop; the EPOS2 its fault reaction). Figures per case, the worst
axis of each run (median and max over ``--runs`` runs), all from the master's last heartbeat (its
own send time):

- detect: the last axis's consumer fired (target: <= consumer time + 1 SYNC period);
- still: the last axis's demand at rest (detect + braking on the quick stop ramp 0x6085 = 0x60C5);
- brake: the longest braking (still - detect of one axis), and the fastest axis's speed then;
- hung only: from the hang to the master's last heartbeat (it beats while its receive thread
  dispatched a frame within the drives' heartbeat window, heartbeat_ms x heartbeat_timeout_factor).

    python3 bench/master_loss.py [--runs 3] [--kill-at-ms 500] [--master-heartbeat-ms 100]
        [--timeout-factor 10] [--profiles epos2_pvt,cia402_ip_linear,sync_setpoint,parker_slvdn] [--real-time]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.service.api import parse_execute, parse_plan
from pvtflow.service.config import CellConfig, load_cell_config
from pvtflow.service.motion import MotionService

# 4 ms: the planner refuses arm6 at 1 ms on a linear drive (one count of rounding is more than 0x60C5
# allows), and the Parker interpolates between SYNCs from 2.5 ms on (the direct loop below stands at
# its last setpoint without SYNC)
FIXED = {
    "cia402_ip_linear": {"period_ms": 4},
    "sync_setpoint": {"period_ms": 4},
    "parker_slvdn": {"period_ms": 4, "interpolation_submode": -1},
}


def cell_for(profile: str, master_heartbeat_ms: int, factor: float | None) -> CellConfig:
    arm6 = load_cell_config(None)
    extra = FIXED.get(profile, {})
    axes = tuple(dataclasses.replace(a, profile=profile, **extra) for a in arm6.axes)  # type: ignore[arg-type]
    bus = dataclasses.replace(
        arm6.bus,
        channel=f"master-loss-{uuid.uuid4().hex[:8]}",
        sync_period_ms=float(extra.get("period_ms", 1)),
        master_heartbeat_ms=master_heartbeat_ms,
        heartbeat_timeout_factor=arm6.bus.heartbeat_timeout_factor if factor is None else factor,
    )
    return dataclasses.replace(arm6, axes=axes, bus=bus)


def run_once(cell: CellConfig, how: str, kill_at_ms: float, real_time: bool) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as journal:
        svc = MotionService(cell, journal_dir=journal, clock=Clock.of(not real_time), planner_process=False).open()
        release = threading.Event()
        killed = threading.Event()
        hang_at: list[float] = []
        try:
            assert svc.bus is not None and svc.sim is not None and svc.group is not None
            bus, group = svc.bus, svc.group
            kill_at_sync = round(kill_at_ms / cell.bus.sync_period_ms)

            def listener(n: int) -> None:  # the master's receive thread
                elapsed = group.elapsed_syncs() if group.running else None  # not the last run's
                if elapsed is None or elapsed < kill_at_sync or killed.is_set():
                    return
                killed.set()
                if how == "hung":
                    hang_at.append(time.monotonic())
                    release.wait()

            lim = cell.joint_limits()
            low = [lo + 0.1 * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)]
            high = [lo + 0.9 * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)]
            for target in (low, high):  # to one end first, then the long move across
                plan = svc.plan(parse_plan({"waypoints": [target], "start": "current"}, cell.joint_names, lim))
                if target is low:
                    svc.execute(parse_execute({"plan_id": plan["plan_id"], "wait": True}))
            bus.sync.add_listener(listener)
            svc.execute(parse_execute({"plan_id": plan["plan_id"], "wait": False}))
            deadline = time.monotonic() + 120
            while not killed.wait(0.01) and time.monotonic() < deadline:
                if not group.running and not killed.is_set():
                    raise RuntimeError(f"the motion ended before the kill: {group.last_result}")
            if how == "dead":
                bus.network.notifier.stop(timeout=1.0)
                bus.network.bus.shutdown()
            drives = list(svc.sim)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not all(
                d.master_loss.losses and d.master_loss.losses[-1].standstill is not None for d in drives
            ):
                time.sleep(0.005)
            losses = [d.master_loss.losses[-1] if d.master_loss.losses else None for d in drives]
            if any(x is None or x.standstill is None for x in losses):
                raise RuntimeError("an axis did not stop within 30 s")
            last_beat = bus.master_heartbeat.last_beat
            out = {
                "detect_ms": max(x.detected for x in losses) * 1e3 - last_beat * 1e3,  # type: ignore[union-attr]
                "still_ms": max(x.standstill for x in losses) * 1e3 - last_beat * 1e3,  # type: ignore[union-attr]
                "brake_ms": max((x.standstill - x.detected) * 1e3 for x in losses),  # type: ignore[union-attr,operator]
                "rpm": max(abs(x.velocity_rpm) for x in losses),  # type: ignore[union-attr]
                "moving": sum(abs(x.velocity_rpm) > 1.0 for x in losses),  # type: ignore[union-attr]
                "states": sorted({d.state.value for d in drives}),
            }
            if hang_at:
                out["hang_to_last_beat_ms"] = (last_beat - hang_at[0]) * 1e3
            return out
        finally:
            release.set()
            svc.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--kill-at-ms", type=float, default=500.0)
    ap.add_argument("--master-heartbeat-ms", type=int, default=100)
    ap.add_argument(
        "--timeout-factor",
        type=float,
        default=None,
        help="heartbeat_timeout_factor (default: arm6's 10; at 3, a real bus's, the simulated drives and the master "
        "sharing a loaded host's CPU lose each other's heartbeats in the middle of motions)",
    )
    ap.add_argument("--profiles", default="epos2_pvt,cia402_ip_linear,sync_setpoint,parker_slvdn")
    ap.add_argument("--real-time", action="store_true", help="SYNC on the wall clock (default: lockstep)")
    args = ap.parse_args()
    print(f"# {' '.join(sys.argv)}")
    for profile in args.profiles.split(","):
        cell = cell_for(profile, args.master_heartbeat_ms, args.timeout_factor)
        consumer = cell.bus.master_consumer_time_ms
        target = consumer + cell.bus.sync_period_ms
        for how in ("dead", "hung"):
            runs = [run_once(cell, how, args.kill_at_ms, args.real_time) for _ in range(args.runs)]
            worst = {k: max(r[k] for r in runs) for k in ("detect_ms", "still_ms", "brake_ms", "rpm")}
            detect = sorted(r["detect_ms"] for r in runs)
            still = sorted(r["still_ms"] for r in runs)
            line = (
                f"{profile:17s} {how:4s} consumer {consumer} ms, SYNC {cell.bus.sync_period_ms:g} ms: "
                f"detect median {detect[len(detect) // 2]:.1f} / max {detect[-1]:.1f} ms (target <= {target:g}: "
                f"{sum(d <= target for d in detect)}/{len(detect)} within), "
                f"still median {still[len(still) // 2]:.1f} / max {still[-1]:.1f} ms, "
                f"brake <= {worst['brake_ms']:.1f} ms from <= {worst['rpm']:.0f} rpm; "
                f"moving at the loss {min(r['moving'] for r in runs)}/6; end {runs[-1]['states']}"
            )
            if how == "hung":
                line += f"; hang -> last beat <= {max(r['hang_to_last_beat_ms'] for r in runs):.0f} ms"
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
