"""Master and simulated drives in two processes on the simulated wire: ``pvtflow sim`` serves the
cell's drives and its wire on loopback, the master in this process opens that channel."""

from __future__ import annotations

import contextlib
import dataclasses
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from axes_programs import check_limits, program

from axes.bus import CellBus
from axes.group import AxisGroup, Result
from axes.objects import SYNC_COB_ID
from axes.subscriptions import subscribe, unsubscribe
from service.config import CellConfig, load_cell_config
from service.sim_cmd import WIRE_SERVED_AT

REPO = Path(__file__).resolve().parents[2]
ARM6 = REPO / "configs" / "cells" / "arm6.yaml"


@dataclasses.dataclass
class Served:
    cell: CellConfig  # the cell as the master sees it: simulated: false, the served channel
    process: subprocess.Popen[str]


def serve_drives(clock: str, config: Path = ARM6) -> Iterator[Served]:
    cell = load_cell_config(config)
    channel = f"procs-{uuid.uuid4().hex[:8]}"
    args = [sys.executable, "-m", "service.cli", "sim", "--config", str(config), "--channel", channel]
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
    bus = CellBus(cell.bus, lockstep=clock == "lockstep").open()
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


def linear_ip_arm6(folder: Path, period_ms: int) -> Path:
    """arm6 on CiA 402 linear-IP drives at ``period_ms`` (a cell file ``pvtflow sim`` reads)."""
    data = yaml.safe_load(ARM6.read_text())
    data["robot"]["urdf"] = str((ARM6.parent / data["robot"]["urdf"]).resolve())
    data["bus"]["sync_period_ms"] = float(period_ms)
    for axis in data["axes"]:
        axis.update(profile="cia402_ip_linear", period_ms=period_ms)
    path = folder / "arm6-ip-linear.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("held_syncs", "halts"), [(1, False), (4, True)], ids=["ridden_out", "too_long"])
def test_a_follower_held_mid_motion_costs_a_period_or_halts_with_no_setpoint(
    tmp_path: Path, held_syncs: int, halts: bool
) -> None:
    """The wire sends SYNC by itself (simwire's cyclic send, as SocketCAN's BCM does) and the linear-IP
    drives, in their own process, keep their own clock. The master's follower, woken by a SYNC at the
    motion's fastest, is held until the bus has carried one more SYNC: that SYNC goes out without a
    setpoint, the drives hold one period and go on with the next record at the planned speed (a jump
    over the missed record would ask for twice it), and the motion finishes where it was going, a
    period late. Held over four SYNCs, past the 2 periods the drives ride out: halted, reported as such.
    The hold is counted in SYNCs heard on the bus, not in slept milliseconds, so that a slow host
    cannot turn one case into the other."""
    with contextlib.contextmanager(serve_drives)("wall", linear_ip_arm6(tmp_path, 10)) as served:
        run_with_a_held_follower(served, held_syncs, halts)
        assert served.process.poll() is None  # the drives' process is still up: nothing it did crashed it


def run_with_a_held_follower(served: Served, held_syncs: int, halts: bool) -> None:
    cell = served.cell
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, max_sync_gap_periods=2))
    bus = CellBus(cell.bus, lockstep=False).open()
    axes = cell.ordered_axes()[:3]  # three axes: what the wire's loopback server carries on the wall clock
    group = AxisGroup(bus, axes)
    events: list[object] = []
    group.on_event = events.append
    held: list[int] = []
    on_bus = threading.Condition()
    heard = [0]

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        with on_bus:
            heard[0] += 1
            on_bus.notify_all()

    def hold() -> None:  # the follower, woken by a SYNC at the motion's fastest, held before it follows
        start = group._start_sync
        if start is not None and bus.sync.count >= start + 50 and not held:
            held.append(bus.sync.count)
            with on_bus:
                until = heard[0] + held_syncs
                assert on_bus.wait_for(lambda: heard[0] >= until, 5.0)

    subscribe(bus.network, SYNC_COB_ID, on_sync)
    try:
        group.refresh()
        here = [lk.position for lk in group.links]
        prog = program(axes, 1000, starts=here, fraction=0.6)
        check_limits(prog)
        bus.sync.hold = hold
        assert group.start(prog) is None
        result = group.wait(timeout_s=60)
        assert bus.sync.native and held, result.message
        assert bus.sync.skipped >= held_syncs
        if halts:
            assert result.result is Result.BUS_ERROR, result.message
            assert "no setpoint for 30.0 ms" in result.message, result.message
            assert any(getattr(e, "kind", None) is not None and e.kind.value == "sync_gap" for e in events)
        else:
            assert result.ok, result.message
            group.refresh()
            assert [lk.position for lk in group.links] == [int(a.records[-1, 0]) for a in prog.axes]
    finally:
        unsubscribe(bus.network, SYNC_COB_ID, on_sync)
        group.close()
        bus.close()
