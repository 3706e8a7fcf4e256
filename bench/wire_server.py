"""How many frames per second the simwire loopback server (``axes.sim.wire.server``) carries.

The server process hosts the medium and ``--local`` nodes of its own, each drained by a thread
(where ``pvtflow sim`` runs the drives: a canopen Notifier per drive); this process holds the
remote clients: one sender (the master) and ``--remote`` receivers each drained by a thread.
Every frame goes client -> server -> every other node. The sender keeps its transmit FIFO full
(``send(timeout=5)``): the figure is what the server and its clients carry, not the wire's bit
time, so the wall-clock case runs the wire at ``--bitrate`` (default 50 Mbit/s, far above any
real bus) and the lockstep case has no bit time in wall time at all.

    python bench/wire_server.py [--frames N] [--local L] [--remote R] [--bitrate B]

What the busiest shipped cell needs on the wall clock: about 3000 frames/s (docs/cells.md, "Sizing a
cell": six EPOS2 at 5 ms, or three fixed-period axes at 2 ms).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from wire_medium import drain_all, frames  # noqa: E402

from pvtflow.axes.sim.wire import SimWireBus  # noqa: E402

SERVER = """
import sys
sys.path.insert(0, {root!r})
sys.path.insert(0, {bench!r})
from pvtflow.axes.sim.wire import SimWireBus, serve_wire
from wire_medium import drain_all
server = serve_wire("bench", 0, clock={clock!r}, bitrate={bitrate}, sync_period=0.001)
buses = [SimWireBus("bench") for _ in range({local})]
got, threads = drain_all(buses, {count})
print(server.address, flush=True)
for t in threads:
    t.join()
print(min(got, default={count}), flush=True)
sys.stdin.read()
for b in buses:
    b.shutdown()
server.close()
"""


def run(clock: str, count: int, local: int, remote: int, bitrate: int) -> dict[str, float]:
    code = SERVER.format(
        root=str(ROOT), bench=str(ROOT / "bench"), clock=clock, bitrate=bitrate, local=local, count=count
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        channel = child.stdout.readline().strip()
        sender = SimWireBus(channel, txqueuelen=10)
        receivers = [SimWireBus(channel) for _ in range(remote)]
        got, threads = drain_all(receivers, count)
        msgs = frames(count)
        server_cpu0, cpu0, t0 = process_cpu(child.pid), time.process_time(), time.perf_counter()
        for m in msgs:
            sender.send(m, timeout=5.0)
        for t in threads:
            t.join()
        local_got = int(child.stdout.readline())
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        server_cpu = process_cpu(child.pid) - server_cpu0
        for bus in (sender, *receivers):
            bus.shutdown()
        assert min(got, default=count) == count and local_got == count, (got, local_got)
    finally:
        child.stdin.close()
        child.wait(timeout=10)
    return {
        "frames_per_s": count / wall,
        "deliveries_per_s": count * (local + remote) / wall,
        "server_us": 1e6 * server_cpu / count,
        "client_us": 1e6 * cpu / count,
    }


def process_cpu(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--local", type=int, default=0, help="nodes of the server's process (drives)")
    parser.add_argument("--remote", type=int, default=1, help="remote receivers beside the sender (monitors)")
    parser.add_argument("--bitrate", type=int, default=50_000_000, help="wall clock: the wire's bit rate")
    args = parser.parse_args()
    print(
        f"python bench/wire_server.py --frames {args.frames} --local {args.local} --remote {args.remote} "
        f"--bitrate {args.bitrate}"
    )
    print(f"{'clock':10} {'frames/s':>9} {'deliveries/s':>13} {'server CPU us/frame':>20} {'clients CPU us/frame':>21}")
    for clock in ("lockstep", "wall"):
        r = run(clock, args.frames, args.local, args.remote, args.bitrate)
        print(
            f"{clock:10} {r['frames_per_s']:9.0f} {r['deliveries_per_s']:13.0f} {r['server_us']:20.1f} "
            f"{r['client_us']:21.1f}"
        )


if __name__ == "__main__":
    main()
