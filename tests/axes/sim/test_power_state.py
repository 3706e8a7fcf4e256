"""Drive side of CiA 301 / CiA 402 on a simulated drive: NMT, heartbeat, EMCY, power state machine."""

from __future__ import annotations

import canopen
import pytest

from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim import Epos2Drive

from .conftest import Bench

SOD, RTSO, SO, OE, FAULT = 0x0040, 0x0031, 0x0033, 0x0037, 0x0008
TARGET_REACHED = 1 << 10


def statusword(node: canopen.RemoteNode) -> int:
    return node.sdo[od.STATUSWORD].raw


def test_boot_up_pre_operational_and_heartbeat_per_0x1017(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(7))
    boot = bench.log.wait_for(0x707)
    assert boot and bytes(boot[0].data) == b"\x00"
    assert drive.nmt_state == "PRE-OPERATIONAL"
    node = bench.remote(drive)
    node.sdo[od.PRODUCER_HEARTBEAT_TIME].raw = 10
    beats = bench.log.wait_for(0x707, 4, where=lambda m: m.data[0] == 0x7F)
    assert len(beats) >= 4
    node.nmt.state = "OPERATIONAL"
    assert bench.log.wait_for(0x707, 1, where=lambda m: m.data[0] == 0x05)
    assert drive.operational


def test_heartbeat_stops_on_injection(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(8))
    node = bench.remote(drive)
    node.sdo[od.PRODUCER_HEARTBEAT_TIME].raw = 5
    assert len(bench.log.wait_for(0x708, 3, where=lambda m: m.data[0] == 0x7F)) >= 3
    drive.nmt.stop_heartbeat()
    bench.log.clear()
    # 20 heartbeat periods of silence: waiting for a frame that must not come
    assert bench.log.wait_for(0x708, 1, timeout=0.1) == []
    # a master rewriting 0x1017 does not revive a dead node; resuming does
    node.sdo[od.PRODUCER_HEARTBEAT_TIME].raw = 5
    assert bench.log.wait_for(0x708, 1, timeout=0.05) == []
    drive.nmt.resume_heartbeat()
    assert bench.log.wait_for(0x708, 2)


def test_power_state_machine_statuswords(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(9))
    node = bench.remote(drive)
    assert statusword(node) == SOD
    node.sdo[od.CONTROLWORD].raw = 0x0006
    assert statusword(node) == RTSO
    node.sdo[od.CONTROLWORD].raw = 0x0007
    assert statusword(node) == SO
    node.sdo[od.CONTROLWORD].raw = 0x000F
    assert statusword(node) == OE | TARGET_REACHED
    node.sdo[od.CONTROLWORD].raw = 0x0007  # disable operation
    assert statusword(node) == SO
    node.sdo[od.CONTROLWORD].raw = 0x000F
    node.sdo[od.CONTROLWORD].raw = 0x0006  # shutdown from operation enabled
    assert statusword(node) == RTSO
    node.sdo[od.CONTROLWORD].raw = 0x000F  # the EPOS2 goes on from ready to switch on at once
    assert drive.state == "OPERATION ENABLED"
    node.sdo[od.CONTROLWORD].raw = 0x0002  # quick stop at rest: straight to switch on disabled
    assert statusword(node) == SOD
    node.sdo[od.CONTROLWORD].raw = 0x0006
    node.sdo[od.CONTROLWORD].raw = 0x0000  # disable voltage
    assert statusword(node) == SOD
    node.sdo[od.CONTROLWORD].raw = 0x000F  # no transition from switch on disabled
    assert statusword(node) == SOD
    node.sdo[od.MODES_OF_OPERATION].raw = od.INTERPOLATED_POSITION_MODE
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == od.INTERPOLATED_POSITION_MODE


def test_fault_emcy_and_reset_on_rising_edge_only(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(10))
    node = bench.remote(drive)
    for cw in (0x0006, 0x000F):
        node.sdo[od.CONTROLWORD].raw = cw
    node.sdo[od.CONTROLWORD].raw = 0x008F  # rising bit 7 outside FAULT: no effect on the state
    assert drive.state == "OPERATION ENABLED"
    drive.inject_emcy(0x5113)
    emcy = bench.log.wait_for(0x8A)
    assert emcy and int.from_bytes(emcy[0].data[:2], "little") == 0x5113 and emcy[0].data[2] & 0x01
    assert statusword(node) & 0x4F == FAULT
    assert node.sdo[0x603F].raw == 0x5113
    assert node.sdo[0x1001].raw & 0x01
    node.sdo[od.CONTROLWORD].raw = 0x0080  # bit 7 was already 1: no rising edge
    assert drive.state == "FAULT"
    node.sdo[od.CONTROLWORD].raw = 0x0000
    node.sdo[od.CONTROLWORD].raw = 0x0080  # rising edge
    assert statusword(node) == SOD
    assert node.sdo[0x1001].raw == 0
    reset = bench.log.wait_for(0x8A, 2)
    assert int.from_bytes(reset[-1].data[:2], "little") == 0  # error reset EMCY
    assert [f.code for f in drive.faults] == [0x5113]


def test_nmt_reset_node_boots_again_with_commissioned_limits(bench: Bench) -> None:
    from pvtflow.axes.drive.scaling import DriveLimits

    limits = DriveLimits(3000, 20000, -5000, 5000)
    drive = bench.add(Epos2Drive(11, limits=limits))
    node = bench.remote(drive)
    node.sdo[od.MODES_OF_OPERATION].raw = 7
    node.sdo[od.PRODUCER_HEARTBEAT_TIME].raw = 50
    bench.log.clear()
    node.nmt.send_command(0x81)
    assert bench.log.wait_for(0x70B, 1, where=lambda m: m.data[0] == 0)
    assert drive.wait_until(lambda: drive.nmt_state == "PRE-OPERATIONAL")
    assert node.sdo[od.MODES_OF_OPERATION].raw == 0
    assert node.sdo[od.PRODUCER_HEARTBEAT_TIME].raw == 0
    assert node.sdo[od.MAX_PROFILE_VELOCITY].raw == 3000
    assert node.sdo[od.SOFTWARE_POSITION_LIMIT][1].raw == -5000


def test_bad_node_id_is_refused() -> None:
    with pytest.raises(ValueError, match="node id"):
        Epos2Drive(0)
