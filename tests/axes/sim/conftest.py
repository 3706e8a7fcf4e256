"""A plain master for the drive-side tests: a canopen Network with RemoteNodes and raw frames on a
python-can virtual channel of its own (one per test), plus the simulated drive's own network."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from frame_log import FrameLog

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.objects import PdoLayout
from pvtflow.axes.sim.drive import EDS_DIR, SimulatedDrive


class Bench:
    """The simulated drives' network and a master network on one fresh virtual channel."""

    def __init__(self) -> None:
        self.channel = f"pvtflow-sim-{uuid.uuid4().hex[:12]}"
        self.sim = canopen.Network()
        self.sim.NOTIFIER_CYCLE = 0.02  # quick shutdown: the notifier thread wakes this often
        self.sim.connect(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.master = canopen.Network()
        self.master.NOTIFIER_CYCLE = 0.02
        self.log = FrameLog()
        self.master.listeners.append(self.log)
        self.master.connect(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.drives: list[SimulatedDrive] = []
        self.syncs = 0

    def add(self, drive: SimulatedDrive) -> SimulatedDrive:
        drive.attach(self.sim)
        drive.boot()
        self.drives.append(drive)
        return drive

    def remote(self, drive: SimulatedDrive, eds: str | Path | None = None) -> canopen.RemoteNode:
        node = self.master.add_node(drive.node_id, str(eds or drive.eds_path))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        return node

    def sync(self, n: int = 1, wait: bool = True) -> int:
        """Send n SYNC frames; by default wait until every drive processed them. Returns the SYNC count."""
        for _ in range(n):
            self.master.send_message(0x80, b"")
        self.syncs += n
        if wait:
            for d in self.drives:
                assert d.wait_sync(self.syncs, 10.0), f"node {d.node_id} did not process SYNC {self.syncs}"
        return self.syncs

    def send(self, can_id: int, data: bytes) -> None:
        self.master.send_message(can_id, data)

    def close(self) -> None:
        for d in self.drives:
            d.detach()
        self.master.disconnect()
        self.sim.disconnect()


@pytest.fixture
def bench() -> Iterator[Bench]:
    b = Bench()
    try:
        yield b
    finally:
        errors = [e for d in b.drives for e in d.internal_errors]
        b.close()
    assert not errors, f"simulated drive raised internally: {errors!r}"


def enable(node: canopen.RemoteNode, mode: int = od.INTERPOLATED_POSITION_MODE) -> None:
    """Mode, then shutdown / switch on / enable operation over SDO."""
    node.sdo[od.MODES_OF_OPERATION].raw = mode
    for cw in (0x0006, 0x0007, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw


def configure_pdos(node: canopen.RemoteNode, rpdos: tuple[PdoLayout, ...], tpdos: tuple[PdoLayout, ...]) -> None:
    """The CiA 301 way, with python-canopen's master API: read, remap, save (disable, map, enable)."""
    for layouts, maps, receive in ((rpdos, node.rpdo, True), (tpdos, node.tpdo, False)):
        maps.read()
        for layout in layouts:
            m = maps[layout.number]
            m.clear()
            for index, subindex, bits in layout.entries:
                m.add_variable(index, subindex, bits)
            m.trans_type = layout.transmission_type
            m.cob_id = layout.cob_id(node.id, receive)
            m.enabled = True
            m.save()


__all__ = ["EDS_DIR", "Bench", "FrameLog", "configure_pdos", "enable"]
