"""Commissioning (axes/master/commission.py): a simulated drive that is not what the cell expects (its
``simulation:`` section: encoder, polarity, identity, motor speed) is caught, named, and refused by
configuration before anything is written; a cell whose drives agree passes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import AxisSimulation
from pvtflow.axes.master.commission import CheckKind, Status, commission
from pvtflow.axes.master.link import DriveError
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

GANTRY = CONFIG_DIR / "cells" / "gantry3.yaml"

# each kind of drive that differs from the cell, and the object that must name it
MISMATCHES: dict[str, tuple[dict[str, int], str]] = {
    "encoder": ({"qc_per_motor_rev": 2048}, "0x2210:01"),
    "polarity": ({"polarity": 0x80}, "0x607E"),
    "vendor": ({"vendor_id": 0x1234}, "0x1018:01-02"),
    "product": ({"product_code": 0x7}, "0x1018:01-02"),
    "motor speed": ({"max_motor_speed_rpm": 1000}, "0x6410:04"),
    "sensor polarity": ({"sensor_polarity": 1}, "0x2210:04"),
    "sensor type": ({"sensor_type": 4}, "0x2210:02"),
    "velocity notation": ({"velocity_notation_index": -1}, "0x608B"),
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
    assert facts == {
        "0x1018:01-02",
        "0x6502",
        "0x2210:01",
        "0x2210:02",
        "0x2210:04",
        "0x607E",
        "0x6410:04",
        "0x608B",
        "0x608C",
    }
    assert {c.status for c in report.axes[0].checks if c.kind is CheckKind.FACT} == {Status.OK}
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


# --- an EPOS2 whose dictionary is maxon's own EDS ------------------------------------------------
MAXON = "vendor/maxon-epos2-70-10.eds"
MAXON_REQUIRES = ("0x2210:01", "0x2210:02", "0x2210:04", "0x608B", "0x608C", "0x6410:04")


def maxon_cell(cell: CellConfig, requires: tuple[str, ...] = MAXON_REQUIRES, **drive: int) -> CellConfig:
    """The cell with every axis's simulated drive built from maxon's EDS (y as ``drive`` says), each
    axis requiring what maxon's objects give."""
    axes = []
    for a in cell.axes:
        sim = dataclasses.replace(a.simulation or AxisSimulation(), eds=MAXON, **(drive if a.joint == "y" else {}))
        axes.append(dataclasses.replace(a, simulation=sim, commission_requires=requires))
    return dataclasses.replace(cell, axes=tuple(axes))


def test_a_maxon_eds_epos2_is_checked_by_maxons_objects_and_what_it_lacks_is_not_checked(
    gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    rig = make_rig(maxon_cell(gantry3))
    assert all(d.eds_path.name == "maxon-epos2-70-10.eds" for d in rig.sim)
    report = commission(rig.group.links, rig.group.profiles)
    assert report.ok, [str(c) for a in report.axes for c in a.mismatches]
    for axis in report.axes:
        status = {c.object: c.status for c in axis.checks}
        for where in (*MAXON_REQUIRES, "0x1018:01-02", "0x6502"):
            assert status[where] is Status.OK, where
        # maxon's EDS has no 0x607E: not checked, named, never ok, and not required by this cell
        assert status["0x607E"] is Status.NOT_CHECKED
        polarity = next(c for c in axis.checks if c.object == "0x607E")
        assert not polarity.ok and "not checked, the drive has no 0x607E" in str(polarity)
        # every limit written is read back by commissioning, 0x6085 too
        settings = {c.object: c.status for c in axis.checks if c.kind is CheckKind.SETTING}
        assert {"0x607F:00", "0x60C5:00", "0x607D:01", "0x607D:02", "0x6065:00", "0x6085:00"} <= set(settings)
        assert set(settings.values()) == {Status.OK}
    rig.group.configure()
    assert rig.group.configured


@pytest.mark.parametrize("kind", ["sensor polarity", "sensor type", "velocity notation", "encoder", "motor speed"])
def test_each_maxon_eds_epos2_set_up_wrong_is_caught_and_refused(
    kind: str, gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    drive, where = MISMATCHES[kind]
    rig = make_rig(maxon_cell(gantry3, **drive))
    report = commission(rig.group.links, rig.group.profiles)
    assert {a.joint: [c.object for c in a.mismatches] for a in report.axes if not a.ok} == {"y": [where]}
    written = (od.MODES_OF_OPERATION, od.PRODUCER_HEARTBEAT_TIME, od.MAX_PROFILE_VELOCITY)
    before = [[d.read(index) for index in written] for d in rig.sim]
    with pytest.raises(DriveError) as refused:
        rig.group.configure()
    assert refused.value.node_id == 12 and where in str(refused.value)
    assert not rig.group.configured
    assert [[d.read(index) for index in written] for d in rig.sim] == before  # nothing written


def test_a_required_check_the_drive_cannot_answer_fails_and_is_refused(
    gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    rig = make_rig(maxon_cell(gantry3, requires=("0x607E",)))  # maxon's EDS has no 0x607E
    report = commission(rig.group.links, rig.group.profiles)
    assert not report.ok
    for axis in report.axes:
        assert [(c.object, c.status, c.required) for c in axis.mismatches] == [("0x607E", Status.NOT_CHECKED, True)]
    with pytest.raises(DriveError) as refused:
        rig.group.configure()
    assert "0x607E polarity: not checked, the drive has no 0x607E (required by the cell)" in str(refused.value)


def test_a_tpdo_event_timer_the_drive_cannot_take_is_refused_naming_setting_and_object(
    gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    cell = maxon_cell(gantry3, requires=())
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, status_event_timer_ms=100))
    rig = make_rig(cell)
    report = commission(rig.group.links, rig.group.profiles)
    assert not report.ok
    wrong = report.axes[0].mismatches
    assert wrong and all(c.object.endswith(":05") and c.status is Status.NOT_CHECKED for c in wrong)
    written = (od.MODES_OF_OPERATION, od.PRODUCER_HEARTBEAT_TIME, od.MAX_PROFILE_VELOCITY)
    before = [[d.read(index) for index in written] for d in rig.sim]
    with pytest.raises(DriveError) as refused:
        rig.group.configure()
    assert "status_event_timer_ms" in str(refused.value) and ":05" in str(refused.value)
    assert not rig.group.configured
    assert [[d.read(index) for index in written] for d in rig.sim] == before  # nothing written


def test_the_same_event_timer_on_a_drive_with_0x1800_05_is_taken(
    gantry3: CellConfig, make_rig: Callable[..., object]
) -> None:
    cell = dataclasses.replace(gantry3, bus=dataclasses.replace(gantry3.bus, status_event_timer_ms=100))
    rig = make_rig(cell)
    assert commission(rig.group.links, rig.group.profiles).ok
