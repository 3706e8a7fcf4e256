"""Master and simulated drives in two processes on the simulated wire: ``pvtflow sim`` serves the
cell's drives and its wire on loopback, the master in this process opens that channel."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from axes_programs import check_limits, program

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup, Result
from pvtflow.service.config import CellConfig, load_cell_config
from pvtflow.service.sim_cmd import WIRE_SERVED_AT

REPO = Path(__file__).resolve().parents[2]
ARM6 = REPO / "configs" / "cells" / "arm6.yaml"


@dataclasses.dataclass
class Served:
    cell: CellConfig  # the cell as the master sees it: simulated: false, the served channel
    process: subprocess.Popen[str]


def serve_drives(clock: str) -> Iterator[Served]:
    cell = load_cell_config(ARM6)
    channel = f"procs-{uuid.uuid4().hex[:8]}"
    args = [sys.executable, "-m", "pvtflow.service.cli", "sim", "--config", str(ARM6), "--channel", channel]
    if clock == "wall":
        args.append("--wall-clock")
    process = subprocess.Popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        address = None
        deadline = time.monotonic() + 60.0
        assert process.stdout is not None
        while address is None and time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            if WIRE_SERVED_AT in line:
                address = line.split(WIRE_SERVED_AT, 1)[1].split()[0]
        assert address is not None, (
            f"pvtflow sim did not serve its wire: {process.stderr.read() if process.stderr else ''}"
        )
        bus = dataclasses.replace(cell.bus, channel=address)
        yield Served(dataclasses.replace(cell, bus=bus, simulated=False), process)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            process.kill()


@pytest.fixture(params=["lockstep", "wall"])
def served(request: pytest.FixtureRequest) -> Iterator[Served]:
    yield from serve_drives(request.param)


@pytest.fixture
def clock(served: Served, request: pytest.FixtureRequest) -> str:
    return request.node.callspec.params["served"]


def test_a_move_finishes_and_the_next_is_stopped_with_the_drives_in_another_process(served: Served, clock: str) -> None:
    cell = served.cell
    bus = CellBus(cell.bus, clock=Clock(clock)).open()
    # two of the six axes move: the wire's loopback server carries a few thousand frames/s (Python),
    # what six axes at full rate on the wall clock need; in lockstep all six
    axes = cell.ordered_axes() if clock == "lockstep" else cell.ordered_axes()[:2]
    group = AxisGroup(bus, axes)
    try:
        group.refresh()
        here = [lk.position for lk in group.links]
        prog = program(axes, 300, starts=here, spacing_ms=20)
        check_limits(prog)
        result = group.run(prog, timeout_s=60)
        assert result.ok, result.message
        assert [lk.position for lk in group.links] == [int(a.records[-1, 0]) for a in prog.axes]
        # the next move, stopped on its way: every axis halts and the run says so
        here = [lk.position for lk in group.links]
        prog = program(axes, 2000, starts=here, spacing_ms=20, sign=-1)
        assert group.start(prog) is None
        deadline = time.monotonic() + 60
        while group.running and (group.elapsed_syncs() or 0) * cell.bus.sync_period_ms < 300:
            assert time.monotonic() < deadline
            time.sleep(0.005)
        group.stop("test stop")
        stopped = group.wait(timeout_s=60)
        assert stopped.result is Result.STOPPED, stopped.message
        for link, start, axis in zip(group.links, here, prog.axes, strict=True):
            end = int(axis.records[-1, 0])
            if end != start:  # halted on its way, short of its end
                assert link.position != start and link.position != end
    finally:
        group.close()
        bus.close()
    assert served.process.poll() is None  # the drives' process is still up: nothing it did crashed it
