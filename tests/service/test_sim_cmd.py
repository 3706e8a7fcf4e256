"""``pvtflow sim``: a cell's simulated drives on their own, driven by a master of someone else's.

The command runs in this process's main thread (it owns the SIGINT/SIGTERM handlers) on a virtual
channel of its own; a thread plays the other tool: it waits for the boot-up frames, takes one drive
through python-canopen's ``BaseNode402`` into interpolated position mode, makes another fault, and
stops the command with a signal, as Ctrl-C would."""

from __future__ import annotations

import argparse
import os
import signal
import threading
import uuid
from pathlib import Path
from typing import Any

import canopen
import pytest
import yaml
from canopen.profiles.p402 import BaseNode402
from frame_log import FrameLog

from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim.drive import EDS_DIR
from pvtflow.axes.sim.node.device import SUPPORTED_DRIVE_MODES, SYNC_SETPOINT_MODES
from pvtflow.service import sim_cmd
from pvtflow.service.cli import main

CELLS = Path(__file__).resolve().parents[2] / "configs" / "cells"
MIXED = CELLS / "gantry3-mixed.yaml"  # x: EPOS2 node 11, y: linear IP node 12, z: bufferless node 13
NODES = (11, 12, 13)


def other_tool(channel: str, log: FrameLog, master: canopen.Network, done: threading.Event) -> dict[str, Any]:
    """What a foreign master sees and does; always ends by signalling the command, once it is up."""
    seen: dict[str, Any] = {}
    booted = all(log.wait_for(0x700 + n, 1, timeout=30.0, where=lambda m: m.data[0] == 0) for n in NODES)
    seen["booted"] = booted
    try:
        if not booted:
            return seen
        node = BaseNode402(11, str(EDS_DIR / "epos2.eds"))
        master.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        node.nmt.state = "PRE-OPERATIONAL"
        node.setup_402_state_machine()
        node.nmt.state = "OPERATIONAL"
        node.op_mode = "INTERPOLATED POSITION"
        node.state = "OPERATION ENABLED"
        seen["mode"], seen["state"] = node.op_mode, node.state
        z = master.add_node(13, str(EDS_DIR / "sync_setpoint.eds"))
        z.sdo.RESPONSE_TIMEOUT = 2.0
        seen["z_modes"] = z.sdo[SUPPORTED_DRIVE_MODES].raw
        # the EPOS2 started with an empty buffer: underflow at the SYNC, EMCY and fault
        node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
        node.controlword = 0x001F
        master.send_message(0x80, b"")
        emcy = log.wait_for(0x8B, 1, timeout=5.0)
        seen["emcy"] = int.from_bytes(emcy[0].data[:2], "little") if emcy else None
        seen["state_after"] = node.sdo[od.STATUSWORD].raw & 0x4F
    except Exception as exc:  # reported by the test, never left to hang the command
        seen["error"] = repr(exc)
    finally:
        if not done.is_set():
            os.kill(os.getpid(), signal.SIGTERM)
    return seen


def test_pvtflow_sim_serves_the_cells_drives_to_another_master_until_sigterm(capsys: pytest.CaptureFixture) -> None:
    channel = f"pvtflow-simcmd-{uuid.uuid4().hex[:10]}"
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.02
    log = FrameLog()
    master.listeners.append(log)
    master.connect(interface="virtual", channel=channel)
    done = threading.Event()
    seen: dict[str, Any] = {}
    tool = threading.Thread(target=lambda: seen.update(other_tool(channel, log, master, done)), daemon=True)
    tool.start()
    try:
        code = main(["sim", "--config", str(MIXED), "--interface", "virtual", "--channel", channel])
    finally:
        done.set()
        tool.join(10.0)
        master.disconnect()
    out = capsys.readouterr().out
    assert seen.get("booted") and "error" not in seen, seen
    assert seen["mode"] == "INTERPOLATED POSITION" and seen["state"] == "OPERATION ENABLED"
    assert seen["z_modes"] == SYNC_SETPOINT_MODES.supported
    assert seen["emcy"] == od.EMCY_EPOS2_IPM_ERROR and seen["state_after"] == 0x08  # FAULT
    assert code == sim_cmd.EXIT_OK
    assert f"cell gantry3-mixed: 3 simulated drives on virtual:{channel}" in out
    for node_id, profile, eds in ((11, "epos2_pvt", "epos2.eds"), (12, "cia402_ip_linear", "cia402_ip_linear.eds")):
        line = next(x for x in out.splitlines() if x.strip().startswith(f"node  {node_id}"))
        assert profile in line and line.endswith(str(EDS_DIR / eds))
    assert "node 11 (x): fault, EMCY 0xFF0C: buffer underflow" in out
    assert out.rstrip().endswith("pvtflow sim: stopping")


def write_cell(tmp_path: Path, **bus: Any) -> Path:
    """gantry3-mixed with another bus (and whatever top-level fields are given)."""
    data = yaml.safe_load(MIXED.read_text())
    data["robot"]["urdf"] = str((CELLS / data["robot"]["urdf"]).resolve())
    simulated = bus.pop("simulated", None)
    data["bus"].update(bus)
    if simulated is not None:
        data["simulated"] = simulated
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run_sim(config: Path | None, interface: str | None = None, channel: str | None = None) -> int:
    return sim_cmd.run(argparse.Namespace(config=config and str(config), interface=interface, channel=channel))


def test_udp_multicast_is_refused_from_the_flags_and_from_the_cell(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    assert run_sim(MIXED, interface="udp_multicast", channel="239.74.163.2") == sim_cmd.EXIT_CANNOT_START
    assert "udp_multicast is refused" in capsys.readouterr().err
    cell = write_cell(tmp_path, interface="udp_multicast", channel="239.74.163.2", simulated=True)
    assert run_sim(cell) == sim_cmd.EXIT_CANNOT_START  # the cell file itself: simulated drives on a real bus
    assert "simulated drives on interface udp_multicast" in capsys.readouterr().err


def test_a_cell_of_real_drives_needs_the_bus_named(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Simulated drives must not join a bus where the cell's real drives answer to the same ids."""
    cell = write_cell(tmp_path, interface="socketcan", channel="can0")
    assert run_sim(cell) == sim_cmd.EXIT_CANNOT_START
    err = capsys.readouterr().err
    assert "real drives on socketcan:can0" in err and "--interface" in err
    config = sim_cmd.load_cell_config(cell)
    assert sim_cmd.choose_bus(config, "socketcan", "vcan0") == ("socketcan", "vcan0")
    assert sim_cmd.choose_bus(config, "virtual", "x") == ("virtual", "x")
    with pytest.raises(sim_cmd.SimError, match="unknown python-can interface"):
        sim_cmd.choose_bus(config, "nope", None)
