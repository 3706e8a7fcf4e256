"""A wall-clock transmit FIFO judged in bus time, and a remote simwire bus's frames sent together
(``SimWireBus.coalesced``: one loopback write for a run of frames, as the SYNC thread sends SYNC,
time stamp and setpoints): each frame still counted in its transmit FIFO, refused when it is full,
and on the wire only once the run is written."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from can import BusState

from pvtflow.axes.canbus.frame_time import frame_bits
from pvtflow.axes.master.bus.network import LoggingNetwork
from pvtflow.axes.sim.wire import ERROR_PASSIVE, Medium, SimWireBus

from .wire_child import wire_in_a_child

REPO = Path(__file__).resolve().parents[3]
BITRATE = 125_000  # a frame about 1 ms: ten of them outrun the wire


@pytest.fixture
def served() -> Iterator[tuple[str, subprocess.Popen]]:
    """A wall-clock simwire server in a child process; its channel string and the process."""
    with wire_in_a_child("wall", BITRATE, 0.001) as served:
        yield served


@pytest.fixture
def address(served: tuple[str, subprocess.Popen]) -> str:
    return served[0]


@pytest.fixture
def pair(address: str) -> Iterator[tuple[SimWireBus, SimWireBus]]:
    master = SimWireBus(address, node_name=f"master-{uuid.uuid4().hex[:6]}")
    drive = SimWireBus(address, node_name="drive")
    yield master, drive
    master.shutdown()
    drive.shutdown()


def frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x200 + i, data=bytes([i] * 8), is_extended_id=False)


def test_frames_sent_together_count_in_the_fifo_and_reach_the_wire_when_the_run_is_written(
    pair: tuple[SimWireBus, SimWireBus],
) -> None:
    master, drive = pair
    with master.coalesced():
        for i in range(10):
            master.send(frame(i))
        with pytest.raises(can.CanOperationError) as raised:
            master.send(frame(10))  # the ten held frames fill the FIFO: the eleventh is refused
        assert raised.value.error_code == errno.ENOBUFS
        assert drive.recv(0.05) is None  # held: not one is on the wire yet
    got = [drive.recv(5.0) for _ in range(10)]
    assert [m.arbitration_id for m in got if m is not None] == [0x200 + i for i in range(10)]
    stats = master.medium.stats()
    assert stats.enobufs[master.node_name] == 1 and stats.frames == 10


def test_a_sender_waiting_for_room_inside_a_run_writes_the_held_frames_first(
    pair: tuple[SimWireBus, SimWireBus],
) -> None:
    master, drive = pair
    with master.coalesced():
        for i in range(10):
            master.send(frame(i))
        master.send(frame(10), timeout=2.0)  # room comes only once the held frames are on the wire
    got = [drive.recv(5.0) for _ in range(11)]
    assert [m.arbitration_id for m in got if m is not None] == [0x200 + i for i in range(11)]


def test_a_network_sends_together_where_the_interface_can_and_frame_by_frame_elsewhere(
    pair: tuple[SimWireBus, SimWireBus],
) -> None:
    master, drive = pair
    network = LoggingNetwork(master)
    with network.together():
        network.send_message(0x80, b"")
        network.send_message(0x100, bytes(4))
        assert drive.recv(0.05) is None
    assert [drive.recv(5.0).arbitration_id for _ in range(2)] == [0x80, 0x100]
    channel = f"v-{uuid.uuid4().hex[:8]}"
    virtual = can.Bus(interface="virtual", channel=channel)
    heard = can.Bus(interface="virtual", channel=channel)
    try:
        plain = LoggingNetwork(virtual)
        with plain.together():
            plain.send_message(0x80, b"")
            assert heard.recv(1.0).arbitration_id == 0x80  # virtual: each frame as it is sent
    finally:
        virtual.shutdown()
        heard.shutdown()


@pytest.mark.wall
def test_a_wall_fifo_is_judged_in_bus_time_when_the_driver_is_late() -> None:
    """Frames whose last bit has left by a send's bus time are out of the sender's FIFO, though no
    driver thread woke to retire them (a held simulation process): the send finds room, and the
    frames it retired reach the other nodes stamped with their own ends."""
    medium = Medium("late-driver", bitrate=100_000, clock="wall")  # no driver: nothing retires on its own
    got: list[can.Message] = []
    sender = medium.attach(lambda m: None, name="sender")
    medium.attach(got.append, name="receiver")
    t0 = 1000.0
    for i in range(10):
        medium.submit(sender, frame(i), now=t0)
    medium.step(t0)  # the first frame goes on the wire at t0
    with pytest.raises(can.CanOperationError) as raised:
        medium.submit(sender, frame(10), now=t0)  # full at t0: nothing has left yet
    assert raised.value.error_code == errno.ENOBUFS
    first, second = (frame_bits(0x200 + i, bytes([i] * 8)) / 100_000 for i in range(2))
    medium.submit(sender, frame(10), now=t0 + first + second + first / 2)  # two frames have left by then
    assert [m.arbitration_id for m in got] == [0x200, 0x201]
    assert [m.timestamp for m in got] == pytest.approx([t0 + first, t0 + first + second], abs=1e-9)
    assert len(sender.fifo) == 9


def held(child: subprocess.Popen) -> None:
    """SIGSTOP the server and wait until the kernel has stopped it."""
    os.kill(child.pid, signal.SIGSTOP)
    deadline = time.monotonic() + 5.0
    while Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "T":
        assert time.monotonic() < deadline, "the server did not stop"
        time.sleep(0.001)


def test_a_frame_posted_waits_for_no_other_threads_request(served: tuple[str, subprocess.Popen]) -> None:
    """A request to the server (the accounting, a test hook) waits for its reply on the control
    connection; a SYNC posted meanwhile goes out without waiting for it (here: a server held until
    the post is done)."""
    address, child = served
    master = SimWireBus(address, node_name="master")
    try:
        held(child)
        asked = threading.Thread(target=master.medium.stats, daemon=True)
        asked.start()
        asked.join(0.2)
        assert asked.is_alive()  # its reply cannot come: the server is held
        posted = threading.Thread(target=master.send, args=(frame(0),), daemon=True)
        posted.start()
        posted.join(2.0)
        assert not posted.is_alive()
        os.kill(child.pid, signal.SIGCONT)
        asked.join(5.0)
        assert not asked.is_alive()
    finally:
        os.kill(child.pid, signal.SIGCONT)
        master.shutdown()


def test_a_remote_bus_knows_its_state_from_the_error_frames_without_asking_the_server(
    served: tuple[str, subprocess.Popen],
) -> None:
    """``bus.state`` as a socketcan user knows it (the controller error frames received): no round
    trip, so the bus watch polling it costs the server nothing; exact right after ``set_state``."""
    address, child = served
    master = SimWireBus(address, node_name="master")
    try:
        master.medium.set_state("master", ERROR_PASSIVE)
        assert master.state == ERROR_PASSIVE
        held(child)  # no answer could come now
        assert master.state == ERROR_PASSIVE
        os.kill(child.pid, signal.SIGCONT)
        master.medium.set_state("master", BusState.ACTIVE)
        assert master.state == BusState.ACTIVE
    finally:
        os.kill(child.pid, signal.SIGCONT)
        master.shutdown()


def test_an_acceptance_filter_keeps_frames_from_a_node_not_from_the_wire() -> None:
    """``accept_only``: the filtered node's queue gets only what it accepts; the refused frames still
    take their bits on the wire (the next frame's end is the same for a node without the filter)."""
    channel = f"filter-{uuid.uuid4().hex[:8]}"
    sender = SimWireBus(channel, clock="lockstep", sync_period=0.001, bitrate=125_000)
    drive = SimWireBus(channel)
    monitor = SimWireBus(channel)
    try:
        assert drive.accept_only(lambda can_id: can_id in (0x80, 0x20B))
        for can_id in (0x80, 0x20C, 0x20D, 0x20B):
            data = b"" if can_id == 0x80 else bytes(8)
            sender.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        got = [drive.recv(1.0) for _ in range(2)]
        assert [m.arbitration_id for m in got] == [0x80, 0x20B]
        assert drive.recv(0.05) is None
        heard = [monitor.recv(1.0) for _ in range(4)]
        assert got[1].timestamp == heard[3].timestamp  # 0x20B ends after the two frames the drive refused
    finally:
        for bus in (sender, drive, monitor):
            bus.shutdown()
