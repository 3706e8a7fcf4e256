"""Service latency over zenoh on loopback: plan request -> reply, execute request -> all axes moving.

A pvtflow service for the arm6 cell (6 simulated EPOS2 drives on python-can's virtual bus, SYNC in
lockstep) behind a zenoh peer on a free 127.0.0.1 port; a zenoh client session in the same process
sends the requests, like any cell software would.

- idle: the process CPU time (and the busiest threads, from /proc/self/task) over ``--idle`` s with
  the cell served and nothing asked of it: what the simulated drives and the service burn while idle.
- plan: ``--plans`` requests of ``--waypoints`` random waypoints inside ``--range`` of each joint's
  range (``start: first``, so the request is exactly those waypoints), timed from ``session.get`` to
  the reply. Each reply's ``timing_ms`` splits it, per request (p50 / p99 of each part): TOPP-RA
  (``plan``), knots + validation (``knots``), the service's own code (``service - total``: worker
  queue, JSON parsing, schema and limit checks, plan bookkeeping) and zenoh + JSON outside the
  service (round trip - ``service``: request encoding, loopback transport both ways, reply encoding
  and decoding); "waiting" is ``total - cpu``, the time the planning thread was runnable but had no
  CPU or no GIL (other threads, other processes). A drawn path that leaves the position limits
  between waypoints is answered ``plan_failed`` and redrawn (counted, not timed), as in
  bench/plan_latency.py.
- execute: ``--executes`` moves alternating between two targets, each planned first; timed from
  ``session.get`` of execute to the CAN frame in which the LAST of the six drives reports ip mode
  active in its SYNC answer (TPDO2 statusword bit 12): that SYNC is program t = 0 on every axis. A
  tap on the master's frame recorder finds the frames (no second bus on the channel, no thread of
  the bench's own); the time is the frame's own (when it went on the bus), and when the master's
  receive thread got it is printed as well. The bound the issue sets is
  "plan time + 2 SYNC periods"; both the measured plan p50 and the 10 ms plan target are used.
- plans during a motion (``--during N``, N pairs): a ~2 s tour runs alone, then again while a second
  client sends plan requests back to back. Planner and drives share one interpreter (unless
  ``--planner-process``: the planner in a child process, service/planning.py): the SYNC rate of
  the lockstep motion and the latency of those plans show what each costs the other.

Run:  python bench/service_latency.py [--plans 200] [--executes 30] [--waypoints 8] [--seed 1] [--idle 5]
      [--during 1] [--planner-process]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can
import numpy as np

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.service.config import load_cell_config
from pvtflow.service.demo_cmd import free_port, tour
from pvtflow.service.motion import MotionService
from pvtflow.service.request_cmd import Client
from pvtflow.service.server import Server, peer_config

IP_MODE_ACTIVE = 0x1000
TARGETS = ([0.3, -0.2, 0.3, -0.2, 0.3, -0.2], [0.0] * 6)


class IpActiveWatch(can.Listener):
    """The first SYNC answer (TPDO2, 0x280 + node) with ip mode active, per node: when the frame was
    on the bus (its timestamp: python-can's virtual bus stamps a frame with time.time() when it is
    sent) and when the master got it (perf_counter; later by however long its receive thread
    waited for the interpreter, which the bench's process shares with the service and the drives)."""

    def __init__(self, nodes: list[int]) -> None:
        self.nodes = set(nodes)
        self.lock = threading.Lock()
        self.first: dict[int, tuple[float, float]] = {}
        self.armed = False

    def arm(self) -> None:
        with self.lock:
            self.first.clear()
            self.armed = True

    def on_message_received(self, msg: can.Message) -> None:
        now = time.perf_counter()
        node = msg.arbitration_id - 0x280
        if not self.armed or node not in self.nodes or len(msg.data) < 2:
            return
        statusword = msg.data[0] | (msg.data[1] << 8)
        if statusword & IP_MODE_ACTIVE:
            with self.lock:
                self.first.setdefault(node, (msg.timestamp, now))

    def all_moving_at(self) -> tuple[float, float] | None:
        """(bus time.time(), received perf_counter) of the last node's first ip-active answer."""
        with self.lock:
            if len(self.first) < len(self.nodes):
                return None
            return max(t for t, _ in self.first.values()), max(r for _, r in self.first.values())


PARTS = (
    "TOPP-RA",
    "knots + validation",
    "service code",
    "zenoh + JSON",
    "rest (all but planner)",
    "waiting (total - cpu)",
)


def thread_cpu() -> dict[int, tuple[str, float]]:
    """CPU seconds (user + system) of every thread of this process, by thread id, from /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name for t in threading.enumerate()}
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
        except OSError:  # the thread ended
            continue
        comm, rest = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :].split()
        out[int(tid)] = (names.get(int(tid), comm), (int(rest[11]) + int(rest[12])) / tick)
    return out


def idle_cpu(seconds: float) -> tuple[float, float, list[tuple[str, float]]]:
    """Process CPU seconds over ``seconds`` of idling, and the three busiest threads."""
    before, cpu0, t0 = thread_cpu(), time.process_time(), time.perf_counter()
    time.sleep(seconds)
    after, cpu1, t1 = thread_cpu(), time.process_time(), time.perf_counter()
    used = sorted(((c - before.get(tid, (n, 0.0))[1], n) for tid, (n, c) in after.items()), reverse=True)
    return cpu1 - cpu0, t1 - t0, [(n, c) for c, n in used[:3]]


def motion_with_plans(
    client: Client,
    service: MotionService,
    endpoint: str,
    rng: np.random.Generator,
    mid: np.ndarray,
    half: np.ndarray,
    with_plans: bool,
) -> tuple[float, list[float]]:
    """One ~2 s tour from where the axes are (and back home); SYNC/s of it, and the latency of the
    plan requests a second client sent while it ran (when ``with_plans``)."""
    cell = service.cell
    lim = cell.joint_limits()
    plan = client.request(cell.name, "plan", {"waypoints": tour(lim.lower, lim.upper, 4)})
    if not plan.ok:
        raise RuntimeError(f"tour: {plan.data}")
    stop, latencies = threading.Event(), []

    def plans() -> None:
        with Client(connect=endpoint) as other:
            while not stop.is_set():
                wp = rng.uniform(mid - half, mid + half, (8, lim.dof)).tolist()
                t0 = time.perf_counter()
                if other.request(cell.name, "plan", {"waypoints": wp, "start": "first"}).ok:
                    latencies.append((time.perf_counter() - t0) * 1e3)

    worker = threading.Thread(target=plans) if with_plans else None
    sync0, t0 = service.group.bus.sync.answered, time.perf_counter()  # type: ignore[union-attr]
    ex = client.request(cell.name, "execute", {"plan_id": plan.data["plan_id"]})
    if not ex.ok:
        raise RuntimeError(f"tour: {ex.data}")
    if worker is not None:
        worker.start()
    service.motion.done.wait(60)  # type: ignore[union-attr]
    rate = (service.group.bus.sync.answered - sync0) / (time.perf_counter() - t0)  # type: ignore[union-attr]
    stop.set()
    if worker is not None:
        worker.join()
    home = client.request(cell.name, "plan", {"target": TARGETS[1]})
    if home.ok:
        client.request(cell.name, "execute", {"plan_id": home.data["plan_id"], "wait": True}, timeout=60)
    return rate, latencies


def pct(a: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(a), q))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plans", type=int, default=200)
    parser.add_argument("--executes", type=int, default=30)
    parser.add_argument("--waypoints", type=int, default=8)
    parser.add_argument("--range", type=float, default=0.5, help="waypoints drawn in this fraction of each range")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--idle", type=float, default=5.0, help="seconds of idle CPU measurement (0: none)")
    parser.add_argument("--planner-process", action="store_true", help="plan in a child process (service/planning.py)")
    parser.add_argument("--during", type=int, default=1, help="motions alone / with plans meanwhile (pairs)")
    args = parser.parse_args(argv)

    cell = load_cell_config(None)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    journal = tempfile.mkdtemp(prefix="pvtflow-bench-")
    service = MotionService(
        cell, journal_dir=journal, clock=Clock.LOCKSTEP, planner_process=args.planner_process
    ).open()
    freeze_startup_objects()  # as pvtflow serve does once its service is open
    server = Server(service, peer_config(listen=[endpoint])).start()
    client = Client(connect=endpoint)
    watch = IpActiveWatch([a.node_id for a in cell.axes])
    # the master's frame recorder hands every frame it receives to its taps, in its receive thread:
    # no second bus on the channel (one more copy of every frame) and no thread of the bench's own
    # competing with the service and the drives for the interpreter
    taps = service.group.bus.recorder.taps  # type: ignore[union-attr]
    taps.append(watch.on_message_received)
    try:
        name = cell.name
        lim = cell.joint_limits()
        rng = np.random.default_rng(args.seed)
        mid, half = 0.5 * (lim.upper + lim.lower), 0.5 * args.range * (lim.upper - lim.lower)
        for _ in range(5):  # warm up (imports, caches, zenoh routes)
            client.request(name, "plan", {"target": TARGETS[0]})
        idle = idle_cpu(args.idle) if args.idle > 0 else None

        plan_ms: list[float] = []
        parts: dict[str, list[float]] = {k: [] for k in PARTS}
        redrawn, errors = 0, 0
        while len(plan_ms) < args.plans:
            wp = rng.uniform(mid - half, mid + half, (args.waypoints, lim.dof)).tolist()
            t0 = time.perf_counter()
            reply = client.request(name, "plan", {"waypoints": wp, "start": "first"})
            dt = time.perf_counter() - t0
            if not reply.ok:
                if reply.error_code == "plan_failed":
                    redrawn += 1
                    continue
                errors += 1  # the service survives a bug in the planner: count it, show how to reproduce it
                print(
                    f"plan error {reply.data['error']['code']}: {reply.data['error']['message']}\n  waypoints "
                    f"(start: first): {wp}",
                    file=sys.stderr,
                )
                if errors > 10:
                    return 1
                continue
            plan_ms.append(dt * 1e3)
            t = reply.data["timing_ms"]
            parts["TOPP-RA"].append(t["plan"])
            parts["knots + validation"].append(t["knots"])
            parts["service code"].append(t["service"] - t["total"])
            parts["zenoh + JSON"].append(dt * 1e3 - t["service"])
            parts["rest (all but planner)"].append(dt * 1e3 - t["plan"] - t["knots"])
            parts["waiting (total - cpu)"].append(t["total"] - t["cpu"])

        exec_ms, received_ms, reply_ms = [], [], []
        for i in range(args.executes):
            plan = client.request(name, "plan", {"target": TARGETS[i % 2]})
            if not plan.ok:
                print(f"plan failed: {plan.data}", file=sys.stderr)
                return 1
            watch.arm()
            t0, t0_wall = time.perf_counter(), time.time()
            ex = client.request(name, "execute", {"plan_id": plan.data["plan_id"]})
            t_reply = time.perf_counter()
            if not ex.ok:
                print(f"execute failed: {ex.data}", file=sys.stderr)
                return 1
            deadline = time.monotonic() + 5
            while watch.all_moving_at() is None and time.monotonic() < deadline:
                time.sleep(0.0005)
            moving = watch.all_moving_at()
            watch.armed = False
            if moving is None:
                print("the axes did not all report ip mode active", file=sys.stderr)
                return 1
            exec_ms.append((moving[0] - t0_wall) * 1e3)
            received_ms.append((moving[1] - t0) * 1e3)
            reply_ms.append((t_reply - t0) * 1e3)
            service.motion.done.wait(30)
            if service.motion.outcome["result"] != "finished":
                print(f"motion ended: {service.motion.outcome['message']}", file=sys.stderr)
                return 1

        during: dict[bool, list[tuple[float, list[float]]]] = {False: [], True: []}
        for _ in range(args.during):
            for with_plans in (False, True):
                during[with_plans].append(motion_with_plans(client, service, endpoint, rng, mid, half, with_plans))
    finally:
        taps.remove(watch.on_message_received)
        client.close()
        server.close()
        service.close()

    sync_ms = cell.bus.sync_period_ms
    p50_plan = pct(plan_ms, 50)
    print(
        f"command: python bench/service_latency.py --plans {args.plans} --executes {args.executes} "
        f"--waypoints {args.waypoints} --range {args.range} --seed {args.seed} --idle {args.idle:g} "
        f"--during {args.during}{' --planner-process' if args.planner_process else ''}"
    )
    print(
        f"cell {cell.name}: {len(cell.axes)} simulated EPOS2 axes, SYNC {sync_ms:g} ms lockstep; zenoh peer on "
        f"{endpoint}, client session in-process; {os.cpu_count()} CPU(s)"
    )
    print(
        f"plan request -> reply ({args.waypoints} waypoints, {args.plans} plans, {redrawn} drawn paths "
        f"redrawn, {errors} other errors):  p50 {p50_plan:.2f} ms   p99 {pct(plan_ms, 99):.2f} ms   "
        f"max {max(plan_ms):.2f} ms"
    )
    print("  per request, ms:        p50      p99")
    for part, values in parts.items():
        print(f"    {part:22s} {pct(values, 50):7.2f}  {pct(values, 99):7.2f}")
    if idle is not None:
        cpu_s, seconds, busiest = idle
        print(
            f"idle (served, nothing asked): process CPU {cpu_s:.3f} s over {seconds:.1f} s "
            f"({100 * cpu_s / seconds:.1f}% of one core); busiest threads: "
            + ", ".join(f"{n} {c:.3f} s" for n, c in busiest)
        )
    print(
        f"execute request -> all {len(cell.axes)} axes in ip mode ({args.executes} moves):  p50 "
        f"{pct(exec_ms, 50):.2f} ms   p99 {pct(exec_ms, 99):.2f} ms   max {max(exec_ms):.2f} ms  "
        f"(reply p50 {pct(reply_ms, 50):.2f} ms; that frame received by the master p50 "
        f"{pct(received_ms, 50):.2f} ms)"
    )
    ready = exec_ms[1:] or exec_ms  # after the first run every start finds the cell ready (AxisGroup)
    print(
        f"  the first (the cell not ready yet: every axis enabled by SDO) {exec_ms[0]:.2f} ms; the other "
        f"{len(ready)} (ready after the run before: checked by one SYNC) p50 {pct(ready, 50):.2f} ms   "
        f"p99 {pct(ready, 99):.2f} ms   max {max(ready):.2f} ms"
    )
    for label, plan_time in (("measured plan p50", p50_plan), ("10 ms plan target", 10.0)):
        bound = plan_time + 2 * sync_ms
        print(
            f"  bound {label} + 2 SYNC = {bound:.2f} ms: p50 {'within' if pct(exec_ms, 50) <= bound else 'OVER'}, "
            f"p99 {'within' if pct(exec_ms, 99) <= bound else 'OVER'}; ready cell p50 "
            f"{'within' if pct(ready, 50) <= bound else 'OVER'}, p99 {'within' if pct(ready, 99) <= bound else 'OVER'}"
        )
    for with_plans, runs in during.items():
        if runs:
            rates = ", ".join(f"{rate:.0f}" for rate, _ in runs)
            lat = [x for _, ms in runs for x in ms]
            extra = f"; {len(lat)} plans meanwhile: p50 {pct(lat, 50):.2f} ms p99 {pct(lat, 99):.2f} ms" if lat else ""
            print(f"tour {'with plan requests meanwhile' if with_plans else 'alone'}: {rates} SYNC/s{extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
