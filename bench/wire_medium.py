"""How many frames per second the simulated wire (``axes.sim.wire``) carries, in-process and
through the loopback server, on both clocks.

A 1 ms SYNC cell carries about 1000-3000 frames/s; the wire must carry that with room to spare
and cost microseconds per frame. Each case: one sender, ``--receivers`` other nodes each drained
by its own thread (as canopen's Notifier does); a SYNC and six 8-byte frames per period.

* lockstep: frames are delivered inside send(): the figure is what the simulation costs.
* cross-process: the receivers are buses of the server's process (where ``pvtflow sim`` runs the
  drives), the sender and one monitor are remote clients (the master's process); every send
  waits for the server's acknowledgement.
* wall at 1 Mbit/s: the wire itself limits (this mix: about 9200 frames/s);
  the sender keeps its FIFO full (send with a timeout), the figure is the bus utilisation reached.

    python bench/wire_medium.py [--frames N] [--receivers R]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pvtflow.axes.canbus.frame_time import frame_bits  # noqa: E402
from pvtflow.axes.sim.wire import SimWireBus  # noqa: E402

BITRATE = 1_000_000


def frames(count: int) -> list[can.Message]:
    """A SYNC and six 8-byte RPDOs per period, as a 6-axis cell's master sends them (in lockstep
    the SYNC advances the sender's virtual time, so its FIFO drains)."""
    return [
        can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        if i % 7 == 0
        else can.Message(arbitration_id=0x200 + (i % 7), data=i.to_bytes(4, "little") * 2, is_extended_id=False)
        for i in range(count)
    ]


def drain_all(buses: list[can.BusABC], count: int) -> tuple[list[int], list[threading.Thread]]:
    """A thread per bus reading ``count`` frames (as canopen's Notifier reads them)."""
    got = [0] * len(buses)

    def drain(i: int, bus: can.BusABC) -> None:
        while got[i] < count and bus.recv(5.0) is not None:
            got[i] += 1

    threads = [threading.Thread(target=drain, args=(i, b), daemon=True) for i, b in enumerate(buses)]
    for t in threads:
        t.start()
    return got, threads


def run(channel: str, count: int, receivers: int, clock: str) -> dict[str, float]:
    kwargs = {"clock": clock, "sync_period": 0.001, "bitrate": BITRATE} if "@" not in channel else {}
    sender = SimWireBus(channel, txqueuelen=10, **kwargs)
    nodes = [SimWireBus(channel) for _ in range(receivers)]
    got, threads = drain_all(nodes, count)
    msgs = frames(count)
    cpu0, t0 = time.process_time(), time.perf_counter()
    for m in msgs:
        sender.send(m, timeout=5.0)
    sent = time.perf_counter() - t0
    for t in threads:
        t.join()
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    bits = sum(frame_bits(m.arbitration_id, bytes(m.data)) for m in msgs)
    stats = sender.medium.stats()
    for bus in (sender, *nodes):
        bus.shutdown()
    assert min(got) == count, got
    return {
        "frames_per_s": count / wall,
        "send_us": 1e6 * sent / count,
        "cpu_us_per_frame": 1e6 * cpu / count,
        "bus_load": bits / BITRATE / wall,
        "enobufs": sum(stats.enobufs.values()),
    }


SERVER = """
import sys, threading
sys.path.insert(0, {root!r})
from pvtflow.axes.sim.wire import SimWireBus, serve_wire
sys.path.insert(0, {bench!r})
from wire_medium import drain_all
server = serve_wire("bench", 0, clock={clock!r}, bitrate={bitrate}, sync_period=0.001)
buses = [SimWireBus("bench") for _ in range({receivers})]
got, threads = drain_all(buses, {count})
print(server.address, flush=True)
for t in threads:
    t.join()
print(min(got), flush=True)
sys.stdin.read()
for b in buses:
    b.shutdown()
server.close()
"""


def serve(clock: str, receivers: int, count: int) -> tuple[subprocess.Popen, str]:
    """A server process whose ``receivers`` nodes are its own buses (where ``pvtflow sim`` runs
    the drives); the bench process holds the sender (the master) and one remote monitor."""
    code = SERVER.format(
        root=str(ROOT), bench=str(ROOT / "bench"), clock=clock, bitrate=BITRATE, receivers=receivers, count=count
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    return child, child.stdout.readline().strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--receivers", type=int, default=6)
    args = parser.parse_args()
    print(f"python bench/wire_medium.py --frames {args.frames} --receivers {args.receivers}")
    print(f"{'case':34} {'frames/s':>9} {'send us':>8} {'CPU us/frame':>13} {'bus load':>9} {'ENOBUFS':>8}")
    for clock in ("lockstep", "wall"):
        for where in ("in-process", "cross-process"):
            if where == "in-process":
                r = run(f"bench-{clock}", args.frames, args.receivers, clock)
            else:
                child, channel = serve(clock, args.receivers, args.frames)
                try:
                    r = run(channel, args.frames, 1, clock)
                    assert int(child.stdout.readline()) == args.frames  # every drive node got every frame
                finally:
                    child.stdin.close()
                    child.wait(timeout=10)
            load = f"{r['bus_load']:.0%}" if clock == "wall" else "-"
            print(
                f"{clock + ', ' + where:34} {r['frames_per_s']:9.0f} {r['send_us']:8.1f} "
                f"{r['cpu_us_per_frame']:13.1f} {load:>9} {r['enobufs']:8d}"
            )
    print(f"(wall: the wire carries at most {run_capacity():.0f} of these frames/s at {BITRATE} bit/s)")


def run_capacity() -> float:
    msgs = frames(1000)
    return BITRATE * len(msgs) / sum(frame_bits(m.arbitration_id, bytes(m.data)) for m in msgs)


if __name__ == "__main__":
    main()
