"""Drive behaviours: one module per profile, each with its configuration, its feed, its delay, its end.

``AxisLink`` (``axes.master.link``) is the master's handle on one drive (SDO access by index, controlword,
the values its TPDOs bring); ``Profile`` (``axes.master.profiles.base``) is what a behaviour adds to it.
``profile_for(link)`` picks the module from ``AxisConfig.profile``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pvtflow.axes.master.link import DriveError

if TYPE_CHECKING:
    from pvtflow.axes.drive.drive_profile import DriveProfile
    from pvtflow.axes.master.link import AxisLink
    from pvtflow.axes.master.profiles.base import Profile


def profile_class(name: DriveProfile) -> type[Profile]:
    """The profile module's class by its name (KeyError: no such profile)."""
    from pvtflow.axes.master.profiles.cia402_ip_linear import Cia402IpLinear
    from pvtflow.axes.master.profiles.epos2_pvt import Epos2Pvt
    from pvtflow.axes.master.profiles.parker_slvdn import ParkerSlvdn
    from pvtflow.axes.master.profiles.sync_setpoint import SyncSetpoint

    classes = {c.name: c for c in (Epos2Pvt, Cia402IpLinear, SyncSetpoint, ParkerSlvdn)}
    return classes[name]


def profile_for(link: AxisLink) -> Profile:
    """The profile module named by the axis's configuration."""
    try:
        return profile_class(link.config.profile)(link)
    except KeyError:
        raise DriveError(link.node_id, f"unknown profile {link.config.profile!r}") from None
