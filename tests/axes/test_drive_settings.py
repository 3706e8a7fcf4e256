"""Every profile writes the drive's limit objects from the axis (0x607F, 0x60C5, 0x607D, 0x6065, 0x6085)
where the drive has them and reads them back: what a vendor tool stored does not stay."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from axes_rig import with_profiles

from pvtflow.axes.drive import objects as od
from pvtflow.axes.master.profiles.base import expected_settings
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

PROFILES = {
    "epos2_pvt": {},
    "cia402_ip_linear": {"profile": "cia402_ip_linear", "period_ms": 3, "homing": None},
    "sync_setpoint": {"profile": "sync_setpoint", "period_ms": 3},
    "parker_slvdn": {"profile": "parker_slvdn", "period_ms": 3, "homing": None},
}


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_every_profile_writes_and_reads_back_its_limit_objects(profile: str, make_rig: Callable[..., object]) -> None:
    gantry3: CellConfig = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
    cell = with_profiles(gantry3, {"x": PROFILES[profile]}, 3.0)
    rig = make_rig(cell)
    x = cell.axis_for_joint("x")
    drive = rig.sim.drive("x")
    stored = {  # what a vendor tool left on the drive
        (od.MAX_PROFILE_VELOCITY, 0): 9999,
        (od.MAX_ACCELERATION, 0): 123456,
        (od.SOFTWARE_POSITION_LIMIT, 1): -5,
        (od.SOFTWARE_POSITION_LIMIT, 2): 5,
        (od.MAX_FOLLOWING_ERROR, 0): 77,
        (od.QUICK_STOP_DECELERATION, 0): 4242,
    }
    for (index, sub), value in stored.items():
        drive.store(index, sub, value)
    rig.group.configure()
    settings = expected_settings(x)
    assert {(s.index, s.subindex) for s in settings} == set(stored)
    for s in settings:
        assert drive.read(s.index, s.subindex) == s.value, s.where


def test_the_quick_stop_option_the_master_loss_reaction_relies_on_is_written(make_rig: Callable[..., object]) -> None:
    """0x6007 = 3 (quick stop on a lost master) brakes as 0x605A says: a drive a tool left on 0
    (power stage off: the axis coasts) gets 2, the quick stop ramp, and reads it back."""
    rig = make_rig(load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml"))
    for drive in rig.sim:
        drive.store(od.QUICK_STOP_OPTION_CODE, 0, 0)
    rig.group.configure()
    assert all(d.read(od.QUICK_STOP_OPTION_CODE) == od.QUICK_STOP_ON_QUICK_STOP_RAMP for d in rig.sim)
