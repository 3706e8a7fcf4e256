"""SYNC on the wall clock: the master's SYNC producer alone, and with CPU-bound processes beside it.

The master's real ``CellBus`` on the ``virtual`` bus (no drives: the SYNC thread is what is
measured) sends SYNC and the 0x1013 time stamp every ``--period-ms`` for ``--seconds``. Each SYNC's
send time is the master's own (``SyncClock.sent_at``: taken in the sending thread once the frame is
out), read by a sender (``SyncClock.add_sender``). Cases: alone and with ``--load`` busy-loop
processes (multiprocessing, started and stopped here), each with SCHED_FIFO asked
(``sync_priority`` 50) and not (0). Figures per case: SYNC interval p50 / p99 / max in periods, each
run's max, bursts (a SYNC less than half a period after the one before), periods skipped
(``SyncClock.skipped``), whether SCHED_FIFO was granted, and the machine's CPU load during the case
(/proc/stat, all cores). Target under load: p99 <= 1.1 periods, max <= 2, 0 bursts.

The machine's floor, a row under each case: one thread in a child process of its own, SCHED_FIFO
as asked, waking at absolute deadlines by ``time.sleep`` and nothing else, under the same load
(``bare_timer``): what the master adds is what its figure shows above that. ``--floor before``: the
floor runs alone with the load just before the master; ``--floor beside``: at the same moments, and
the master's gaps over 2 periods that the floor also had (a gap of the machine) are counted.

The master's bus threads run at SCHED_FIFO one below SYNC when SYNC has it (``axes.master.bus.sync.lift``);
``--bus-threads-normal`` leaves them at normal priority, for comparison. Two SYNC threads on two
CPUs (``SyncClock.backup``); ``--one-sync-thread``: one, for comparison. The caller starts SYNC and
waits under ``axes.master.bus.sync.below_sync``, as ``AxisGroup.run`` does; ``--caller-normal``: at normal
priority, for comparison. ``--runs N`` repeats each
case (the rare multi-ms gaps need many runs to be seen); ``--under-load-only``: the case that
matters, under load with SCHED_FIFO.

``--interface simwire``: the master on pvtflow's simulated wire (wall clock, 1 Mbit/s), where the
interface sends SYNC cyclically by itself (``SyncClock.native``: the medium times each SYNC as
SocketCAN's broadcast manager does) and the master's thread only follows it with the time stamp.
The intervals are then those of the SYNC frames on the wire (their start times, ``Medium.
sync_intervals``), and a second row per case gives the follower's (when the master's thread
followed each SYNC it heard).

    python3 bench/sync_jitter.py [--seconds 5] [--period-ms 1] [--load 2] [--interface virtual|simwire]
        [--runs N] [--under-load-only] [--floor before|beside] [--bus-threads-normal]
        [--one-sync-thread] [--caller-normal]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import math
import multiprocessing
import sys
import time
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.sync import ask_realtime, below_sync


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


def bare_timer(seconds: float, period_ms: float, priority: int, out: multiprocessing.connection.Connection) -> None:  # type: ignore[name-defined]
    """The machine's own floor: one thread, SCHED_FIFO at ``priority`` when asked, waking at absolute
    deadlines by ``time.sleep`` and doing nothing else, with the master's skip rule (a deadline passed
    by more than half a period is skipped, never caught up). Sends its wake-up times through ``out``."""
    fifo = ask_realtime(priority)
    period = period_ms / 1000.0
    woke: list[float] = []
    deadline = time.monotonic()
    end = deadline + seconds
    while deadline < end:
        now = time.monotonic()
        late = now - deadline
        if late > period / 2:
            deadline += math.ceil((late - period / 2) / period) * period
        due = deadline if not woke else max(deadline, woke[-1] + period / 2)
        if now >= due:
            woke.append(now)
            deadline += period
            due = deadline
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    out.send((fifo, woke))
    out.close()


class Floor:
    """``bare_timer`` in a child process of its own: the floor the master's figure is set beside."""

    def __init__(self, seconds: float, period_ms: float, priority: int) -> None:
        self.period_ms = period_ms
        self._receive, send = multiprocessing.Pipe(duplex=False)
        self._child = multiprocessing.Process(target=bare_timer, args=(seconds, period_ms, priority, send), daemon=True)
        self._child.start()

    def result(self) -> dict[str, object]:
        fifo, woke = self._receive.recv()
        self._child.join(2.0)
        intervals = np.diff(np.asarray(woke)) / (self.period_ms / 1000.0)
        return {"syncs": len(woke), **figures(intervals), "intervals": intervals, "fifo": fifo, "woke": woke}


def where_late(sent: list[float], woke: list[float], period_s: float) -> tuple[int, int]:
    """The master's gaps over 2 periods: how many were lost before its thread ran again (the sleep's
    wake-up and the GIL), and how many after it (the SYNC lock, the send)."""
    w = np.asarray(woke)
    at_wake = after_wake = 0
    for a, b in itertools.pairwise(sent):
        if b - a <= 2 * period_s:
            continue
        i = np.searchsorted(w, b, side="right") - 1  # the last wake before this SYNC went out
        if i >= 0 and b - w[i] > period_s:
            after_wake += 1
        else:
            at_wake += 1
    return at_wake, after_wake


def shared_gaps(sent: list[float], woke: list[float], period_s: float) -> tuple[int, int]:
    """The master's gaps over 2 periods, and how many of them overlap a gap of the floor's over 1.5
    periods (the floor beside the master: a gap both saw is the machine's, not the master's)."""
    s, w = np.asarray(sent), np.asarray(woke)
    mine = [(a, b) for a, b in itertools.pairwise(s) if b - a > 2 * period_s]
    theirs = [(a, b) for a, b in itertools.pairwise(w) if b - a > 1.5 * period_s]
    both = sum(1 for a, b in mine if any(c < b and d > a for c, d in theirs))
    return len(mine), both


def run_case(
    seconds: float,
    period_ms: float,
    priority: int,
    load: int,
    interface: str,
    lift: bool = True,
    beside: bool = False,
    backup: bool = True,
    caller_waits_realtime: bool = True,
) -> dict[str, object]:
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    time.sleep(0.2 if load else 0.0)
    floor = None if beside else Floor(seconds, period_ms, priority).result()
    config = BusConfig(
        interface=interface,
        channel=f"jitter-{uuid.uuid4().hex[:8]}",
        sync_period_ms=period_ms,
        time_stamp=True,
        sync_priority=priority,
        max_sync_gap_periods=1e6,
    )
    bus = CellBus(config, clock=Clock.WALL).open()
    bus.sync.lift_bus_threads = lift and bus.sync.lift_bus_threads
    sent: list[float] = []
    bus.sync.add_sender(lambda n: sent.append(bus.sync.sent_at or time.monotonic()))  # when the SYNC went out
    woke: list[float] = []  # when the SYNC thread had woken from its sleep and held the GIL again
    bus.sync.hold = lambda: woke.append(time.monotonic())
    b0, t0 = cpu_times()
    beside_floor = Floor(seconds, period_ms, priority) if beside else None
    bus.sync.backup = backup
    with below_sync(bus.sync) if caller_waits_realtime else contextlib.nullcontext():
        bus.sync.start()  # the caller starts and waits on the motion as AxisGroup.run does
        time.sleep(seconds)
        bus.sync.stop()
    if beside_floor is not None:
        floor = beside_floor.result()
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
        "intervals": intervals if wire is None else wire,
        "follower": None
        if wire is None
        else {"syncs": len(sent), **figures(intervals), "intervals": intervals, "fifo": realtime},
        "native": native,
        "skipped": skipped,
        "fifo": realtime,
        "cpu": (b1 - b0) / max(1, t1 - t0) * cores,
        "cores": cores,
        "baseline": floor,
        "where": where_late(sent, woke, period_ms / 1000.0),
        "shared": shared_gaps(sent, floor["woke"], period_ms / 1000.0) if beside else None,  # type: ignore[index,arg-type]
    }


def pooled(runs: list[dict[str, object]], key: str | None = None) -> dict[str, object]:
    """Figures of several runs of one case: percentiles over every interval, each run's max."""
    rows = [r if key is None else r[key] for r in runs]
    intervals = np.concatenate([np.asarray(r["intervals"]) for r in rows])  # type: ignore[index]
    return {
        "syncs": sum(int(r["syncs"]) for r in rows),  # type: ignore[index]
        **figures(intervals),
        "maxes": " ".join(f"{float(r['max']):.1f}" for r in rows),  # type: ignore[index]
        "fifo": all(bool(r["fifo"]) for r in rows),  # type: ignore[index]
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--period-ms", type=float, default=1.0)
    parser.add_argument("--load", type=int, default=2, help="CPU-bound processes beside the master")
    parser.add_argument("--interface", choices=("virtual", "simwire"), default="virtual")
    parser.add_argument("--runs", type=int, default=1, help="runs per case (max: each run's)")
    parser.add_argument("--under-load-only", action="store_true", help="only the case under load, SCHED_FIFO asked")
    parser.add_argument(
        "--bus-threads-normal",
        action="store_true",
        help="leave the bus's other threads at normal priority (SyncClock.lift_bus_threads off): for comparison",
    )
    parser.add_argument(
        "--one-sync-thread",
        action="store_true",
        help="one SYNC thread, unpinned (SyncClock.backup off): for comparison",
    )
    parser.add_argument(
        "--caller-normal",
        action="store_true",
        help="the caller waits at normal priority (not under axes.master.bus.sync.below_sync): for comparison",
    )
    parser.add_argument(
        "--floor",
        choices=("before", "beside"),
        default="before",
        help="the bare timer loop runs before the master (each alone with the load) or beside it (the "
        "same moments: the master's gaps over 2 periods that the floor saw too are counted)",
    )
    args = parser.parse_args()
    print(
        f"SYNC every {args.period_ms:g} ms for {args.seconds:g} s per run, {args.runs} run(s) per case on "
        f"{args.interface}; intervals in periods; bus threads "
        f"{'at normal priority' if args.bus_threads_normal else 'lifted below SYNC when SYNC has SCHED_FIFO'}"
    )
    print("| case | SCHED_FIFO | SYNCs | p50 | p99 | max | max per run | bursts | skipped | CPU load, cores |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    loads = (args.load,) if args.under_load_only else (0, args.load)
    priorities = (50,) if args.under_load_only else (50, 0)
    for load in loads:
        for priority in priorities:
            runs = [
                run_case(
                    args.seconds,
                    args.period_ms,
                    priority,
                    load,
                    args.interface,
                    not args.bus_threads_normal,
                    args.floor == "beside",
                    not args.one_sync_thread,
                    not args.caller_normal,
                )
                for _ in range(args.runs)
            ]
            r = pooled(runs)
            case = "alone" if load == 0 else f"{load} busy processes"
            if runs[0]["native"]:
                case += ", SYNC on the wire (native)"
            fifo = "asked, granted" if r["fifo"] else ("asked, refused" if priority else "not asked")
            skipped = sum(int(x["skipped"]) for x in runs)  # type: ignore[call-overload]
            cpu = np.mean([float(x["cpu"]) for x in runs])  # type: ignore[arg-type]
            print(
                f"| {case} | {fifo} | {r['syncs']} | {r['p50']:.3f} | {r['p99']:.3f} | {r['max']:.2f} | "
                f"{r['maxes']} | {r['bursts']} | {skipped} | {cpu:.2f} of {runs[0]['cores']} |",
                flush=True,
            )
            if runs[0]["follower"] is not None:
                f = pooled(runs, "follower")
                print(
                    f"| {case}: the follower's time stamps | {fifo} | {f['syncs']} | {f['p50']:.3f} | "
                    f"{f['p99']:.3f} | {f['max']:.2f} | {f['maxes']} | {f['bursts']} | | |",
                    flush=True,
                )
            if args.floor == "beside":
                gaps = [r["shared"] for r in runs]
                mine = sum(g[0] for g in gaps)  # type: ignore[index]
                both = sum(g[1] for g in gaps)  # type: ignore[index]
                print(f"<!-- {case}: {mine} master gaps over 2 periods, {both} of them while the floor had one -->")
            at_wake = sum(r["where"][0] for r in runs)  # type: ignore[index]
            after_wake = sum(r["where"][1] for r in runs)  # type: ignore[index]
            print(
                f"<!-- {case}: of the master's gaps over 2 periods, {at_wake} before its thread ran again "
                f"(the wake-up, the GIL), {after_wake} after (the SYNC lock, the send) -->"
            )
            b = pooled(runs, "baseline")
            bfifo = "asked, granted" if b["fifo"] else ("asked, refused" if priority else "not asked")
            print(
                f"| {case}: bare timer loop (the machine's floor) | {bfifo} | {b['syncs']} | {b['p50']:.3f} | "
                f"{b['p99']:.3f} | {b['max']:.2f} | {b['maxes']} | {b['bursts']} | | |",
                flush=True,
            )


if __name__ == "__main__":
    main()
