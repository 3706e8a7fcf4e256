"""Homing in a cell file: an axis's ``homing`` section and the cell's ``homing_order``.

A method the drive's profile has (CiA 402 homing mode 6), speeds within the drive's 0x607F; the order
in stages of joints homed together, every axis with homing in one stage.
"""

from __future__ import annotations

from typing import Any

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import HomingConfig
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.scaling import INT32_MAX, INT32_MIN, DriveLimits
from pvtflow.service.config.fields import Fields

HOMING_FIELDS = (
    "method",
    "switch_speed_rpm",
    "zero_speed_rpm",
    "acceleration_rpm_s",
    "offset_qc",
    "current_threshold_ma",
    "timeout_s",
    "overtravel_qc",
)


def parse_homing(f: Fields, profile: DriveProfile, limits: DriveLimits) -> HomingConfig:
    """``axes[i].homing``: the method (its 0x6098 number or its name in axes.drive.objects.HomingMethod) the
    profile has, speeds within the drive's 0x607F, the home offset, the hard-stop current threshold."""
    methods = profile.spec.homing_methods
    if not methods:
        raise f.error("homing", f"the {profile} profile has no homing mode (0x6060 = 6)")
    h = Fields(f.file, f.path("homing"), f.data["homing"], HOMING_FIELDS)

    def method_of(key: str, v: Any) -> int:
        if isinstance(v, str) and v.upper() in od.HomingMethod.__members__:
            return int(od.HomingMethod[v.upper()])
        if isinstance(v, bool) or not isinstance(v, int) or v not in methods:
            have = ", ".join(f"{int(m)} {od.HomingMethod(m).name.lower()}" for m in sorted(methods))
            raise h.error(key, f"{v!r} is not a homing method of {profile} (one of: {have})")
        return v

    method = h.get("method", method_of)
    if method not in methods:
        raise h.error("method", f"{od.HomingMethod(method).name.lower()} is not a homing method of {profile}")
    d = HomingConfig(method)
    speeds = {}
    for key, default in (("switch_speed_rpm", d.switch_speed_rpm), ("zero_speed_rpm", d.zero_speed_rpm)):
        speeds[key] = h.get(key, h.number(positive=True), default)
        if speeds[key] > limits.max_profile_velocity_rpm:
            raise h.error(
                key,
                f"{speeds[key]:g} rpm is above the drive's max profile velocity "
                f"({limits.max_profile_velocity_rpm:g} rpm)",
            )
    threshold = h.get("current_threshold_ma", h.integer(1, 65535), None)
    if threshold is not None and method >= 0:
        raise h.error("current_threshold_ma", "only the hard-stop methods (-1 to -4) use a current threshold")
    return HomingConfig(
        method=method,
        switch_speed_rpm=speeds["switch_speed_rpm"],
        zero_speed_rpm=speeds["zero_speed_rpm"],
        acceleration_rpm_s=h.get("acceleration_rpm_s", h.number(positive=True), d.acceleration_rpm_s),
        offset_qc=h.get("offset_qc", h.integer(INT32_MIN, INT32_MAX), d.offset_qc),
        current_threshold_ma=threshold,
        timeout_s=h.get("timeout_s", h.number(positive=True), d.timeout_s),
        overtravel_qc=h.get("overtravel_qc", h.integer(0, INT32_MAX), None),
    )


def parse_homing_order(top: Fields, homing: list[str], joints: list[str]) -> tuple[tuple[str, ...], ...]:
    """``homing_order``: a list of stages, each a joint or a list of joints homed together."""
    raw = top.get("homing_order", lambda k, v: v, None)
    if raw is None:
        return ()
    if not isinstance(raw, list) or not raw:
        raise top.error("homing_order", "must be a list of stages (a joint, or a list of joints homed together)")
    seen: set[str] = set()
    stages: list[tuple[str, ...]] = []
    for i, entry in enumerate(raw):
        names = entry if isinstance(entry, list) else [entry]
        where = f"homing_order[{i}]"
        if not names:
            raise top.error(where, "an empty stage")
        for name in names:
            if not isinstance(name, str) or name not in joints:
                raise top.error(where, f"unknown joint {name!r} (the cell has {', '.join(joints)})")
            if name not in homing:
                raise top.error(where, f"joint {name!r} has no homing section: nothing to home")
            if name in seen:
                raise top.error(where, f"joint {name!r} is in the order twice")
            seen.add(name)
        stages.append(tuple(names))
    missing = [j for j in homing if j not in seen]
    if missing:
        raise top.error("homing_order", f"leaves out {', '.join(missing)}: every axis with homing needs its stage")
    return tuple(stages)
