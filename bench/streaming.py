"""Streaming benchmark: 8 simulated EPOS2 axes, a long PVT program, SYNC lockstep (faster than real time).

Figures: buffer underflows / overflows (must be 0), min / max FIFO level per axis (the drive's own
count), host CPU time per record (the master's receive thread, which runs every feeder and the
SYNC clock; and the whole process with the simulated drives), frames per second (wall clock and
bus time), bus load at the bit rate (every frame's bits counted with its real bit stuffing and
CRC), start skew in SYNC periods (must be 0), and the halt latency after a fault on one axis (must
be within one SYNC period).

    python3 bench/streaming.py [--axes 8] [--records 100000] [--record-ms 8] [--sync-ms 4]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.service.config import CellConfig, load_cell_config


# --- CAN frame length ---------------------------------------------------------------------------------
def _crc15(bits: list[int]) -> int:
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def frame_bits(msg: can.Message) -> int:
    """Bits on the wire of one classic CAN frame: SOF..CRC with bit stuffing, then the fixed tail
    (CRC delimiter, ACK slot + delimiter, 7 EOF, 3 intermission)."""
    bits: list[int] = [0]  # SOF
    if msg.is_extended_id:
        ident = msg.arbitration_id
        bits += [(ident >> (28 - i)) & 1 for i in range(11)] + [1, 1]  # base id, SRR, IDE
        bits += [(ident >> (17 - i)) & 1 for i in range(18)] + [int(msg.is_remote_frame), 0, 0]
    else:
        bits += [(msg.arbitration_id >> (10 - i)) & 1 for i in range(11)] + [int(msg.is_remote_frame), 0, 0]
    dlc = msg.dlc
    bits += [(dlc >> (3 - i)) & 1 for i in range(4)]
    if not msg.is_remote_frame:
        for byte in bytes(msg.data):
            bits += [(byte >> (7 - i)) & 1 for i in range(8)]
    crc = _crc15(bits)
    bits += [(crc >> (14 - i)) & 1 for i in range(15)]
    stuffed, run, last = 0, 0, -1
    for b in bits:
        if b == last:
            run += 1
        else:
            run, last = 1, b
        if run == 5:
            stuffed += 1
            last, run = 1 - b, 1  # the stuff bit starts the next run
    return len(bits) + stuffed + 13


class FrameTap:
    """Keeps (id, extended, remote, data) of every frame; the bits are counted after the run, so that
    the bit-level CRC and stuffing arithmetic does not load the master's thread being measured."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bool, bool, int, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, msg: can.Message) -> None:
        with self.lock:
            self.frames.append((msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc, bytes(msg.data)))

    def bits(self, start: int = 0) -> int:
        total = 0
        for ident, ext, remote, dlc, data in self.frames[start:]:
            total += frame_bits(
                can.Message(arbitration_id=ident, is_extended_id=ext, is_remote_frame=remote, dlc=dlc, data=data)
            )
        return total


# --- the cell and the program -----------------------------------------------------------------------------
def bench_cell(n_axes: int, sync_ms: float) -> tuple[CellConfig, tuple[AxisConfig, ...]]:
    arm = load_cell_config(None)
    base = arm.ordered_axes()
    axes = tuple(dataclasses.replace(base[i % len(base)], joint=f"axis_{i + 1}", node_id=i + 1) for i in range(n_axes))
    bus = dataclasses.replace(arm.bus, channel=f"bench-{uuid.uuid4().hex[:8]}", sync_period_ms=sync_ms)
    return dataclasses.replace(arm, name="bench", axes=axes, bus=bus), axes


def long_program(axes: tuple[AxisConfig, ...], records_per_axis: int, record_ms: int) -> PvtProgram:
    """Back-and-forth rest-to-rest quintic moves at half the drive limits, sampled every record_ms."""
    out = []
    for i, axis in enumerate(axes):
        sc, lim = axis.scaling, axis.limits
        span = (records_per_axis - 1) * record_ms  # the last record ends a move: at rest
        moves = max(1, round(span / (400.0 + 40.0 * i)))
        move_ms = span / moves
        vmax = float(sc.rpm_to_qc_per_ms(lim.max_profile_velocity_rpm))
        amax = float(sc.rpm_s_to_qc_per_ms2(lim.max_acceleration_rpm_s))
        dist = 0.4 * min(
            vmax * move_ms / 1.875, amax * move_ms**2 / 5.7735, 0.8 * min(lim.max_position_qc, -lim.min_position_qc)
        )
        t = np.arange(records_per_axis) * record_ms
        k = np.minimum(np.floor(t / move_ms), moves - 1)
        u = (t - k * move_ms) / move_ms
        sign = np.where(k % 2 == 0, 1.0, -1.0)  # out and back
        s = u**3 * (10 - 15 * u + 6 * u**2)
        ds = 30 * u**2 * (1 - u) ** 2 / move_ms
        p = np.where(sign > 0, dist * s, dist * (1 - s))
        v = sign * dist * ds
        records = np.empty((records_per_axis + 1, 3), dtype=np.int64)
        records[:-1, 0] = np.round(p)
        records[:-1, 1] = np.round(v / sc.qc_per_ms_per_velocity_unit)
        records[:-1, 2] = record_ms
        records[0] = [0, 0, record_ms]
        records[-1] = [records[-2, 0], 0, 0]
        out.append(AxisProgram.of(dataclasses.replace(axis, scaling=sc, limits=lim), records))
    return PvtProgram("bench", tuple(out))


def thread_cpu(thread: threading.Thread) -> float:
    assert thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


def notifier_thread(bus: CellBus) -> threading.Thread:
    assert bus.network.notifier is not None
    return next(t for t in bus.network.notifier._readers if isinstance(t, threading.Thread))


# --- runs -------------------------------------------------------------------------------------------------
def streaming_run(args: argparse.Namespace) -> None:
    cell, axes = bench_cell(args.axes, args.sync_ms)
    per_axis = -(-args.records // args.axes)
    prog = long_program(axes, per_axis, args.record_ms)
    if not args.no_validate:
        from pvtflow.planner.validate import validate_program

        report = validate_program(prog)
        if not report.ok:
            print(report.format_text())
            raise SystemExit("the benchmark program is invalid")
    total_records = sum(len(a.records) for a in prog.axes)
    cell = sharing_the_interpreter(cell)  # the drives run in this interpreter
    sim = SimulatedCell(cell).start()
    bus = CellBus(cell.bus, clock=Clock.LOCKSTEP).open()
    tap = FrameTap()
    bus.recorder.taps.append(tap)
    group = AxisGroup(bus, axes)
    drives = [sim.drive(a.node_id) for a in axes]
    low: list[int | None] = [None] * len(axes)

    def drive_levels(n: int) -> None:
        # after every answered SYNC, before the feeders refill: the FIFO's low point (drive's count)
        for i, (d, f) in enumerate(zip(drives, group.feeders, strict=True)):
            if d.ip_active and not f.all_sent:
                low[i] = d.level if low[i] is None else min(low[i], d.level)

    bus.sync.add_listener(drive_levels)  # runs before the group's listener (added at the start)
    try:
        group.configure()
        master_thread = notifier_thread(bus)
        cpu_master0, cpu_proc0 = thread_cpu(master_thread), time.process_time()
        frames0 = len(tap.frames)
        wall0 = time.perf_counter()
        result = group.run(prog, timeout_s=3600)
        wall = time.perf_counter() - wall0
        cpu_master = thread_cpu(master_thread) - cpu_master0
        cpu_proc = time.process_time() - cpu_proc0
        frames = len(tap.frames) - frames0
    finally:
        group.close()
        bus.close()
        sim.stop()
    if result.result is not Result.FINISHED:
        raise SystemExit(f"streaming run ended with {result.result.value}: {result.message}")
    bits = tap.bits(frames0)
    bus_time_s = (result.end_sync - result.start_sync + 1) * args.sync_ms / 1000.0
    underflows = sum(a.feed.underflows for a in result.axes)
    overflows = sum(a.feed.overflows for a in result.axes)
    drive_faults = sum(len(d.faults) for d in sim)
    print(
        f"program: {len(axes)} axes x {per_axis + 1} records = {total_records} records, "
        f"{prog.duration_ms / 1000:.1f} s of motion, records every {args.record_ms} ms, SYNC every {args.sync_ms} ms"
    )
    print(f"result: {result.result.value}; drive faults {drive_faults}")
    print(f"underflows: {underflows}   overflows: {overflows}   (buffer error bits and drive faults: must be 0)")
    print("FIFO level per axis while records were left to send (drive's own count; feeder's estimate):")
    for i, (a, d) in enumerate(zip(result.axes, drives, strict=True)):
        print(
            f"  {a.joint:7s} node {a.node_id}: drive min {low[i]} max {d.max_level}; "
            f"feeder min {a.feed.min_level} max {a.feed.max_level}; records sent {a.feed.sent}"
        )
    print(
        f"start skew: {result.start_skew_syncs} SYNC period(s) (master, statusword bit 12); "
        f"drives entered ip mode at SYNC(s) {sorted({d.ip_active_sync for d in sim})}"
    )
    print(f"wall time {wall:.2f} s for {bus_time_s:.1f} s of bus time: {bus_time_s / wall:.2f}x real time")
    print(
        f"host CPU per record: master receive thread {1e6 * cpu_master / total_records:.1f} us, "
        f"whole process incl. simulated drives {1e6 * cpu_proc / total_records:.1f} us"
    )
    print(f"frames: {frames} ({frames / wall:.0f} frames/s wall, {frames / bus_time_s:.0f} frames/s of bus time)")
    print(
        f"bus load at {cell.bus.bitrate / 1e6:g} Mbit/s: {bits / bus_time_s / cell.bus.bitrate * 100:.1f}% "
        f"({bits / frames:.1f} bits per frame with stuffing)"
    )


def halt_run(args: argparse.Namespace) -> None:
    """A fault inside one drive (its feeder stops: FIFO underflow) and the halt of all the others."""
    cell, axes = bench_cell(args.axes, args.sync_ms)
    prog = long_program(axes, 2000, args.record_ms)
    cell = sharing_the_interpreter(cell)  # the drives run in this interpreter
    sim = SimulatedCell(cell).start()
    bus = CellBus(cell.bus, clock=Clock.LOCKSTEP).open()
    group = AxisGroup(bus, axes)
    index = len(axes) // 2
    faulty = sim.drive(axes[index].node_id)
    try:
        assert group.start(prog) is None
        group.feeders[index].enabled = False  # starved after its preload
        result = group.wait(60)
    finally:
        group.close()
        bus.close()
        sim.stop()
    fault_sync = faulty.faults[0].sync
    halts = []
    for d in sim:
        if d is faulty:
            continue
        active = [s.sync for s in d.history if s.ip_active]
        halts.append(active[-1] + 1 - fault_sync)  # the first SYNC without interpolation, after the fault's
    print(
        f"halt after a fault on node {faulty.node_id} ({faulty.faults[0].check}; "
        f"{result.result.value}: {result.message})"
    )
    print(
        f"  master: halt controlword on SYNC {result.halt_sync}, {result.halt_latency_syncs} SYNC period(s) "
        f"after the period of the fault; {1e6 * (result.halt_latency_s or 0):.0f} us from the fault report "
        f"to the last halt frame sent"
    )
    print(
        f"  drives: every other axis stopped interpolating {min(halts)}..{max(halts)} SYNC period(s) after "
        f"the SYNC on which node {faulty.node_id} faulted (must be <= 1)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--axes", type=int, default=8)
    ap.add_argument("--records", type=int, default=100_000, help="records in total (all axes)")
    ap.add_argument("--record-ms", type=int, default=8, help="time of each record (1-255 ms)")
    ap.add_argument("--sync-ms", type=float, default=4.0, help="SYNC period")
    ap.add_argument("--no-validate", action="store_true", help="skip planner.validate on the program")
    args = ap.parse_args()
    print("command: python3 " + " ".join(sys.argv))
    streaming_run(args)
    halt_run(args)


if __name__ == "__main__":
    main()
