"""SYNC on the wall clock: the master's SYNC producer alone, and with CPU-bound processes beside it.

The master's real ``CellBus`` on the ``virtual`` bus (no drives: the SYNC thread is what is
measured) sends SYNC and the 0x1013 time stamp every ``--period-ms`` for ``--seconds``. Each SYNC's
send time is taken in the sending thread right after the frame went out (``SyncClock.add_sender``).
Cases: alone and with ``--load`` busy-loop processes (multiprocessing, started and stopped here),
each with SCHED_FIFO asked (``sync_priority`` 50) and not (0). Figures per case: SYNC interval
p50 / p99 / max in periods, bursts (a SYNC less than half a period after the one before), periods
skipped (``SyncClock.skipped``), whether SCHED_FIFO was granted, and the machine's CPU load during
the case (/proc/stat, all cores). Target under load: p99 <= 1.1 periods, max <= 2, 0 bursts.

``--interface simwire``: the master on pvtflow's simulated wire (wall clock, 1 Mbit/s), where the
interface sends SYNC cyclically by itself (``SyncClock.native``: the medium times each SYNC as
SocketCAN's broadcast manager does) and the master's thread only follows it with the time stamp.
The intervals are then those of the SYNC frames on the wire (their start times, ``Medium.
sync_intervals``), and a second row per case gives the follower's (when the master's thread sent the
time stamp after each SYNC it heard).

    python3 bench/sync_jitter.py [--seconds 5] [--period-ms 1] [--load 2] [--interface virtual|simwire]
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from axes.bus import CellBus
from axes.config import BusConfig


def busy(stop: multiprocessing.synchronize.Event) -> None:  # type: ignore[name-defined]
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def cpu_times() -> tuple[int, int]:
    """(busy, total) jiffies of all cores since boot."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + fields[4]
    return sum(fields) - idle, sum(fields)


def figures(intervals: np.ndarray) -> dict[str, float | int]:
    return {
        "p50": float(np.percentile(intervals, 50)),
        "p99": float(np.percentile(intervals, 99)),
        "max": float(intervals.max()),
        "bursts": int((intervals < 0.5).sum()),
    }


def run_case(seconds: float, period_ms: float, priority: int, load: int, interface: str) -> dict[str, object]:
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    time.sleep(0.2 if load else 0.0)
    config = BusConfig(
        interface=interface,
        channel=f"jitter-{uuid.uuid4().hex[:8]}",
        sync_period_ms=period_ms,
        time_stamp=True,
        sync_priority=priority,
        max_sync_gap_periods=1e6,
    )
    bus = CellBus(config, lockstep=False).open()
    sent: list[float] = []
    bus.sync.add_sender(lambda n: sent.append(time.monotonic()))
    b0, t0 = cpu_times()
    bus.sync.start()
    time.sleep(seconds)
    bus.sync.stop()
    b1, t1 = cpu_times()
    realtime = bus.sync.realtime
    skipped = bus.sync.skipped
    native = bus.sync.native
    wire = None
    if interface == "simwire":
        assert bus.network.bus is not None
        wire = np.asarray(bus.network.bus.medium.sync_intervals()) / (period_ms / 1000.0)
    bus.close()
    stop.set()
    for w in workers:
        w.join(2.0)
    intervals = np.diff(np.asarray(sent)) / (period_ms / 1000.0)
    cores = multiprocessing.cpu_count()
    return {
        "syncs": len(sent) if wire is None else len(wire) + 1,
        **figures(intervals if wire is None else wire),
        "follower": None if wire is None else {"syncs": len(sent), **figures(intervals)},
        "native": native,
        "skipped": skipped,
        "fifo": realtime,
        "cpu": (b1 - b0) / max(1, t1 - t0) * cores,
        "cores": cores,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--period-ms", type=float, default=1.0)
    parser.add_argument("--load", type=int, default=2, help="CPU-bound processes beside the master")
    parser.add_argument("--interface", choices=("virtual", "simwire"), default="virtual")
    args = parser.parse_args()
    print(f"SYNC every {args.period_ms:g} ms for {args.seconds:g} s per case on {args.interface}; intervals in periods")
    print("| case | SCHED_FIFO | SYNCs | p50 | p99 | max | bursts | skipped | CPU load (cores busy of N) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for load in (0, args.load):
        for priority in (50, 0):
            r = run_case(args.seconds, args.period_ms, priority, load, args.interface)
            case = "alone" if load == 0 else f"{load} busy processes"
            if r["native"]:
                case += ", SYNC on the wire (native)"
            fifo = "asked, granted" if r["fifo"] else ("asked, refused" if priority else "not asked")
            print(
                f"| {case} | {fifo} | {r['syncs']} | {r['p50']:.3f} | {r['p99']:.3f} | {r['max']:.2f} | "
                f"{r['bursts']} | {r['skipped']} | {r['cpu']:.2f} of {r['cores']} |",
                flush=True,
            )
            f = r["follower"]
            if isinstance(f, dict):
                print(
                    f"| {case}: the follower's time stamps | {fifo} | {f['syncs']} | {f['p50']:.3f} | "
                    f"{f['p99']:.3f} | {f['max']:.2f} | {f['bursts']} | | |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
