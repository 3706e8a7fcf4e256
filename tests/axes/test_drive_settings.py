"""Every profile writes the drive's limit objects from the axis (0x607F, 0x60C5, 0x607D, 0x6065)
where the drive has them and reads them back: what a vendor tool stored does not stay."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from axes_rig import with_profiles

from axes import objects as od
from axes.profiles import expected_settings
from service.config import CONFIG_DIR, CellConfig, load_cell_config

PROFILES = {
    "epos2_pvt": {},
    "cia402_ip_linear": {"profile": "cia402_ip_linear", "period_ms": 3, "homing": None},
    "sync_setpoint": {"profile": "sync_setpoint", "period_ms": 3},
    "parker_slvdn": {"profile": "parker_slvdn", "homing": None},
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
    }
    for (index, sub), value in stored.items():
        drive.store(index, sub, value)
    rig.group.configure()
    settings = expected_settings(x)
    assert {(s.index, s.subindex) for s in settings} == set(stored)
    for s in settings:
        assert drive.read(s.index, s.subindex) == s.value, s.where
