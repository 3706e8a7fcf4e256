"""Commissioning (axes/commission.py): a simulated drive that is not what the cell expects (its
``simulation:`` section: encoder, polarity, identity, motor speed) is caught, named, and refused by
configuration before anything is written; a cell whose drives agree passes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from pvtflow.axes import objects as od
from pvtflow.axes.commission import CheckKind, commission
from pvtflow.axes.config import AxisSimulation
from pvtflow.axes.link import DriveError
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"

# each kind of drive that differs from the cell, and the object that must name it
MISMATCHES: dict[str, tuple[dict[str, int], str]] = {
    "encoder": ({"qc_per_motor_rev": 2048}, "0x2210:01"),
    "polarity": ({"polarity": 0x80}, "0x607E"),
    "vendor": ({"vendor_id": 0x1234}, "0x1018:01-02"),
    "product": ({"product_code": 0x7}, "0x1018:01-02"),
    "motor speed": ({"max_motor_speed_rpm": 1000}, "0x6410:04"),
}


@pytest.fixture(scope="module")
def gantry3() -> CellConfig:
    return load_cell_config(GANTRY)


def with_drive(cell: CellConfig, joint: str, **drive: int) -> CellConfig:
    """The cell with one axis's simulated drive different from what the cell says of it."""
    axes = []
    for a in cell.axes:
        if a.joint == joint:
            a = dataclasses.replace(a, simulation=dataclasses.replace(a.simulation or AxisSimulation(), **drive))
        axes.append(a)
    return dataclasses.replace(cell, axes=tuple(axes))


def test_a_cell_whose_drives_agree_passes(gantry3: CellConfig, make_rig: Callable[..., object]) -> None:
    rig = make_rig(gantry3)
    report = commission(rig.group.links, rig.group.profiles)
    assert report.ok, [str(c) for a in report.axes for c in a.mismatches]
    assert [a.joint for a in report.axes] == [a.joint for a in gantry3.ordered_axes()]
    facts = {c.object for c in report.axes[0].checks if c.kind is CheckKind.FACT}
    assert facts == {"0x1018:01-02", "0x6502", "0x2210:01", "0x607E", "0x6410:04"}
    assert report.sdo_transfers > 0
    rig.group.configure()  # the same checks when configuring: nothing refused
    assert rig.group.configured


def test_a_fixed_period_drive_reports_its_encoder_in_0x608f(
    gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    from axes_rig import with_profiles

    cell = with_profiles(gantry3, {"x": {"profile": "parker_slvdn", "period_ms": 3}}, 3.0)
    rig = make_rig(with_drive(cell, "x", qc_per_motor_rev=1000))
    x = commission(rig.group.links, rig.group.profiles).axes[[a.joint for a in cell.ordered_axes()].index("x")]
    # the Parker has no homing mode (0x6502), which the gantry's x axis needs, and its own encoder
    assert [(c.object, c.found.split(" (")[0]) for c in x.mismatches] == [
        ("0x6502", "0x00000040"),
        ("0x608F:01-02", "1000 qc/rev"),
    ]


@pytest.mark.parametrize("kind", sorted(MISMATCHES))
def test_each_drive_that_differs_is_caught_and_refused_before_anything_is_written(
    kind: str, gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    drive, where = MISMATCHES[kind]
    rig = make_rig(with_drive(gantry3, "y", **drive))
    report = commission(rig.group.links, rig.group.profiles)
    assert not report.ok
    bad = {a.joint: [c.object for c in a.mismatches] for a in report.axes if not a.ok}
    assert bad == {"y": [where]}
    with pytest.raises(DriveError) as refused:
        rig.group.configure()
    assert refused.value.node_id == 12 and where in str(refused.value) and "expected" in str(refused.value)
    assert not rig.group.configured
    for d in rig.sim:  # nothing written: heartbeat, mode and PDOs as the drives powered up
        assert d.read(od.PRODUCER_HEARTBEAT_TIME) == 0
        assert d.read(od.MODES_OF_OPERATION) == 0
        assert d.read(0x1A01, 0) == 0
