"""CiA 301 PDO handling of the simulated drives: configured by the master over SDO."""

from __future__ import annotations

import pytest
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.objects import EPOS2_RPDOS, EPOS2_TPDOS
from pvtflow.axes.sim import Epos2Drive

from .conftest import Bench, configure_pdos, enable


def test_mapping_written_by_the_master_is_honoured(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(51))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    assert drive.pdo.rpdos[1].entries == ((od.EPOS2_INTERPOLATION_DATA_RECORD, 0, 64),)
    assert drive.pdo.rpdos[2].transmission_type == 1 and drive.pdo.rpdos[2].valid
    assert drive.pdo.tpdos[1].entries == ((od.EPOS2_INTERPOLATION_BUFFER, 1, 16), (od.STATUSWORD, 0, 16))
    # pre-operational: no PDO either way
    bench.send(0x300 + 51, (0x0006).to_bytes(2, "little"))
    bench.sync(2)
    assert drive.state == "SWITCH ON DISABLED" and bench.log.of(0x280 + 51) == []
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational)
    # the synchronous RPDO acts at the SYNC, not before
    bench.send(0x300 + 51, (0x0006).to_bytes(2, "little"))
    assert not drive.wait_until(lambda: drive.state == "READY TO SWITCH ON", timeout=0.05)
    bench.sync(1)
    assert drive.state == "READY TO SWITCH ON"
    # synchronous TPDO (type 1): one per SYNC
    assert len(bench.log.wait_for(0x280 + 51, 1)) == 1  # the one SYNC since operational
    bench.sync(5)
    assert len(bench.log.wait_for(0x280 + 51, 6)) == 6
    # event TPDO (255): sent when its content changes
    n = len(bench.log.of(0x180 + 51))
    bench.send(0x300 + 51, (0x000F).to_bytes(2, "little"))
    bench.sync(1)
    frames = bench.log.wait_for(0x180 + 51, n + 1)
    assert int.from_bytes(frames[-1].data[2:4], "little") & 0x6F == 0x27


def test_mapping_changes_are_refused_while_the_pdo_is_valid(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(52))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    with pytest.raises(SdoAbortedError) as err:  # a valid PDO's mapping: unsupported access
        node.sdo[0x1600][0].raw = 0
    assert err.value.code == 0x06010000
    with pytest.raises(SdoAbortedError) as err:  # its COB-ID, even by the write that invalidates it
        node.sdo[0x1400][1].raw = 0x80000000 | 0x400
    assert err.value.code == 0x06090030
    with pytest.raises(SdoAbortedError) as err:
        node.sdo[0x1400][1].raw = 0x400
    assert err.value.code == 0x06090030
    with pytest.raises(SdoAbortedError) as err:  # a valid TPDO's inhibit time
        node.sdo[0x1800][3].raw = 30
    assert err.value.code == 0x06090030
    node.sdo[0x1400][1].raw = 0x80000000 | (0x200 + 52)  # invalidate
    with pytest.raises(SdoAbortedError) as err:  # an entry while sub 0 counts entries
        node.sdo[0x1600][1].raw = (od.CONTROLWORD << 16) | 16
    assert err.value.code == 0x08000022
    node.sdo[0x1600][0].raw = 0
    with pytest.raises(SdoAbortedError) as err:  # 0x60C4:02 is not PDO-mappable
        node.sdo[0x1600][1].raw = (od.INTERPOLATION_DATA_CONFIGURATION << 16) | (2 << 8) | 32
    assert err.value.code == 0x06040041
    with pytest.raises(SdoAbortedError):  # statusword is read-only: not in an RPDO
        node.sdo[0x1600][1].raw = (od.STATUSWORD << 16) | 16
    node.sdo[0x1600][1].raw = (od.CONTROLWORD << 16) | 16
    node.sdo[0x1600][0].raw = 1
    node.sdo[0x1400][1].raw = 0x200 + 52
    assert drive.pdo.rpdos[1].entries == ((od.CONTROLWORD, 0, 16),) and drive.pdo.rpdos[1].valid


def test_short_rpdo_is_dropped_with_emcy(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(53))
    node = bench.remote(drive)
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    node.nmt.state = "OPERATIONAL"
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    bench.send(0x200 + 53, b"\x01\x02\x03")
    emcy = bench.log.wait_for(0x80 + 53)
    assert int.from_bytes(emcy[0].data[:2], "little") == od.EMCY_PDO_LENGTH
    assert drive.level == 0 and drive.state == "OPERATION ENABLED"
