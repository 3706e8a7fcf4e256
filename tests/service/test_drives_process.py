"""The simulated drives of a user-facing command run in a process of their own (axes.sim.process),
and no way out of the master leaves that process behind: a normal end, an error, Ctrl-C, SIGTERM,
or the master killed outright."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from axes_programs import program

from pvtflow.axes.sim.process import DrivesProcess
from pvtflow.service.config import load_cell_config

REPO = Path(__file__).resolve().parents[2]
ARM6 = REPO / "configs" / "cells" / "arm6.yaml"


def alive(pid: int) -> bool:
    """The process exists and is not a zombie waiting for its parent."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def children(pid: int) -> list[int]:
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(c) for c in (task / "children").read_text().split()]
        except FileNotFoundError:
            continue
    return found


def wait_for(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return condition()


def test_the_drives_process_serves_the_wire_and_is_reaped_on_an_error() -> None:
    cell = load_cell_config(ARM6)
    with pytest.raises(RuntimeError, match="the master failed"), DrivesProcess(cell, "lockstep") as drives:
        pid = drives.process.pid
        assert drives.bus.channel.startswith(f"{cell.bus.channel}@127.0.0.1:")
        raise RuntimeError("the master failed")
    assert not alive(pid)


@pytest.fixture
def long_program(tmp_path: Path) -> Path:
    cell = load_cell_config(ARM6)
    path = tmp_path / "program.json"
    path.write_text(program(cell.ordered_axes(), 20_000, spacing_ms=10, cell=cell.name).dumps())
    return path


def start_execute(program_path: Path) -> tuple[subprocess.Popen[str], int]:
    """``pvtflow execute`` (lockstep), its motion under way; (the master, its drives' pid)."""
    master = subprocess.Popen(
        [sys.executable, "-m", "pvtflow.service.cli", "execute", str(program_path), "--config", str(ARM6)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert master.stdout is not None
    said = []
    for line in master.stdout:  # the motion runs
        said.append(line)
        if line.startswith("started"):
            break
    drives = children(master.pid)
    assert len(drives) == 1, f"the master's children: {drives}; it said {said}"
    return master, drives[0]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_master_halts_and_reaps_its_drives(long_program: Path, signum: int) -> None:
    master, drives = start_execute(long_program)
    try:
        master.send_signal(signum)
        _, err = master.communicate(timeout=30)
        assert master.returncode != 0
        assert not alive(drives), "the master ended and left its drives' process running"
        assert "Traceback" not in err, err
    finally:
        master.kill()
        master.wait()


def test_the_drives_go_when_the_master_is_killed(long_program: Path) -> None:
    master, drives = start_execute(long_program)
    master.kill()
    master.wait()
    assert wait_for(lambda: not alive(drives), 10.0), "the drives' process outlived its killed master"
