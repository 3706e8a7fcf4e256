"""TPDO rates of the simulated drives: a synchronous TPDO of type n on every n-th SYNC, an event
TPDO's inhibit time and event timer (axes/sim/node/tpdo_timing.py), as the master writes them over SDO."""

from __future__ import annotations

import dataclasses
import threading
import time

import canopen
import pytest

from pvtflow.axes.drive.objects import EPOS2_RPDOS, EPOS2_TPDOS
from pvtflow.axes.sim import Epos2Drive
from pvtflow.axes.sim.node.pdo import PdoState

from .conftest import Bench, configure_pdos

STATUS_RPDO = 0x300  # the synchronous controlword RPDO2


def _retime_tpdo1(node: canopen.RemoteNode, inhibit_100us: int, event_timer_ms: int) -> None:
    """0x1800:03 / :05 of TPDO1 the CiA 301 way: only while the PDO is invalid."""
    cob = node.sdo[0x1800][1].raw
    node.sdo[0x1800][1].raw = cob | 0x8000_0000
    node.sdo[0x1800][3].raw = inhibit_100us
    node.sdo[0x1800][5].raw = event_timer_ms
    node.sdo[0x1800][1].raw = cob


def _sent_at(drive: Epos2Drive, cob_id: int) -> list[int]:
    """The SYNC count of the drive at each frame of ``cob_id`` it sends from now on (the drive's own
    account: the master's log receives them later, on its notifier thread)."""
    at: list[int] = []
    send = drive.pdo._send

    def spy(pdo: PdoState, data: bytes) -> None:
        if pdo.cob_id == cob_id:
            at.append(drive.sync_count)
        send(pdo, data)

    drive.pdo._send = spy  # type: ignore[method-assign]
    return at


def _operational(bench: Bench, drive: Epos2Drive, node: canopen.RemoteNode) -> None:
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational)


def test_a_synchronous_tpdo_of_type_n_goes_out_on_every_nth_sync(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(61))
    node = bench.remote(drive)
    every_third = tuple(t if t.number != 2 else dataclasses.replace(t, transmission_type=3) for t in EPOS2_TPDOS)
    configure_pdos(node, EPOS2_RPDOS, every_third)
    assert drive.pdo.tpdos[2].transmission_type == 3
    at = _sent_at(drive, 0x280 + 61)
    _operational(bench, drive, node)
    first = drive.sync_count
    bench.sync(9)
    assert [n - first for n in at] == [3, 6, 9]  # the 3rd, 6th and 9th SYNC after OPERATIONAL
    assert len(bench.log.wait_for(0x280 + 61, 3)) == 3


def test_an_event_tpdo_never_goes_out_faster_than_its_inhibit_time(bench: Bench) -> None:
    """Three statusword changes on three SYNCs 1 ms apart, inhibit time 3 ms: the first change goes
    out, the next two wait, and the state after them goes out 3 ms after the first frame."""
    drive = bench.add(Epos2Drive(62))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    _retime_tpdo1(node, 30, 0)
    _operational(bench, drive, node)
    bench.sync(4)  # past the inhibit time of the frame OPERATIONAL sent
    base = len(bench.log.wait_for(0x180 + 62, 1))
    at = _sent_at(drive, 0x180 + 62)
    start = drive.sync_count
    for word in (0x0006, 0x0007, 0x000F, None, None):
        if word is not None:
            bench.send(STATUS_RPDO + 62, word.to_bytes(2, "little"))
        bench.sync(1)
    assert drive.state == "OPERATION ENABLED"
    assert [n - start for n in at] == [1, 4]  # the change at SYNC 1, then SYNC 4: 3 ms later
    frames = bench.log.wait_for(0x180 + 62, base + 2)
    assert int.from_bytes(frames[-1].data[2:4], "little") & 0x6F == 0x27  # the latest state: operation enabled


def test_an_event_tpdo_without_inhibit_sends_every_change(bench: Bench) -> None:
    """The same changes without an inhibit time: one frame per change (the rule above is the inhibit's)."""
    drive = bench.add(Epos2Drive(63))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    _retime_tpdo1(node, 0, 0)
    _operational(bench, drive, node)
    bench.sync(1)
    at = _sent_at(drive, 0x180 + 63)
    start = drive.sync_count
    for word in (0x0006, 0x0007, 0x000F):
        bench.send(STATUS_RPDO + 63, word.to_bytes(2, "little"))
        bench.sync(1)
    assert [n - start for n in at] == [1, 2, 3]


def test_the_event_timer_sends_an_unchanged_tpdo(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(64))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    _retime_tpdo1(node, 10, 4)  # inhibit 1 ms, event timer 4 ms
    _operational(bench, drive, node)
    bench.sync(1)
    at = _sent_at(drive, 0x180 + 64)
    start = drive.sync_count
    bench.sync(12)  # nothing changes: a frame every 4 ms of the drive's clock
    assert [n - start for n in at] == [3, 7, 11]


@pytest.mark.wall
def test_a_change_held_by_the_inhibit_time_is_not_sent_once_the_drive_left_the_bus(bench: Bench) -> None:
    """A statusword change held by a 50 ms inhibit time while the drive's clock stands still (no
    SYNC) waits on a wall-clock timer; the drive leaves the bus before it runs out: the timer is
    cancelled, and nothing is sent by a drive that is off the network."""
    drive = bench.add(Epos2Drive(65))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    _retime_tpdo1(node, 500, 0)  # inhibit 50 ms
    _operational(bench, drive, node)
    bench.sync(60)  # past the inhibit time of the frame OPERATIONAL sent
    failures: list[threading.ExceptHookArgs] = []
    hook, threading.excepthook = threading.excepthook, failures.append
    try:
        for word in (0x0006, 0x0007):  # the first goes out, the second is held (no SYNC: the clock stands)
            node.sdo[0x6040].raw = word
        assert drive.pdo.tpdos[1].held is not None
        bench.drives.remove(drive)
        drive.detach()
        assert drive.pdo.tpdos[1].held is None
        time.sleep(0.1)  # past the inhibit time
    finally:
        threading.excepthook = hook
    assert failures == []
