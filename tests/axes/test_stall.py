"""A master process that stalls mid-motion (SIGSTOP for 50 ms, as a preempted or swapped-out master
would) halts every axis when it resumes and says why (``sync_gap``): the drives, in their own
process (``pvtflow sim --wall-clock`` serving the simulated wire), kept their own clocks through
the gap. Not timed: bench/stall.py measures how fast."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest
import yaml
from axes_programs import axis_program, safe_distance

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup, Result
from pvtflow.service.config import CellConfig, load_cell_config
from pvtflow.service.sim_cmd import WIRE_SERVED_AT

REPO = Path(__file__).resolve().parents[2]
GANTRY = REPO / "configs" / "cells" / "gantry3-ip-linear.yaml"  # fixed-period drives: they ride out 2 periods
STALL_S = 0.05
PERIOD_MS = 8.0  # the drives ride out 16 ms; a quarter of the shipped 2 ms's frames for the loopback wire server


def at_period(cell_file: Path, period_ms: float, directory: Path) -> Path:
    """A copy of ``cell_file`` whose SYNC period is ``period_ms``."""
    data = yaml.safe_load(cell_file.read_text())
    data["robot"]["urdf"] = str((cell_file.parent / data["robot"]["urdf"]).resolve())
    data["bus"]["sync_period_ms"] = period_ms
    out = directory / cell_file.name
    out.write_text(yaml.safe_dump(data))
    return out


def serve(cell_file: Path) -> Iterator[tuple[CellConfig, subprocess.Popen[str]]]:
    """``pvtflow sim --wall-clock`` on a channel of its own; the cell as a master in this process sees it."""
    cell = load_cell_config(cell_file)
    channel = f"stall-{uuid.uuid4().hex[:8]}"
    args = [sys.executable, "-m", "pvtflow.service.cli", "sim", "--config", str(cell_file), "--channel", channel]
    process = subprocess.Popen(
        [*args, "--wall-clock"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        address = None
        assert process.stdout is not None
        deadline = time.monotonic() + 60.0
        while address is None and time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            if WIRE_SERVED_AT in line:
                address = line.split(WIRE_SERVED_AT, 1)[1].split()[0]
        assert address is not None, (
            f"pvtflow sim did not serve its wire: {process.stderr.read() if process.stderr else ''}"
        )
        yield dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=address), simulated=False), process
    finally:
        process.terminate()
        try:
            process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            process.kill()


def stall_this_process(seconds: float) -> tuple[float, float]:
    """Another process stops this one (SIGSTOP) and continues it (SIGCONT) ``seconds`` later; when
    it did both, on the host's monotonic clock (``time.monotonic()`` of every process)."""
    code = "import os, signal, sys, time; p = int(sys.argv[1]); t0 = time.monotonic(); os.kill(p, signal.SIGSTOP); "
    code += f"time.sleep({seconds}); t1 = time.monotonic(); os.kill(p, signal.SIGCONT); print(t0, t1)"
    out = subprocess.run([sys.executable, "-c", code, str(os.getpid())], capture_output=True, text=True, timeout=30)
    stopped, resumed = (float(v) for v in out.stdout.split())
    return stopped, resumed


def toward_the_middle(axes_of: Sequence[AxisConfig], here: list[int | None], duration_ms: int) -> PvtProgram:
    """A move of every axis from where it stands toward the middle of its 0x607D range."""
    axes = []
    for axis, start in zip(axes_of, here, strict=True):
        at = int(start or 0)
        middle = (axis.limits.min_position_qc + axis.limits.max_position_qc) / 2
        sign = 1 if middle >= at else -1
        distance = sign * min(safe_distance(axis, duration_ms, 0.3), abs(middle - at))
        axes.append(axis_program(axis, at, distance, duration_ms))
    return PvtProgram("stall", tuple(axes))


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[CellConfig, subprocess.Popen[str]]]:
    yield from serve(at_period(GANTRY, PERIOD_MS, tmp_path))


@pytest.mark.wall
def test_a_50_ms_stall_of_the_master_halts_every_axis_and_says_sync_gap(served) -> None:
    cell, drives = served
    # the master reports a gap past 40 ms (5 periods) rather than the drives' 16, and retries a
    # frame for 20 ms rather than 2: a loaded test host holds the master's process for 30 ms now and
    # then by itself, and the loopback wire client's queue with it; the 50 ms stall must be what halts
    # SYNC from this process (``cyclic_process`` false): with the cyclic process (``auto`` on this served wire) a
    # stall of the master's process holds neither SYNC nor the setpoints, and the motion runs on
    bus_config = dataclasses.replace(cell.bus, max_sync_gap_periods=5, tx_retry_ms=20.0, cyclic_process=False)
    cell = dataclasses.replace(cell, bus=bus_config)
    bus = CellBus(cell.bus, clock=Clock.WALL).open()
    # two of the three axes: the loopback wire server (Python) carries their frames on a loaded host
    group = AxisGroup(bus, cell.ordered_axes()[:2])
    events = []
    group.on_event = events.append
    try:
        group.refresh()
        here = [lk.position for lk in group.links]
        prog = toward_the_middle([lk.config for lk in group.links], here, 3000)
        assert group.start(prog) is None
        deadline = time.monotonic() + 60
        while group.running and (group.elapsed_syncs() or 0) * cell.bus.sync_period_ms < 300:
            assert time.monotonic() < deadline
            time.sleep(0.005)
        assert group.running, group.wait(1.0).message
        stall_this_process(STALL_S)
        result = group.wait(timeout_s=30)
        assert result.result is Result.BUS_ERROR, result.message
        # the wire sends SYNC itself (its broadcast manager, axes.master.bus.sync_follower): SYNCs went on
        # through the stall without setpoints; a master that sends SYNC itself sent none
        what = "no setpoint for" if bus.sync.native else "no SYNC for"
        assert what in result.message
        gaps = [e for e in events if e.kind.value == "sync_gap"]
        assert gaps and what in gaps[0].message
        gap_ms = float(gaps[0].message.split(f"{what} ", 1)[1].split(" ms", 1)[0])
        assert gap_ms >= STALL_S * 1000 * 0.9  # the stall itself, as the master measured it
        stop = group.last_quick_stop
        assert stop is not None and stop.done.wait(5.0)
        assert sorted(stop.confirmed) + sorted(stop.nmt_stopped) != []
        assert set(stop.confirmed) | set(stop.nmt_stopped) == {lk.node_id for lk in group.links}, stop.describe()
        # every axis stands still short of its end, and its drive is out of OPERATION ENABLED
        time.sleep(0.3)
        before = [lk.read(0x6064, 0, "i") for lk in group.links]
        time.sleep(0.2)
        after = [lk.read(0x6064, 0, "i") for lk in group.links]
        assert before == after
        ends = [int(a.records[-1, 0]) for a in prog.axes]
        assert all(b != e for b, e, s in zip(before, ends, here, strict=True) if e != s)
        for link in group.links:
            assert link.read_statusword() & 0x6F != 0x27, hex(link.statusword)  # not operation enabled
    finally:
        group.close()
        bus.close()
    assert drives.poll() is None
