"""One entry of the cell file's ``axes``: the joint, its drive (node id, profile, scaling, limit
objects, buffer), its identity, its jerk limit, and the simulated machine around it (``simulation``).

The homing section of an axis is read by service.config.homing_section.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pvtflow.axes.drive.config import AxisConfig, AxisSimulation, BufferConfig, BusConfig, homing_stop_room
from pvtflow.axes.drive.drive_profile import DriveProfile, ProfileError
from pvtflow.axes.drive.scaling import INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from pvtflow.axes.master.commission import REQUIRABLE_OBJECTS
from pvtflow.axes.sim.drive import eds_file
from pvtflow.planner.model import RobotModel
from pvtflow.service.config.fields import ConfigError, Fields
from pvtflow.service.config.homing_section import parse_homing


def parse_axis(file: Path, where: str, data: Any, model: RobotModel, bus: BusConfig) -> tuple[AxisConfig, float | None]:
    """The axis, and its joint's jerk limit for planning (joint units / s^3; None: unlimited)."""
    f = Fields(
        file,
        where,
        data,
        (
            "joint",
            "node_id",
            "profile",
            "scaling",
            "limits",
            "period_ms",
            "interpolation_submode",
            "buffer",
            "max_jerk",
            "homing",
            "simulation",
            "identity",
            "commission_requires",
        ),
    )
    joint = f.get("joint", f.string)
    if joint not in model.joint_names:
        raise f.error("joint", f"unknown joint {joint!r}: the URDF has {', '.join(model.joint_names)}")
    kind = model.joints[model.index(joint)].kind
    node_id = f.get("node_id", f.integer(1, 127))
    try:
        profile = DriveProfile.parse(f.get("profile", f.string))
    except ValueError as exc:
        raise f.error("profile", str(exc)) from None

    s = Fields(
        file,
        f.path("scaling"),
        f.get("scaling", lambda k, v: v),
        ("qc_per_motor_rev", "gear_ratio", "lead_m", "velocity_unit_rpm", "position_offset_qc"),
    )
    qc = s.get("qc_per_motor_rev", s.number(positive=True))
    gear = s.get("gear_ratio", s.number(), 1.0)
    if gear == 0:
        raise s.error("gear_ratio", "must not be zero (negative inverts the direction)")
    vel_unit = s.get("velocity_unit_rpm", s.number(positive=True), 1.0)
    offset = s.get("position_offset_qc", s.integer(INT32_MIN, INT32_MAX), 0)
    if kind == "prismatic":
        lead = s.get("lead_m", s.number(positive=True))
        scaling = AxisScaling.prismatic(qc, lead, gear, vel_unit, offset)
    else:
        if "lead_m" in s.data:
            raise s.error("lead_m", f"joint {joint!r} is revolute: give gear_ratio only")
        scaling = AxisScaling.revolute(qc, gear, vel_unit, offset)

    lf = Fields(
        file,
        f.path("limits"),
        f.get("limits", lambda k, v: v),
        (
            "max_profile_velocity_rpm",
            "max_acceleration_rpm_s",
            "min_position_qc",
            "max_position_qc",
            "profile_velocity_rpm",
            "profile_acceleration_rpm_s",
        ),
    )
    lo = lf.get("min_position_qc", lf.integer(INT32_MIN, INT32_MAX))
    hi = lf.get("max_position_qc", lf.integer(INT32_MIN, INT32_MAX))
    if lo >= hi:
        raise lf.error("max_position_qc", f"must be above min_position_qc ({hi} <= {lo})")
    limits = DriveLimits(
        max_profile_velocity_rpm=lf.get("max_profile_velocity_rpm", lf.number(positive=True)),
        max_acceleration_rpm_s=lf.get("max_acceleration_rpm_s", lf.number(positive=True)),
        min_position_qc=lo,
        max_position_qc=hi,
        profile_velocity_rpm=lf.get("profile_velocity_rpm", lf.number(positive=True), None),
        profile_acceleration_rpm_s=lf.get("profile_acceleration_rpm_s", lf.number(positive=True), None),
    )

    period = f.get("period_ms", f.integer(1, 255), None)
    submode = f.get("interpolation_submode", f.integer(-(2**15), 2**15 - 1), None)  # 0x60C0, an INT16
    try:
        period, submode = profile.settings(bus.sync_period_ms, period, submode)
    except ProfileError as exc:
        raise f.error(exc.field, exc.problem) from None

    buffer = BufferConfig()
    if "buffer" in f.data:
        if not profile.buffered:
            buffered = ", ".join(p for p in DriveProfile if p.buffered)
            raise f.error("buffer", f"only buffered profiles ({buffered}) have a record buffer")
        b = Fields(file, f.path("buffer"), f.data["buffer"], ("underflow_warning", "overflow_warning"))
        size = profile.spec.buffer_records
        buffer = BufferConfig(
            underflow_warning=b.get("underflow_warning", b.integer(0, size - 1), buffer.underflow_warning),
            overflow_warning=b.get("overflow_warning", b.integer(1, size), buffer.overflow_warning),
        )
        if buffer.underflow_warning + 2 > buffer.overflow_warning:
            raise b.error("overflow_warning", "must be at least 2 above underflow_warning")
    homing = parse_homing(f, profile, limits) if "homing" in f.data else None
    simulation = _parse_simulation(f) if "simulation" in f.data else None
    if homing is not None and (why := homing_stop_room(homing, scaling, simulation)) is not None:
        raise ConfigError(file, f.path("homing"), why)
    identity = None
    if "identity" in f.data:  # the drive's 0x1018:01/:02 where the profile's known drives do not list it
        i = Fields(file, f.path("identity"), f.data["identity"], ("vendor_id", "product_code"))
        u32 = i.integer(0, 2**32 - 1)
        identity = (i.get("vendor_id", u32), i.get("product_code", u32))
    max_jerk = f.get("max_jerk", f.number(positive=True), None)
    requires = f.get("commission_requires", lambda k, v: _requirable_objects(f, k, v), ())
    axis = AxisConfig(
        joint, node_id, profile, scaling, limits, period, submode, buffer, homing, simulation, identity, requires
    )
    return axis, max_jerk


def _requirable_objects(f: Fields, key: str, v: Any) -> tuple[str, ...]:
    """``commission_requires``: a list of the objects of commissioning's FACT checks."""
    known = ", ".join(REQUIRABLE_OBJECTS)
    if not isinstance(v, list) or not all(isinstance(o, str) for o in v):
        raise f.error(key, f"must be a list of objects, each one of {known}")
    unknown = [o for o in v if o not in REQUIRABLE_OBJECTS]
    if unknown:
        raise f.error(key, f"{', '.join(unknown)}: not a commissioning check; one of {known}")
    return tuple(v)


def _shipped_eds(f: Fields, key: str, v: Any) -> str:
    """``simulation.eds``: the name of an EDS the project ships (configs/eds)."""
    if not isinstance(v, str):
        raise f.error(key, f"must be the name of an EDS under configs/eds, got {v!r}")
    try:
        eds_file(v)
    except ValueError as exc:
        raise f.error(key, str(exc)) from None
    return v


def _parse_simulation(f: Fields) -> AxisSimulation:
    """``axes[i].simulation``: the simulated machine around the axis (qc of the machine)."""
    keys = tuple(AxisSimulation.__dataclass_fields__)
    s = Fields(f.file, f.path("simulation"), f.data["simulation"], keys)
    d = AxisSimulation()
    qc = s.integer(INT32_MIN, INT32_MAX)
    values: dict[str, Any] = {}
    for key in keys:
        default = getattr(d, key)
        if key == "home_switch_active_above":
            values[key] = s.get(key, s.boolean, default)
        elif key in ("index_spacing_qc",):
            values[key] = s.get(key, s.integer(1, INT32_MAX), default)
        elif key in ("stall_current_ma", "moving_current_ma"):
            values[key] = s.get(key, s.integer(0, 65535), default)
        elif key == "seed":
            values[key] = s.get(key, s.integer(0, 2**31 - 1), default)
        elif key in ("qc_per_motor_rev", "max_motor_speed_rpm"):
            values[key] = s.get(key, s.integer(1, INT32_MAX), default)
        elif key == "polarity":
            values[key] = s.get(key, s.integer(0, 255), default)
        elif key in ("sensor_type", "sensor_polarity"):  # maxon's 0x2210:02 / :04 (UNSIGNED16)
            values[key] = s.get(key, s.integer(0, 65535), default)
        elif key == "eds":
            values[key] = s.get(key, lambda k, v: _shipped_eds(s, k, v), default)
        elif key == "velocity_notation_index":  # 0x608B (INTEGER8)
            values[key] = s.get(key, s.integer(-128, 127), default)
        elif key in ("vendor_id", "product_code"):
            values[key] = s.get(key, s.integer(0, 2**32 - 1), default)
        else:
            values[key] = s.get(key, qc, default)
    sim = AxisSimulation(**values)
    for lo, hi in (
        ("negative_limit_switch_qc", "positive_limit_switch_qc"),
        ("negative_hard_stop_qc", "positive_hard_stop_qc"),
    ):
        if values[lo] is not None and values[hi] is not None and values[lo] >= values[hi]:
            raise s.error(hi, f"must be above {lo} ({values[hi]} <= {values[lo]})")
    return sim
