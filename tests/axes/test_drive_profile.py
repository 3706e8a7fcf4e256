"""One description per drive profile (axes/drive/drive_profile.py), asked by every layer."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.drive_profile import DriveProfile, ProfileError
from pvtflow.axes.drive.interpolation import Interpolation
from pvtflow.axes.drive.objects import EPOS2_BUFFER_SIZE, MAXON_EPOS2_70_10, SIMULATED_VENDOR_ID
from pvtflow.axes.drive.program import AxisProgram
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits

E, L, S, P = (
    DriveProfile.EPOS2_PVT,
    DriveProfile.CIA402_IP_LINEAR,
    DriveProfile.SYNC_SETPOINT,
    DriveProfile.PARKER_SLVDN,
)


def test_a_cell_file_name_is_its_profile_and_an_unknown_one_is_named() -> None:
    assert DriveProfile.parse("parker_slvdn") is P and P == "parker_slvdn"
    with pytest.raises(ValueError, match="unknown drive profile 'epos4' \\(one of epos2_pvt, cia402_ip_linear"):
        DriveProfile.parse("epos4")


def test_buffered_or_fixed_period() -> None:
    assert E.buffered and not E.fixed_period and E.spec.buffer_records == EPOS2_BUFFER_SIZE
    for profile in (L, S, P):
        assert profile.fixed_period and not profile.buffered and profile.spec.shortest_period_ms == 1.0


@pytest.mark.parametrize(
    ("profile", "period_ms", "submode", "kind"),
    [
        (E, None, None, Interpolation.PVT),
        (L, 1, None, Interpolation.LINEAR),
        (S, 4, None, Interpolation.LINEAR),
        (P, 2, -1, Interpolation.LINEAR),  # below 2.5 ms the Parker's position loop takes each setpoint
        (P, 2, -2, Interpolation.LINEAR),
        (P, 3, 0, Interpolation.LINEAR),
        (P, 3, -1, Interpolation.CUBIC_PV),
        (P, 3, -2, Interpolation.CUBIC_P),
        (P, 3, None, Interpolation.CUBIC_PV),  # its default submode, -1
    ],
)
def test_the_reconstruction_for_a_period_and_submode(
    profile: DriveProfile, period_ms: int | None, submode: int | None, kind: Interpolation
) -> None:
    assert profile.reconstruction(period_ms, submode) is kind


def test_a_program_reconstructs_as_its_profile_says() -> None:
    """A Parker program without a submode is the drive's default (-1), as the bus configures it."""
    records = np.array([[0, 0, 3], [30, 40, 3], [90, 40, 3], [120, 0, 3], [120, 0, 3]], dtype=np.int64)
    axis = AxisProgram(
        "x", 1, "parker_slvdn", AxisScaling(4096, 1.0), DriveLimits(3000, 1e5, -(10**6), 10**6), records=records
    )
    assert axis.profile is P and axis.period_ms == 3
    assert axis.reconstruction().interpolation is Interpolation.CUBIC_PV


def test_which_records_carry_velocities() -> None:
    assert E.carries_velocity() and not L.carries_velocity() and not S.carries_velocity()
    assert P.carries_velocity(-1) and P.carries_velocity(None) and not P.carries_velocity(-2)
    assert not P.carries_velocity(0)


def test_an_axis_setting_the_profile_does_not_take_names_its_field() -> None:
    assert P.settings(3.0, None, None) == (3, -1)
    assert E.settings(5.0, None, None) == (None, None)
    cases = [
        (L, 0.5, None, None, "profile", "shortest SYNC period pvtflow holds for it is 1 ms"),
        (L, 2.5, None, None, "period_ms", "not a whole number of ms"),
        (S, 200.0, None, None, "period_ms", "takes 1 to 100 ms per setpoint"),
        (L, 2.0, 4, None, "period_ms", "must equal bus.sync_period_ms (2)"),
        (E, 2.0, 2, None, "period_ms", "only fixed-period profiles (cia402_ip_linear, sync_setpoint, parker_slvdn)"),
        (L, 2.0, None, -1, "interpolation_submode", "the cia402_ip_linear profile has no interpolation submodes"),
        (P, 3.0, None, -3, "interpolation_submode", "-3 is not one of parker_slvdn's (0, -1, -2)"),
    ]
    for profile, sync, period, submode, field, text in cases:
        with pytest.raises(ProfileError, match=None) as info:
            profile.settings(sync, period, submode)
        assert info.value.field == field and text in info.value.problem, info.value


def test_the_drives_a_profile_may_find() -> None:
    ids = E.identities
    assert ids[0].vendor_id == SIMULATED_VENDOR_ID and MAXON_EPOS2_70_10 in ids
    assert len({p.spec.product_code for p in DriveProfile}) == len(DriveProfile)
    assert all(len(p.identities) == 1 for p in (L, S, P))
