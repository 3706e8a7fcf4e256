"""The cyclic path in a process of its own (``bus.cyclic_process``) on the wall clock: the drives and the
simulated wire in theirs (``axes.sim.process``), the cyclic process a second client of that wire, the
master here. Gentle moves (these are behaviour tests, not timing claims: bench/fullspeed.py measures)."""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import pytest
import yaml
from axes_programs import axis_program, safe_distance

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import DRIVES_PRIORITY, ask_drives_priority
from pvtflow.axes.drive.config import BusConfig
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.bus.faults import BusError
from pvtflow.axes.master.group.axis_group import AxisGroup, Result
from pvtflow.axes.sim.process import DRIVES_NICE, DrivesProcess, start_simulated_drives
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config


def cyclic_cell(name: str, directory: Path) -> CellConfig:
    """A copy of the shipped cell with ``bus.cyclic_process``, homing left out (the machine at its encoder's 0)."""
    source = CONFIG_DIR / "cells" / f"{name}.yaml"
    data = yaml.safe_load(source.read_text())
    for axis in data["axes"]:
        axis.pop("homing", None)
        if "simulation" in axis:  # not homed: the machine stands where its encoder counts 0
            axis["simulation"]["power_up_qc"] = 0
    data.pop("homing_order", None)
    data.pop("requires_homing", None)
    data["bus"]["cyclic_process"] = True
    # a 10 ms SYNC: a behaviour test on a host shared with the suite's other work (the cell's own period
    # is measured by bench/fullspeed.py)
    data["bus"]["sync_period_ms"] = 10
    for axis in data["axes"]:
        if "period_ms" in axis:
            axis["period_ms"] = 10
    robot = data.get("robot", {})
    if "urdf" in robot:
        robot["urdf"] = str((source.parent / robot["urdf"]).resolve())
    copy = directory / f"{name}.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_cell_config(copy)


def can_ask_fifo() -> bool:
    """Whether this host grants SCHED_FIFO at the drives' priority (asked by a thread that then ends)."""
    granted: list[bool] = []
    thread = threading.Thread(target=lambda: granted.append(ask_drives_priority()))
    thread.start()
    thread.join()
    return granted[0]


def inward(cell: CellConfig, starts: list[int | None], duration_ms: int, back: bool = False) -> PvtProgram:
    """Every axis from where it stands into its 0x607D range (its range's middle side), or ``back``."""
    axes = cell.ordered_axes()
    out = []
    for axis, start in zip(axes, starts, strict=True):
        middle = (axis.limits.min_position_qc + axis.limits.max_position_qc) / 2
        sign = (1 if middle > 0 else -1) * (-1 if back else 1)
        out.append(axis_program(axis, int(start or 0), sign * safe_distance(axis, duration_ms), duration_ms))
    return PvtProgram(cell.name, tuple(out))


@pytest.mark.wall
def test_a_cell_runs_to_its_end_with_sync_from_the_cyclic_process_and_a_stop_halts_it(tmp_path: Path) -> None:
    cell = cyclic_cell("gantry3", tmp_path)  # EPOS2s: their FIFO rides out what the host does to SYNC
    drives = start_simulated_drives(cell, "wall")
    bus = CellBus(drives.bus, clock=Clock.WALL).open()
    group = AxisGroup(bus, cell.ordered_axes())
    try:
        assert bus.sync.cyclic is not None and bus.sync.cyclic.process.is_alive()
        # the drives stand in for hardware: no thread of normal priority delays them where the host permits
        assert isinstance(drives, DrivesProcess) and drives.process is not None
        pid = drives.process.pid
        if can_ask_fifo():
            assert os.sched_getscheduler(pid) == os.SCHED_FIFO
            assert os.sched_getparam(pid).sched_priority == DRIVES_PRIORITY
        else:
            assert os.getpriority(os.PRIO_PROCESS, pid) == DRIVES_NICE
        group.refresh()
        here = [lk.position for lk in group.links]
        prog = inward(cell, here, 400)

        result = group.run(prog, timeout_s=60)
        assert result.result is Result.FINISHED, result.message
        assert [lk.position for lk in group.links] == [int(a.records[-1, 0]) for a in prog.axes]
        # the run's SYNCs came from the cyclic process: it counted them, this process heard them
        cyclic = bus.sync.cyclic
        assert cyclic.syncs_sent >= result.end_sync
        # the next move, stopped on its way: the halt reaches the cyclic process's feeders too
        here = [lk.position for lk in group.links]
        prog = inward(cell, here, 1500)
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
            assert link.position not in (start, end), (link.joint, link.position)  # halted on its way
    finally:
        group.close()
        bus.close()
        drives.stop()
    assert not bus.sync.cyclic


@pytest.mark.wall
def test_the_cyclic_process_quick_stops_every_drive_when_the_master_is_gone(tmp_path: Path) -> None:
    cell = cyclic_cell("gantry3", tmp_path)
    drives = start_simulated_drives(cell, "wall")
    bus = CellBus(drives.bus, clock=Clock.WALL).open()
    group = AxisGroup(bus, cell.ordered_axes())
    try:
        group.refresh()
        here = [lk.position for lk in group.links]
        assert group.start(inward(cell, here, 3000)) is None
        deadline = time.monotonic() + 60
        while (group.elapsed_syncs() or 0) * cell.bus.sync_period_ms < 300:
            assert time.monotonic() < deadline and group.running
            time.sleep(0.005)
        cyclic = bus.sync.cyclic
        assert cyclic is not None
        told = []
        bus.report = told.append  # this process stays silent from here: whatever stops the drives is the child
        gone = time.monotonic()
        # as if this process died: its end of the pipe (a socket pair) closes, for every thread at once
        with socket.socket(fileno=os.dup(cyclic._conn.fileno())) as end:
            end.shutdown(socket.SHUT_RDWR)
        # every drive is quick stopped by the cyclic process (SDO, or NMT stop for one that does not
        # confirm within 10 ms), though this process's heartbeat goes on: QUICK STOP ACTIVE, or through
        # it to SWITCH ON DISABLED, long before the drives' watch of the master's heartbeat could have
        # stopped them (withheld 0.4 s after the last SYNC, axes.master.bus.heartbeat, then 0.3 s of their 0x1016)
        time.sleep(0.2)
        words = {link.node_id: link.read_statusword() for link in group.links}
        assert time.monotonic() - gone < 0.6
        stopped = {n: w for n, w in words.items() if (w & 0x6F) == 0x07 or (w & 0x4F) == 0x40}
        assert sorted(stopped) == sorted(lk.node_id for lk in group.links), {n: hex(w) for n, w in words.items()}
        group.stop("test end")
        group.wait(timeout_s=30)
    finally:
        group.close()
        bus.close()
        drives.stop()


@pytest.mark.wall
def test_a_bus_only_this_process_reaches_is_refused_for_the_cyclic_process() -> None:
    config = BusConfig(interface="virtual", channel=f"cyc-{time.monotonic_ns()}", cyclic_process=True)
    with pytest.raises(BusError, match=r"bus\.cyclic_process needs an interface another process can open"):
        CellBus(config, clock=Clock.WALL).open()
    CellBus(config, clock=Clock.LOCKSTEP).open().close()  # lockstep never uses it
