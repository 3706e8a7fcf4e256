"""Where a SYNC gap goes: every thread of the master's process, as the kernel accounted it, across it.

The master's ``CellBus`` on ``virtual`` (SCHED_FIFO 50 asked) sends SYNC every 1 ms for
``--seconds`` with ``--load`` busy-loop processes beside it. At each wake of a SYNC thread
(``SyncClock.hold``) every thread's /proc/self/task/TID/schedstat is read (time on the CPU, time
runnable but waiting for a CPU, switches). For each gap over 2 periods between two wakes, each
thread that ran or waited across it is printed: a SYNC thread that ran and waited nothing across a
gap was not woken (its CPU's timer, the host: ``bench/cpu_stalls.py``) or waited for the GIL; a
normal-priority thread runnable-waiting across it held the GIL while preempted (priority inversion).
Before the runs: every thread with its policy and priority.

    python3 bench/sync_schedstat.py [--runs 4] [--seconds 3] [--load 2] [--one-sync-thread] [--caller-normal]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from sync_jitter import busy

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.sync import below_sync

POLICIES = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO"}


def threads_now() -> list[str]:
    names = {t.native_id: t.name for t in threading.enumerate()}
    rows = []
    for tid in sorted(int(t) for t in os.listdir("/proc/self/task")):
        policy = POLICIES.get(os.sched_getscheduler(tid), "other")
        priority = os.sched_getparam(tid).sched_priority
        rows.append(f"{tid} {names.get(tid, '(not a Python thread)')}: {policy} {priority}")
    return rows


def run(seconds: float, load: int, backup: bool, caller_rt: bool, show_threads: bool) -> None:
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    time.sleep(0.2)
    config = BusConfig(
        channel=f"schedstat-{uuid.uuid4().hex[:8]}", sync_period_ms=1.0, sync_priority=50, max_sync_gap_periods=1e6
    )
    bus = CellBus(config, clock=Clock.WALL).open()
    bus.sync.backup = backup
    files: dict[int, int] = {}
    rows: list[tuple[float, dict[int, tuple[int, ...]]]] = []

    def hold() -> None:
        if not bus.sync.running:
            return
        if not files:
            for tid in os.listdir("/proc/self/task"):
                files[int(tid)] = os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY)
        rows.append((time.monotonic(), {t: tuple(map(int, os.pread(f, 100, 0).split())) for t, f in files.items()}))

    bus.sync.hold = hold
    with below_sync(bus.sync) if caller_rt else contextlib.nullcontext():
        bus.sync.start()
        time.sleep(seconds / 2)
        listing = threads_now()
        names = {t.native_id: t.name for t in threading.enumerate()}
        time.sleep(seconds / 2)
        bus.sync.stop()
    bus.close()
    stop.set()
    for w in workers:
        w.join(2.0)
    for fd in files.values():
        os.close(fd)
    if show_threads:
        print("threads of the master's process during the run:")
        print("\n".join(f"  {row}" for row in listing))
    times = np.array([t for t, _ in rows])
    gaps = np.diff(times) * 1000
    print(f"run: {len(times)} wakes, the longest gap between two wakes {gaps.max():.2f} ms", flush=True)
    for i in np.nonzero(gaps > 2.0)[0]:
        print(f"  gap {gaps[i]:.2f} ms, {times[i] - times[0]:.3f} s into the run:")
        before, after = rows[i][1], rows[i + 1][1]
        for tid in before:
            if tid not in after:
                continue
            ran, waited, switches = (after[tid][k] - before[tid][k] for k in range(3))
            if ran or waited or switches:
                print(
                    f"    {names.get(tid, tid)}: on a CPU {ran / 1e6:.2f} ms, runnable but waiting "
                    f"{waited / 1e6:.2f} ms, {switches} switches"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--load", type=int, default=2)
    parser.add_argument("--one-sync-thread", action="store_true", help="SyncClock.backup off")
    parser.add_argument(
        "--caller-normal", action="store_true", help="the caller not under axes.master.bus.sync.below_sync"
    )
    args = parser.parse_args()
    for i in range(args.runs):
        run(args.seconds, args.load, not args.one_sync_thread, not args.caller_normal, i == 0)


if __name__ == "__main__":
    main()
