"""The host's own SYNC floor per CPU: does it stall one CPU's timer wake-ups at a time?

With ``--load`` busy-loop processes beside them, for ``--runs`` runs of ``--seconds``:

- ``pinned``: two bare timer loops (``sync_jitter.bare_timer``: one SCHED_FIFO thread, absolute 1 ms
  deadlines, nothing else), each in a process of its own, pinned to CPU 0 and CPU 1. Each run's
  gaps over 2 periods per CPU, with when they began: a stall of one CPU shows on one loop only.
- ``two threads``: one process, two SCHED_FIFO threads waking at the same deadlines, the second a
  quarter period later; whichever is awake first sends (the rule of ``SyncClock.backup``), pinned
  to two CPUs and, for comparison, both to CPU 0. Each run's max interval of the sends.

What it shows (bench/RESULTS.md, "Issue 23: SYNC under load (branch sync23)"): whether the second
SYNC thread on another CPU covers what the host adds.

    python3 bench/cpu_stalls.py [--runs 8] [--seconds 3] [--load 2]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sync_jitter import bare_timer, busy

PERIOD_S = 0.001


def pinned_floor(cpu: int, seconds: float, out: multiprocessing.connection.Connection) -> None:  # type: ignore[name-defined]
    os.sched_setaffinity(0, {cpu})
    bare_timer(seconds, PERIOD_S * 1000, 50, out)


def two_threads(seconds: float, cpus: tuple[int, int], out: multiprocessing.connection.Connection) -> None:  # type: ignore[name-defined]
    """Two SCHED_FIFO threads, the second BACKUP_AFTER past each deadline; the first awake sends."""
    sys.setswitchinterval(0.0001)
    lock = threading.Lock()
    sent: list[float] = []
    start = time.monotonic() + 0.05
    end = start + seconds
    state = {"deadline": start}

    def run(cpu: int, after: float) -> None:
        os.sched_setaffinity(0, {cpu})
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
        while True:
            with lock:
                due = state["deadline"]
            delay = due + after - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            now = time.monotonic()
            if now > end:
                return
            with lock:
                if now >= state["deadline"]:
                    sent.append(now)
                    late = now - state["deadline"]
                    state["deadline"] = (now if late > PERIOD_S / 2 else state["deadline"]) + PERIOD_S

    offsets = (0.0, PERIOD_S / 4)
    threads = [threading.Thread(target=run, args=(cpu, after)) for cpu, after in zip(cpus, offsets, strict=True)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    out.send(sent)


def loaded(load: int, body):  # type: ignore[no-untyped-def]
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    time.sleep(0.2)
    try:
        return body()
    finally:
        stop.set()
        for w in workers:
            w.join(2.0)


def child(target, *args):  # type: ignore[no-untyped-def]
    receive, send = multiprocessing.Pipe(duplex=False)
    proc = multiprocessing.Process(target=target, args=(*args, send), daemon=True)
    proc.start()
    return receive, proc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--load", type=int, default=2)
    args = parser.parse_args()
    if len(os.sched_getaffinity(0)) < 2:
        raise SystemExit("cpu_stalls: this compares two CPUs; the process may run on one only")
    print(f"1 ms deadlines, {args.seconds:g} s per run, {args.load} busy processes beside")
    print("pinned bare timer loops: gaps over 2 periods per CPU, 'at' seconds into the run (length in ms)")
    for i in range(args.runs):

        def floors() -> list[list[float]]:
            pipes = [child(pinned_floor, cpu, args.seconds) for cpu in (0, 1)]
            return [receive.recv()[1] for receive, _ in pipes]

        woke = loaded(args.load, floors)
        t0 = min(w[0] for w in woke)
        cells = []
        for cpu, w in enumerate(woke):
            t = np.asarray(w)
            gaps = np.diff(t)
            late = [f"{t[k] - t0:.3f}s ({gaps[k] * 1000:.1f})" for k in np.nonzero(gaps > 2 * PERIOD_S)[0]]
            cells.append(f"CPU {cpu}: max {gaps.max() / PERIOD_S:.2f}, " + (" ".join(late) or "none"))
        print(f"  run {i + 1}: " + " | ".join(cells), flush=True)
    for cpus in ((0, 1), (0, 0)):
        maxes = []
        for _ in range(args.runs):

            def pair(cpus: tuple[int, int] = cpus) -> list[float]:
                receive, _ = child(two_threads, args.seconds, cpus)
                return receive.recv()

            sent = np.asarray(loaded(args.load, pair))
            maxes.append(np.diff(sent).max() / PERIOD_S)
        over = sum(m > 2 for m in maxes)
        print(
            f"two threads on CPUs {cpus}: each run's max interval {' '.join(f'{m:.2f}' for m in maxes)} "
            f"({over} of {args.runs} over 2 periods)",
            flush=True,
        )


if __name__ == "__main__":
    main()
