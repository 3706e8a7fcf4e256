"""The simulated wire (``axes.sim.wire``): bit timing, arbitration, the bounded transmit FIFO,
late SYNCs, bus states, the loopback server, and python-canopen over it, on both clocks."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import time
import tomllib
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from can import BusState

from pvtflow.axes.canbus.frame_time import frame_bits
from pvtflow.axes.sim.wire import BUS_OFF, ERROR_PASSIVE, Medium, SimWireBus, WireConfigError
from pvtflow.axes.sim.wire.bus_states import CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_PROT

from .wire_child import wire_in_a_child

REPO = Path(__file__).resolve().parents[3]
SYNC = 0x80
PERIOD = 0.001
SERVED_BITRATE = 125_000  # a frame about 1 ms: a remote burst outruns the wire


def frame(can_id: int, data: bytes = b"", *, extended: bool = False, remote: bool = False) -> can.Message:
    return can.Message(
        arbitration_id=can_id, data=data, is_extended_id=extended, is_remote_frame=remote, dlc=len(data) or None
    )


def seconds(msg: can.Message, bitrate: int) -> float:
    return frame_bits(msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id) / bitrate


class Buses:
    """Buses opened on fresh channels, shut down after the test."""

    def __init__(self) -> None:
        self.opened: list[can.BusABC] = []

    def channel(self) -> str:
        return f"wire-{uuid.uuid4().hex[:10]}"

    def open(self, channel: str, **kwargs: object) -> SimWireBus:
        bus = SimWireBus(channel, **kwargs)
        self.opened.append(bus)
        return bus

    def close(self) -> None:
        for bus in reversed(self.opened):
            bus.shutdown()


@pytest.fixture
def buses() -> Iterator[Buses]:
    b = Buses()
    yield b
    b.close()


def drain(bus: can.BusABC, count: int, timeout: float = 5.0) -> list[can.Message]:
    out = []
    for _ in range(count):
        msg = bus.recv(timeout)
        assert msg is not None, f"only {len(out)} of {count} frames arrived"
        out.append(msg)
    return out


# -- bit timing ------------------------------------------------------------------------------------


def test_lockstep_back_to_back_frames_are_stamped_with_their_exact_end(buses: Buses) -> None:
    ch = buses.channel()
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD, bitrate=500_000)
    drive = buses.open(ch)
    first, second = frame(SYNC), frame(0x201, bytes(range(8)))
    master.send(first)
    master.send(second)
    got = drain(drive, 2)
    assert got[0].timestamp == pytest.approx(seconds(first, 500_000), abs=1e-12)
    assert got[1].timestamp == pytest.approx(got[0].timestamp + seconds(second, 500_000), abs=1e-12)
    assert [m.is_rx for m in got] == [True, True]
    assert master.recv(0) is None  # no echo without receive_own_messages


def test_wall_back_to_back_frames_arrive_in_order_a_frame_apart(buses: Buses) -> None:
    ch = buses.channel()
    a = buses.open(ch, bitrate=20_000)
    b = buses.open(ch)
    msgs = [frame(0x181 + i, bytes([i] * 8)) for i in range(3)]
    for m in msgs:
        a.send(m)
    got = drain(b, 3)
    assert [m.arbitration_id for m in got] == [0x181, 0x182, 0x183]
    for prev, cur, sent in zip(got, got[1:], msgs[1:], strict=False):
        assert cur.timestamp - prev.timestamp >= seconds(sent, 20_000) - 1e-6  # epoch floats: 0.24 us steps


def test_own_frames_come_back_only_when_asked_and_not_as_received(buses: Buses) -> None:
    ch = buses.channel()
    a = buses.open(ch, clock="lockstep", sync_period=PERIOD, receive_own_messages=True)
    b = buses.open(ch)
    a.send(frame(0x601, bytes(8)))
    own, other = a.recv(1), b.recv(1)
    assert own.is_rx is False and other.is_rx is True
    assert own.timestamp == other.timestamp


# -- arbitration -----------------------------------------------------------------------------------


@pytest.mark.wall
def test_wall_arbitration_when_the_bus_goes_idle_lowest_identifier_first() -> None:
    """Medium.step with chosen times: what is queued while a frame is on the wire competes when it ends."""
    medium = Medium("arb", bitrate=100_000, clock="wall")
    heard: list[can.Message] = []
    listener = medium.attach(heard.append)
    a, b, c, d = (medium.attach(lambda m: None) for _ in range(4))
    medium.submit(a, frame(0x500, bytes(8)), now=0.0)
    assert medium.step(0.0) is not None  # 0x500 on the wire
    medium.submit(b, frame(0x300), now=1e-5)
    medium.submit(c, frame(0x100, extended=True), now=2e-5)  # base bits 0x000: beats 0x300
    medium.submit(d, frame(0x100, remote=True), now=3e-5)
    medium.submit(a, frame(0x050), now=4e-5)  # behind a's own 0x500 in its FIFO until that ends
    medium.step(1.0)
    assert listener is medium.nodes[0]
    order = [(m.arbitration_id, m.is_extended_id, m.is_remote_frame) for m in heard]
    assert order == [
        (0x500, False, False),
        (0x100, True, False),
        (0x050, False, False),
        (0x100, False, True),
        (0x300, False, False),
    ]
    ends = [m.timestamp for m in heard]
    assert ends == sorted(ends)
    assert ends[0] == pytest.approx(seconds(frame(0x500, bytes(8)), 100_000))


@pytest.mark.wall
def test_wall_a_frame_posted_before_the_undelivered_frame_on_the_wire_started_is_arbitrated_as_of_its_post() -> None:
    """A post that reaches the medium late (the loopback, the drives' process) carries its sender's
    time: a SYNC posted before the frame the medium has put on the wire started, that frame not yet
    delivered, goes first, as on a real bus; a frame already delivered is not taken back."""
    medium = Medium("rearb", bitrate=100_000, clock="wall")
    heard: list[can.Message] = []
    medium.attach(heard.append)
    master, drive = medium.attach(lambda m: None), medium.attach(lambda m: None)
    pdo = frame(0x181, bytes(8))
    medium.submit(drive, pdo, now=1e-3)
    assert medium.step(1.1e-3) is not None  # the TPDO on the wire from 1.0 ms, not delivered
    medium.submit(master, frame(SYNC), now=0.5e-3)  # posted at 0.5 ms, reaches the medium now
    medium.step(1.0)
    assert [m.arbitration_id for m in heard] == [SYNC, 0x181]
    sync_ends = 0.5e-3 + seconds(frame(SYNC), 100_000)
    assert heard[0].timestamp == pytest.approx(sync_ends)
    assert heard[1].timestamp == pytest.approx(max(1e-3, sync_ends) + seconds(pdo, 100_000))

    # a SYNC posted while the TPDO was pending but not yet started wins arbitration against it
    heard.clear()
    medium.submit(drive, pdo, now=2.0)
    medium.step(2.0)  # the TPDO starts at 2.0 s
    medium.submit(master, frame(SYNC), now=2.0)  # pending at the same instant: the lower identifier wins
    medium.step(3.0)
    assert [m.arbitration_id for m in heard] == [SYNC, 0x181]

    # delivered frames stay: a SYNC posted before a frame that has already reached the nodes follows it
    heard.clear()
    medium.submit(drive, pdo, now=4.0)
    medium.step(4.0)
    medium.step(4.5)  # the TPDO ended and was delivered
    medium.submit(master, frame(SYNC), now=3.9)
    medium.step(5.0)
    assert [m.arbitration_id for m in heard] == [0x181, SYNC]
    assert heard[1].timestamp == pytest.approx(heard[0].timestamp + seconds(frame(SYNC), 100_000))


@pytest.mark.wall
def test_wall_arbitration_base_before_extended_and_data_before_remote() -> None:
    medium = Medium("arb2", bitrate=100_000, clock="wall")
    heard: list[can.Message] = []
    medium.attach(heard.append)
    senders = [medium.attach(lambda m: None) for _ in range(4)]
    blocker = medium.attach(lambda m: None)
    medium.submit(blocker, frame(0x7FF, bytes(8)), now=0.0)
    medium.step(0.0)
    queued = [
        frame(0x123 << 18, extended=True, remote=True),
        frame(0x123, remote=True),
        frame(0x123 << 18, extended=True),
        frame(0x123),
    ]
    for node, msg in zip(senders, queued, strict=True):
        medium.submit(node, msg, now=1e-5)
    medium.step(1.0)
    assert [(m.is_extended_id, m.is_remote_frame) for m in heard[1:]] == [
        (False, False),
        (False, True),
        (True, False),
        (True, True),
    ]


def test_wall_arbitration_between_two_nodes_in_real_time(buses: Buses) -> None:
    ch = buses.channel()
    a = buses.open(ch, bitrate=2_000)  # about 55 ms a frame: the other two queue while a's first is on
    b = buses.open(ch)
    c = buses.open(ch)
    listener = buses.open(ch)
    a.send(frame(0x500, bytes(8)))
    a.send(frame(0x501, bytes(1)))
    b.send(frame(0x300, bytes(1)))
    c.send(frame(0x100, bytes(1)))
    assert [m.arbitration_id for m in drain(listener, 4)] == [0x500, 0x100, 0x300, 0x501]


# -- the transmit FIFO -----------------------------------------------------------------------------


def test_lockstep_burst_after_sync_gets_enobufs_on_the_eleventh_frame(buses: Buses) -> None:
    ch = buses.channel()
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD, node_name="master")
    drive = buses.open(ch, node_name="drive")
    master.send(frame(SYNC))
    for i in range(9):
        master.send(frame(0x200 + i, bytes(8)))
    with pytest.raises(can.CanOperationError) as raised:
        master.send(frame(0x209, bytes(8)))
    assert raised.value.error_code == errno.ENOBUFS
    stats = master.medium.stats()
    assert stats.enobufs == {"master": 1, "drive": 0}
    assert stats.max_fifo_depth["master"] == 10
    # The drive answers after what it received: once the master has read it, its queue has drained.
    got = drain(drive, 10)
    drive.send(frame(0x181, bytes(2)))
    answer = master.recv(1)
    assert answer.timestamp > got[-1].timestamp
    master.send(frame(0x209, bytes(8)))


def test_lockstep_send_with_a_timeout_waits_in_bus_time_for_room(buses: Buses) -> None:
    """A sender that waits lets its FIFO drain: in lockstep the wait is bus time, so the frame goes
    out once a slot frees, if that is within the timeout, and is refused otherwise."""
    ch = buses.channel()
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD, node_name="master")
    drive = buses.open(ch, node_name="drive")
    master.send(frame(SYNC))
    for i in range(9):
        master.send(frame(0x200 + i, bytes(8)))
    got = drain(drive, 10)
    one_frame = got[1].timestamp - got[0].timestamp
    with pytest.raises(can.CanOperationError):  # a slot frees after the SYNC, longer than this
        master.send(frame(0x209, bytes(8)), timeout=one_frame * 0.1)
    master.send(frame(0x209, bytes(8)), timeout=0.01)
    (late,) = drain(drive, 1)
    assert late.timestamp == pytest.approx(got[-1].timestamp + (got[-1].timestamp - got[-2].timestamp), abs=1e-9)


def test_lockstep_sends_of_another_node_after_a_sync_fill_its_own_fifo(buses: Buses) -> None:
    ch = buses.channel()
    sync = buses.open(ch, clock="lockstep", sync_period=PERIOD)
    master = buses.open(ch)
    sync.send(frame(SYNC))
    for i in range(10):
        master.send(frame(0x300 + i, bytes(8)))
    with pytest.raises(can.CanOperationError) as raised:
        master.send(frame(0x30A, bytes(8)))
    assert raised.value.error_code == errno.ENOBUFS


def test_wall_burst_bigger_than_txqueuelen_raises_enobufs(buses: Buses) -> None:
    ch = buses.channel()
    master = buses.open(ch, bitrate=10_000, node_name="master")  # ~10 ms a frame
    buses.open(ch)
    sent = 0
    with pytest.raises(can.CanOperationError) as raised:
        for i in range(40):
            master.send(frame(0x200 + i, bytes(8)))
            sent += 1
    assert raised.value.error_code == errno.ENOBUFS
    assert sent >= 10
    assert master.medium.stats().enobufs["master"] == 1


def test_wall_send_with_a_timeout_waits_for_room(buses: Buses) -> None:
    ch = buses.channel()
    master = buses.open(ch, bitrate=50_000, txqueuelen=3)
    listener = buses.open(ch)
    for i in range(12):
        master.send(frame(0x200 + i, bytes(8)), timeout=2.0)
    assert [m.arbitration_id for m in drain(listener, 12)] == [0x200 + i for i in range(12)]
    assert master.medium.stats().max_fifo_depth[master.node_name] == 3


# -- late SYNC -------------------------------------------------------------------------------------


def test_lockstep_sync_behind_its_senders_busy_fifo_is_late_by_the_queue(buses: Buses) -> None:
    ch = buses.channel()
    bitrate = 500_000
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD, bitrate=bitrate, txqueuelen=20)
    drive = buses.open(ch)
    master.send(frame(SYNC))
    records = [frame(0x401 + i, bytes([0x55, i, 0, 0, 0, 0, 0, 0])) for i in range(9)]
    for msg in records:
        master.send(msg)
    busy_until = seconds(frame(SYNC), bitrate) + sum(seconds(m, bitrate) for m in records)
    assert busy_until > PERIOD
    master.send(frame(SYNC))
    got = drain(drive, 11)
    second_sync = got[-1]
    assert second_sync.arbitration_id == SYNC
    assert second_sync.timestamp == pytest.approx(busy_until + seconds(frame(SYNC), bitrate), abs=1e-12)
    late = master.medium.late_syncs()
    assert len(late) == 1
    assert late[0].nominal == pytest.approx(PERIOD)
    assert late[0].lateness == pytest.approx(busy_until - PERIOD, abs=1e-12)


def test_lockstep_sync_on_time_is_not_late_and_loads_are_per_period(buses: Buses) -> None:
    ch = buses.channel()
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD)
    drive = buses.open(ch)
    for _ in range(3):
        master.send(frame(SYNC))
        master.send(frame(0x201, bytes(8)))
        drain(drive, 2)
    stats = master.medium.stats()
    assert stats.late_syncs == []
    assert stats.sync_intervals == pytest.approx([PERIOD, PERIOD])
    busy = seconds(frame(SYNC), 1_000_000) + seconds(frame(0x201, bytes(8)), 1_000_000)
    assert stats.period_loads == pytest.approx([busy / PERIOD] * 3)


def test_each_rpdo_is_accounted_its_time_after_the_sync_before_it(buses: Buses) -> None:
    """WireStats.rpdo_after_sync: a setpoint's end on the wire after its SYNC's start (lockstep: exact)."""
    ch = buses.channel()
    master = buses.open(ch, clock="lockstep", sync_period=PERIOD)
    drive = buses.open(ch)
    master.send(frame(0x20B, bytes(4)))  # before any SYNC: no SYNC to be after
    for _ in range(2):
        master.send(frame(SYNC))
        master.send(frame(0x20B, bytes(4)))
        master.send(frame(0x50C, bytes(8)))
        master.send(frame(0x18B, bytes(6)))  # a TPDO: not a receive PDO
    drain(drive, 7)
    stats = master.medium.stats()
    sync, first, second = (seconds(m, 1_000_000) for m in (frame(SYNC), frame(0x20B, bytes(4)), frame(0x50C, bytes(8))))
    assert stats.rpdo_after_sync.keys() == {"0x20B", "0x50C"}
    assert stats.rpdo_after_sync["0x20B"] == pytest.approx([sync + first] * 2, abs=1e-12)
    assert stats.rpdo_after_sync["0x50C"] == pytest.approx([sync + first + second] * 2, abs=1e-12)


# -- bus states and error frames -------------------------------------------------------------------


@pytest.mark.parametrize("clock", ["lockstep", "wall"])
def test_bus_off_node_cannot_send_and_hears_nothing(buses: Buses, clock: str) -> None:
    ch = buses.channel()
    a = buses.open(ch, clock=clock, sync_period=PERIOD, node_name="a")
    b = buses.open(ch, node_name="b")
    a.medium.set_state("a", BUS_OFF)
    assert a.state == BusState.ERROR
    notice = a.recv(1)
    assert notice.is_error_frame and notice.arbitration_id == CAN_ERR_BUSOFF
    with pytest.raises(can.CanOperationError) as raised:
        a.send(frame(0x181, bytes(2)))
    assert raised.value.error_code == errno.ENETDOWN
    b.send(frame(0x601, bytes(8)))
    assert b.recv(0.2) is None  # a's frame never reached the wire
    assert a.recv(0.2) is None  # and a hears nothing
    a.medium.set_state("a", BusState.ACTIVE)
    a.send(frame(0x181, bytes(2)))
    assert b.recv(1).arbitration_id == 0x181


@pytest.mark.wall
def test_bus_off_drops_the_queued_frames_of_the_node() -> None:
    medium = Medium("off", bitrate=100_000, clock="wall")
    heard: list[can.Message] = []
    medium.attach(heard.append)
    node = medium.attach(lambda m: None, name="victim")
    for i in range(3):
        medium.submit(node, frame(0x200 + i, bytes(8)), now=0.0)
    medium.step(0.0)
    medium.set_state("victim", BUS_OFF)
    assert medium.step(1.0) is None
    assert heard == []


@pytest.mark.parametrize("clock", ["lockstep", "wall"])
def test_error_passive_is_reported_and_error_frames_reach_every_node(buses: Buses, clock: str) -> None:
    ch = buses.channel()
    a = buses.open(ch, clock=clock, sync_period=PERIOD, node_name="a")
    b = buses.open(ch, node_name="b")
    a.medium.set_state("a", ERROR_PASSIVE)
    assert a.state == BusState.PASSIVE and b.state == BusState.ACTIVE
    notice = a.recv(1)
    assert notice.is_error_frame and notice.arbitration_id == CAN_ERR_CRTL and notice.data[1] & 0x30
    a.send(frame(0x181, bytes(2)))  # error passive still sends
    assert b.recv(1).arbitration_id == 0x181
    a.medium.inject_error_frame()
    for bus in (a, b):
        msg = bus.recv(1)
        assert msg.is_error_frame and msg.arbitration_id == CAN_ERR_PROT


# -- configuration ---------------------------------------------------------------------------------


@pytest.mark.wall
def test_openers_of_a_channel_must_agree(buses: Buses) -> None:
    ch = buses.channel()
    buses.open(ch, clock="lockstep", sync_period=PERIOD, bitrate=500_000)
    buses.open(ch, bitrate=500_000)
    with pytest.raises(WireConfigError, match="clock"):
        buses.open(ch, clock="wall")
    with pytest.raises(WireConfigError, match="bitrate"):
        buses.open(ch, bitrate=1_000_000)
    with pytest.raises(WireConfigError, match="sync_period"):
        buses.open(buses.channel(), clock="lockstep")
    with pytest.raises(WireConfigError, match="loopback"):
        buses.open("cell@192.168.1.4:29536")
    with pytest.raises(WireConfigError, match=r"NAME@127\.0\.0\.1:PORT"):
        buses.open("cell@127.0.0.1")


def test_the_entry_point_is_declared_and_python_can_finds_it(tmp_path: Path) -> None:
    """python-can and canopen find ``simwire`` through the ``can.interface`` entry point the
    project declares (a dist-info on the path carries it, as an install would)."""
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]["can.interface"]
    assert declared == {"simwire": "pvtflow.axes.sim.wire.interface:SimWireBus"}
    dist = tmp_path / "pvtflow_simwire_probe-0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: pvtflow-simwire-probe\nVersion: 0\n")
    (dist / "entry_points.txt").write_text(f"[can.interface]\nsimwire = {declared['simwire']}\n")
    probe = textwrap.dedent(
        """
        import can, canopen
        bus = can.Bus(interface="simwire", channel="ep", clock="lockstep", sync_period=0.001)
        other = can.Bus(interface="simwire", channel="ep")
        net = canopen.Network().connect(interface="simwire", channel="ep")
        net.send_message(0x181, b"\\x01\\x02")
        msg = bus.recv(1)
        print(type(bus).__name__, hex(msg.arbitration_id), msg.timestamp > 0)
        net.disconnect(); other.shutdown(); bus.shutdown()
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=REPO, env=env, capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.split() == ["SimWireBus", "0x181", "True"]


# -- python-canopen over the wire ------------------------------------------------------------------


def sdo_pair(master_bus: can.BusABC, drive_bus: can.BusABC) -> tuple[canopen.Network, canopen.Network, object]:
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("target", 0x2000, 0)
    var.data_type = canopen.objectdictionary.UNSIGNED32
    var.access_type = "rw"
    var.default = 7
    od.add_object(var)
    name = canopen.objectdictionary.ODVariable("name", 0x2001, 0)
    name.data_type = canopen.objectdictionary.VISIBLE_STRING
    name.access_type = "rw"
    name.default = "simulated wire drive"
    od.add_object(name)
    drive_net = canopen.Network(drive_bus).connect()
    drive_net.add_node(canopen.LocalNode(5, od))
    master_net = canopen.Network(master_bus).connect()
    remote = master_net.add_node(canopen.RemoteNode(5, od))
    return master_net, drive_net, remote


def check_sdo(remote: canopen.RemoteNode) -> None:
    assert remote.sdo[0x2000].raw == 7
    remote.sdo[0x2000].raw = 0xDEADBEEF
    assert remote.sdo.upload(0x2000, 0) == (0xDEADBEEF).to_bytes(4, "little")
    assert remote.sdo[0x2001].raw == "simulated wire drive"  # segmented upload
    remote.sdo[0x2001].raw = "a longer string than four bytes"  # segmented download
    assert remote.sdo[0x2001].raw == "a longer string than four bytes"


@pytest.mark.parametrize("clock", ["lockstep", "wall"])
def test_sdo_upload_and_download_in_process(buses: Buses, clock: str) -> None:
    ch = buses.channel()
    master_bus = buses.open(ch, clock=clock, sync_period=PERIOD, node_name="master")
    drive_bus = buses.open(ch, node_name="drive")
    master_net, drive_net, remote = sdo_pair(master_bus, drive_bus)
    try:
        check_sdo(remote)
    finally:
        master_net.disconnect()
        drive_net.disconnect()
    stats = master_bus.medium.stats()
    assert stats.frames >= 12 and stats.enobufs == {"master": 0, "drive": 0}


# -- another process -------------------------------------------------------------------------------


@pytest.fixture(params=["lockstep", "wall"])
def server(request: pytest.FixtureRequest) -> Iterator[tuple[str, str]]:
    """A simwire server in a child process; yields (channel string, clock)."""
    clock = request.param
    with wire_in_a_child(clock, SERVED_BITRATE, PERIOD) as (address, _):
        assert address.startswith("cell@127.0.0.1:")
        yield address, clock


def test_two_clients_exchange_frames_through_a_server_in_another_process(buses: Buses, server: tuple[str, str]) -> None:
    address, clock = server
    a = buses.open(address, node_name="a", txqueuelen=10)
    b = buses.open(address, clock=clock, node_name="b")
    assert a.clock == clock
    a.send(frame(SYNC))
    a.send(frame(0x201, bytes(range(8))))
    got = drain(b, 2)
    assert [m.arbitration_id for m in got] == [SYNC, 0x201]
    assert got[1].data == bytearray(range(8))
    gap = got[1].timestamp - got[0].timestamp
    if clock == "lockstep":
        assert gap == pytest.approx(seconds(got[1], SERVED_BITRATE), abs=1e-12)
    else:  # the second send may come after the SYNC left the wire
        assert gap >= seconds(got[1], SERVED_BITRATE) - 1e-6
    b.send(frame(0x181, bytes(2)))
    assert a.recv(2).arbitration_id == 0x181
    stats = a.medium.stats()
    assert stats.frames == 3 and stats.clock == clock
    b.medium.inject_error_frame()
    assert a.recv(2).is_error_frame and b.recv(2).is_error_frame
    a.medium.set_state("a", BUS_OFF)
    assert a.state == BusState.ERROR
    notice = a.recv(2)
    assert notice.is_error_frame and notice.arbitration_id == CAN_ERR_BUSOFF
    with pytest.raises(can.CanOperationError) as raised:
        a.send(frame(0x181, bytes(2)))
    assert raised.value.error_code == errno.ENETDOWN


def test_a_remote_burst_gets_enobufs_at_send(buses: Buses, server: tuple[str, str]) -> None:
    address, clock = server
    master = buses.open(address, node_name="master")
    buses.open(address, node_name="drive")
    sent = 0
    with pytest.raises(can.CanOperationError) as raised:
        for i in range(200 if clock == "wall" else 11):
            master.send(frame(0x200 + (i % 64), bytes(8)))
            sent += 1
    assert raised.value.error_code == errno.ENOBUFS
    if clock == "lockstep":
        assert sent == 10
    assert master.medium.stats().enobufs["master"] == 1


def test_a_client_with_other_parameters_is_refused(buses: Buses, server: tuple[str, str]) -> None:
    address, _ = server
    with pytest.raises(WireConfigError, match="bitrate"):
        buses.open(address, bitrate=250_000)
    with pytest.raises(WireConfigError, match="serves channel"):
        buses.open(address.replace("cell@", "other@"))


def test_canopen_sdo_over_the_loopback_server(buses: Buses, server: tuple[str, str]) -> None:
    address, _ = server
    master_net, drive_net, remote = sdo_pair(buses.open(address), buses.open(address))
    try:
        check_sdo(remote)
    finally:
        master_net.disconnect()
        drive_net.disconnect()


@pytest.mark.wall
def test_a_served_medium_times_a_clients_cyclic_send_when_asked(buses: Buses) -> None:
    """``cyclic_by_medium``: ``send_periodic`` of a client is timed by the medium in the server's process
    (SocketCAN's broadcast manager in the kernel): each SYNC queued at its due bus time, heard by the
    sender too; stopped, none follows. Without it, python-can's thread of the client's process sends. The
    client's transmit schedule is the medium's too."""
    with wire_in_a_child("wall", 1_000_000, PERIOD) as (address, _):
        plain = buses.open(address, node_name="plain")
        task = plain.send_periodic(frame(SYNC), 0.005, autostart=False)
        assert isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask)
        task.stop()
        master = buses.open(address, node_name="master", cyclic_by_medium=True)
        listener = buses.open(address, node_name="listener")
        task = master.send_periodic(frame(SYNC), 0.005)
        assert not isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask)
        own = drain(master, 4)
        task.stop()
        heard = drain(listener, 4)
        assert [m.arbitration_id for m in heard] == [SYNC] * 4 and all(m.is_rx for m in own)
        # timed in bus time by the medium (nothing else on the wire): the period exactly, whatever the host did
        assert np.diff([m.timestamp for m in heard]) == pytest.approx([0.005] * 3, abs=1e-6)
        while listener.recv(0.05) is not None:  # what was queued as it stopped
            pass
        assert listener.recv(0.05) is None
        # the SYNCs were the interface's, never the sender's posts: its count of its queue did not move (told
        # each had left, it went one lower per SYNC, and its own ENOBUFS could never come)
        assert master._link is not None and master._link._inflight == 0
        # the transmit schedule through the server (``send_at``): on the wire at its due bus time, whatever
        # the client does meanwhile; ``cancel_scheduled`` takes back the frame not yet due
        due = master.bus_epoch + time.monotonic() + 0.02
        master.send_at([frame(0x20C, b"\x01")], due)
        master.send_at([frame(0x20D, b"\x02")], due + 0.2)
        first = listener.recv(1.0)
        master.cancel_scheduled()
        assert first is not None and first.arbitration_id == 0x20C
        assert first.timestamp == pytest.approx(due + frame_bits(0x20C, b"\x01") * 1e-6, abs=1e-6)
        assert listener.recv(0.3) is None  # the second was taken back


@pytest.mark.wall
def test_a_cyclic_frame_takes_its_place_by_its_due_time_whenever_the_medium_gets_to_it() -> None:
    """The wall-clock medium, held (no driver runs here: it steps when told): a client's cyclic SYNC
    started at the client's time of asking, and frames its node posted after a SYNC was due but that
    reached the medium first, go on the wire in the order of their times, as the kernel's timer and the
    sender's posts meet in one queue: the SYNC due first goes first (never behind a later post), a post
    stamped between two dues goes between them, and a full FIFO is judged at the due time (what left
    the wire by then is out of it: no SYNC dropped for a medium that was late)."""
    medium = Medium(f"cyc-{uuid.uuid4().hex[:8]}", clock="wall")
    heard: list[tuple[int, float]] = []
    child = medium.attach(lambda m: heard.append((m.arbitration_id, m.timestamp)), name="child", receive_own=True)
    medium.attach(lambda m: None, name="drive")
    period = 0.002
    t0 = medium.now() - 0.05  # asked 50 ms ago: the medium hears of it only now
    medium.add_cyclic(child, frame(SYNC), period, start=t0)
    medium.submit(child, frame(0x20C, bytes(8)), now=t0 + period + 0.0001)  # after SYNC 1 was due
    for k in range(10):  # ten setpoints a period after SYNC 2: more than the FIFO holds at once
        medium.submit(child, frame(0x20D, bytes(8)), now=t0 + 2 * period + 0.0001 + k * 1e-6)
    medium.step(t0 + 5 * period)
    order = [cob for cob, _ in heard]
    assert order[:3] == [SYNC, SYNC, 0x20C] and order[3] == SYNC and order[4:14] == [0x20D] * 10
    syncs = [t for cob, t in heard if cob == SYNC]
    assert len(syncs) >= 5  # none dropped: the ten had left the FIFO by SYNC 3's due
    # every SYNC on its due time (bus time in epoch seconds: to a microsecond): no frame ahead of it was
    # pending when it was due, whenever this process got to it
    bits = frame_bits(SYNC, b"")
    assert np.diff(syncs) == pytest.approx([period] * (len(syncs) - 1), abs=1e-6)
    assert syncs[0] == pytest.approx(t0 + bits * 1e-6, abs=1e-6)


@pytest.mark.wall
def test_a_cyclic_frame_stays_on_its_schedule_over_thousands_of_periods() -> None:
    """SYNC k is due k periods after the start, in bus time (epoch seconds, 0.24 us apart near 1.8e9):
    after 5000 SYNCs of 2 ms it starts within a microsecond of that, as the kernel's timer counts in
    integer ns. A schedule summed period by period drifted 95 ns a SYNC, so the master pacing on the
    interface's schedule found its setpoints ahead of the SYNC they followed after about 1000 SYNCs."""
    medium = Medium(f"cyc-{uuid.uuid4().hex[:8]}", clock="wall")
    heard: list[float] = []
    child = medium.attach(lambda m: heard.append(m.timestamp), name="child", receive_own=True)
    period, count = 0.002, 5000
    t0 = medium.now() - period * count  # asked that long ago: every SYNC is due by now
    medium.add_cyclic(child, frame(SYNC), period, start=t0)
    for k in range(count):  # the medium stepped through each period in turn
        medium.step(t0 + period * (k + 0.5))
    bits = frame_bits(SYNC, b"")
    assert len(heard) == count
    ends = np.array(heard) - t0 - bits * 1e-6
    assert np.abs(ends - period * np.arange(count)).max() < 1e-6


@pytest.mark.wall
def test_a_scheduled_frame_goes_on_the_wire_at_its_due_time_after_the_sync_due_with_it() -> None:
    """``Medium.post_at`` (the transmit schedule: SocketCAN's broadcast manager, IXXAT's delayed transmit):
    frames handed over long before are queued at their due time, as a cyclic SYNC is, whenever the medium
    gets to it: due a microsecond after a SYNC of the same node, they follow it (a FIFO) and are pending
    when it ends, so the first takes the next arbitration before a drive's TPDO produced by that SYNC; the
    next then loses to the TPDO by identifier, as on a real bus. The sender hears them as its own."""
    medium = Medium(f"sch-{uuid.uuid4().hex[:8]}", clock="wall")
    heard: list[tuple[int, float, bool]] = []
    child = medium.attach(
        lambda m: heard.append((m.arbitration_id, m.timestamp, m.is_rx)), name="child", receive_own=True
    )
    drive = medium.attach(lambda m: None, name="drive")
    period = 0.002
    t0 = medium.now() - 0.05  # all of it asked for 50 ms ago: the medium gets to it only now
    medium.add_cyclic(child, frame(SYNC), period, start=t0)
    medium.post_at(child, [frame(0x20C, bytes(4)), frame(0x20D, bytes(4))], t0 + period + 1e-6)
    sync_bits = frame_bits(SYNC, b"")
    sync_end = t0 + period + sync_bits * 1e-6
    medium.submit(drive, frame(0x18C, bytes(8)), now=sync_end + 2e-6)  # the drive's answer to SYNC 1
    medium.step(t0 + 3 * period)
    order = [cob for cob, _, _ in heard]
    assert order[:5] == [SYNC, SYNC, 0x20C, 0x18C, 0x20D] and order[5] == SYNC
    ends = {cob: t for cob, t, _ in heard[1:5]}
    assert heard[1][1] == pytest.approx(sync_end, abs=1e-6)  # SYNC 1 on its due time
    assert ends[0x20C] == pytest.approx(sync_end + frame_bits(0x20C, bytes(4)) * 1e-6, abs=1e-6)  # right after it
    assert [rx for cob, _, rx in heard if cob in (0x20C, 0x20D)] == [False, False]  # its own frames


@pytest.mark.wall
def test_a_scheduled_frame_meeting_a_full_fifo_is_dropped_and_a_cancel_takes_back_the_rest() -> None:
    """At its due time the node's FIFO is full (two frames of a txqueuelen of 2 queued before it): the
    scheduled frame is dropped, as the broadcast manager's is, and counted; one due once they left goes;
    ``cancel_posts`` (TX_DELETE) takes back those not yet due."""
    medium = Medium(f"sch-{uuid.uuid4().hex[:8]}", clock="wall")
    heard: list[int] = []
    node = medium.attach(lambda m: heard.append(m.arbitration_id), name="node", receive_own=True, txqueuelen=2)
    t = medium.now() - 0.05
    medium.submit(node, frame(0x300, bytes(8)), now=t)
    medium.submit(node, frame(0x301, bytes(8)), now=t)
    medium.post_at(node, [frame(0x20C, bytes(8))], t + 1e-6)  # both still queued then
    medium.post_at(node, [frame(0x20D, bytes(8))], t + 0.001)  # both gone by then (2 x 111-135 us)
    medium.post_at(node, [frame(0x20E, bytes(8))], t + 0.04)
    medium.step(t + 2e-6)
    medium.step(t + 0.002)
    assert medium.cancel_posts(node) == 1
    medium.step(t + 0.045)
    assert heard == [0x300, 0x301, 0x20D] and node.dropped == 1


@pytest.mark.wall
def test_a_medium_held_for_periods_judges_each_timed_frames_fifo_at_its_due_time() -> None:
    """The medium gets to the wire only 12 ms after a client's SYNC and scheduled setpoints (three per
    period) were due, a frame of another node posted just before it resumed: each timed frame is queued as
    the FIFO stood at its due time, when the frames before it had long left the wire, so none is dropped
    (queued all at once, the FIFO of 10 would have dropped the last)."""
    medium = Medium(f"sch-{uuid.uuid4().hex[:8]}", clock="wall")
    heard: list[int] = []
    child = medium.attach(lambda m: heard.append(m.arbitration_id), name="child", receive_own=True)
    period = 0.002
    t0 = medium.now() - 0.05
    medium.add_cyclic(child, frame(SYNC), period, start=t0)
    for n in range(6):
        medium.post_at(child, [frame(0x20B + k, bytes(4)) for k in range(3)], t0 + n * period + 1e-6)
    drive = medium.attach(lambda m: None, name="drive")
    medium.submit(drive, frame(0x70B, b"\x05"), now=t0 + 6 * period - 2e-4)  # posted as the medium resumed
    medium.step(t0 + 6 * period - 1e-4)
    assert heard == [SYNC, 0x20B, 0x20C, 0x20D] * 6 + [0x70B] and child.dropped == 0
