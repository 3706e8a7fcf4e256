"""The master configures PDOs as CiA 301 says, against drives as strict as strict stacks (a valid
PDO's COB-ID, mapping and inhibit time refused): invalidate with the COB-ID it has, move it while
invalid, map, type, inhibit time and event timer, validate, read back; unused PDOs invalidated."""

from __future__ import annotations

from collections.abc import Callable

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.objects import EPOS2_RPDOS, EPOS2_TIME_STAMP_RPDO, EPOS2_TPDOS, TIME_STAMP_COB_ID
from pvtflow.service.config import CellConfig


def test_every_pdo_is_configured_and_read_back_and_the_rest_invalidated(
    arm6: CellConfig, make_rig: Callable[..., object]
) -> None:
    rig = make_rig(arm6)
    drive = rig.sim.drive(3)
    # what an earlier setup left: RPDO1 valid on another COB-ID, TPDO3 valid and mapped
    drive.store(0x1400, 1, 0x240 + 3)
    drive.store(0x1A02, 1, (od.POSITION_ACTUAL_VALUE << 16) | 32)
    drive.store(0x1A02, 0, 1)
    drive.store(0x1802, 1, 0x380 + 3)
    drive.pdo.reload()
    rig.group.configure()
    period_100us = round(arm6.bus.sync_period_ms * 10)
    for d in rig.sim:
        n = d.node_id
        rpdos, tpdos = d.pdo.rpdos, d.pdo.tpdos
        for layout in (*EPOS2_RPDOS, EPOS2_TIME_STAMP_RPDO):
            cob = TIME_STAMP_COB_ID if layout is EPOS2_TIME_STAMP_RPDO else layout.cob_id(n, True)
            assert (rpdos[layout.number].cob_id, rpdos[layout.number].valid) == (cob, True)
            assert rpdos[layout.number].entries == layout.entries
        for layout in EPOS2_TPDOS:
            assert (tpdos[layout.number].cob_id, tpdos[layout.number].valid) == (layout.cob_id(n, False), True)
            assert tpdos[layout.number].entries == layout.entries
            assert d.read(0x1800 + layout.number - 1, 3) == layout.inhibit_periods * period_100us
            assert d.read(0x1800 + layout.number - 1, 5) == 0
        assert not rpdos[4].valid and not tpdos[3].valid and not tpdos[4].valid
    assert rig.group.configured


def test_the_parker_answers_with_0x6063_as_its_seed_lists(make_rig: Callable[..., object]) -> None:
    from pvtflow.service.config import CONFIG_DIR, load_cell_config

    cell = load_cell_config(CONFIG_DIR / "cells" / "gantry3-parker.yaml")
    rig = make_rig(cell)
    rig.group.configure()
    for link in rig.group.links:
        drive = rig.sim.drive(link.node_id)
        assert drive.pdo.tpdos[1].entries == ((od.STATUSWORD, 0, 16), (od.POSITION_ACTUAL_INTERNAL_VALUE, 0, 32))
        link.position = None
    assert rig.bus.sync.wait_answered(rig.bus.sync.step(), 2.0) == []  # their answers to one SYNC
    for link in rig.group.links:
        assert link.position is not None and link.position == rig.sim.drive(link.node_id).actual
