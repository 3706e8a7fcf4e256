"""Cell configuration: the robot, its CAN bus and its axes, read from YAML and checked field by field.

Every problem is reported as ``FILE: FIELD: PROBLEM`` (a :class:`ConfigError`), never as a
traceback, so that a commissioning engineer can fix the file without reading code.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml
from can.interfaces import VALID_INTERFACES
from numpy.typing import NDArray

from axes import objects as od
from axes.budget import bus_budget
from axes.config import (
    SIMULATION_INTERFACES,
    AxisConfig,
    AxisSimulation,
    BufferConfig,
    BusConfig,
    HomingConfig,
    homing_stop_room,
)
from axes.drive_profile import DriveProfile, ProfileError
from axes.homing import homing_stages
from axes.scaling import INT32_MAX, INT32_MIN, AxisScaling, DriveLimits
from planner.limits import JointLimits, joint_limits_from_drives
from planner.model import ModelError, RobotModel

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
DEFAULT_CELL = CONFIG_DIR / "cells" / "arm6.yaml"
ROBOTS_DIR = CONFIG_DIR / "robots"  # the shipped robots a cell file may name (robot.name)

# python-can's own list of interfaces (``udp_multicast`` among them: it sends to a multicast group,
# off this host, so the tests never name it).
PYTHON_CAN_INTERFACES: tuple[str, ...] = tuple(sorted(VALID_INTERFACES))


class ConfigError(ValueError):
    """A cell configuration problem: which file, which field, what is wrong."""

    def __init__(self, file: str | Path, where: str, problem: str) -> None:
        self.file = str(file)
        self.where = where
        self.problem = problem
        super().__init__(f"{self.file}: {where}: {problem}" if where else f"{self.file}: {problem}")


@dataclass(frozen=True)
class PlanningConfig:
    tcp_frame: str | None = None
    max_tcp_speed: float | None = None  # m/s
    max_tcp_angular_speed: float | None = None  # rad/s
    torque_limits: bool = True  # only where the URDF has effort limits and masses
    position_tolerance_qc: float = 1.0
    budget_ms: float = 200.0  # a plan's deadline when its request sets none (service/cell_planner.py)
    # joint units / s^3 per joint in the model's joint order (inf: that axis sets none); None: no axis sets one
    max_jerk: tuple[float, ...] | None = None


@dataclass(frozen=True)
class CellConfig:
    name: str
    source: Path
    urdf: Path
    bus: BusConfig
    axes: tuple[AxisConfig, ...]
    planning: PlanningConfig
    simulated: bool
    model: RobotModel = field(repr=False, compare=False)
    homing_order: tuple[tuple[str, ...], ...] = ()  # stages of joints homed together (empty: one at a time)
    requires_homing: bool = False  # motion is refused (not_homed) until every axis has homed since it booted

    def homing_stages(self, joints: list[str] | None = None) -> list[list[str]]:
        """The stages to home ``joints`` (None: every axis with homing) in (axes.homing.homing_stages)."""
        return homing_stages(self.ordered_axes(), self.homing_order, joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint order of every plan and program: the robot model's order."""
        return self.model.joint_names

    def axis_for_joint(self, joint: str) -> AxisConfig:
        for a in self.axes:
            if a.joint == joint:
                return a
        raise KeyError(joint)

    def ordered_axes(self) -> tuple[AxisConfig, ...]:
        """The axes in the model's joint order."""
        return tuple(self.axis_for_joint(j) for j in self.joint_names)

    def home_position(self) -> NDArray[np.float64]:
        """Where the axes stand after homing, in joint units (the cell's joint order): each axis's home
        position reads its 0x607C (``homing.offset_qc``). ValueError naming the axes without a homing
        section (they have no home: an absolute encoder stands where it stood)."""
        axes = self.ordered_axes()
        missing = [a.joint for a in axes if a.homing is None]
        if missing:
            raise ValueError(
                f"cell {self.name} has no home position: {', '.join(missing)} "
                f"{'has' if len(missing) == 1 else 'have'} no homing section"
            )
        return np.array([float(a.scaling.qc_to_position(a.homing.offset_qc)) for a in axes])  # type: ignore[union-attr]

    def joint_limits(self) -> JointLimits:
        """Joint-space limits: the drives' (through the scaling) merged with the URDF's."""
        axes = self.ordered_axes()
        return joint_limits_from_drives(
            self.joint_names, [a.scaling for a in axes], [a.limits for a in axes]
        ).merged_with(JointLimits.from_model(self.model))


# --- reading ---------------------------------------------------------------------------------------
T = TypeVar("T")


class _Fields:
    """Reads one YAML mapping, naming the file and the field in every error."""

    def __init__(self, file: Path, where: str, data: Any, allowed: tuple[str, ...]) -> None:
        self.file = file
        self.where = where
        if not isinstance(data, Mapping):
            raise ConfigError(file, where or "(top level)", f"must be a mapping, got {type(data).__name__}")
        self.data = data
        unknown = [k for k in data if k not in allowed]
        if unknown:
            raise ConfigError(file, self.path(str(unknown[0])), f"unknown field (allowed: {', '.join(allowed)})")

    def path(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def error(self, key: str, problem: str) -> ConfigError:
        return ConfigError(self.file, self.path(key), problem)

    def get(self, key: str, convert: Callable[[str, Any], T], default: Any = ...) -> T:
        if key not in self.data or self.data[key] is None:
            if default is ...:
                raise self.error(key, "missing")
            return default
        return convert(key, self.data[key])

    # converters -------------------------------------------------------------------------------
    def number(self, positive: bool = False) -> Callable[[str, Any], float]:
        def conv(key: str, v: Any) -> float:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise self.error(key, f"must be a finite number, got {v!r}")
            if positive and v <= 0:
                raise self.error(key, f"must be positive, got {v!r}")
            return float(v)

        return conv

    def integer(self, lo: int, hi: int) -> Callable[[str, Any], int]:
        def conv(key: str, v: Any) -> int:
            if isinstance(v, bool) or not isinstance(v, int):
                raise self.error(key, f"must be an integer, got {v!r}")
            if not lo <= v <= hi:
                raise self.error(key, f"{v} is outside [{lo}, {hi}]")
            return v

        return conv

    def string(self, key: str, v: Any) -> str:
        if not isinstance(v, str) or not v:
            raise self.error(key, f"must be a non-empty string, got {v!r}")
        return v

    def boolean(self, key: str, v: Any) -> bool:
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v


def load_cell_config(path: str | Path | None = None) -> CellConfig:
    """Read and check a cell YAML file (the demo arm cell when no path is given)."""
    file = Path(path) if path is not None else DEFAULT_CELL
    if not file.is_file():
        raise ConfigError(file, "", "file not found")
    try:
        data = yaml.safe_load(file.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(file, "", f"not UTF-8 text (byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise _yaml_error(file, exc) from None
    return parse_cell_config(data, file)


def _yaml_error(file: Path, exc: yaml.YAMLError) -> ConfigError:
    """A YAML syntax error in one line, ``FILE: line L, column C: not valid YAML: PROBLEM (CONTEXT)``, like every
    other mistake in a cell file (PyYAML's own message spans several lines and quotes the source)."""
    if not isinstance(exc, yaml.MarkedYAMLError) or exc.problem_mark is None:
        return ConfigError(file, "", f"not valid YAML: {' '.join(str(exc).split())}")
    mark = exc.problem_mark
    problem = f"line {mark.line + 1}, column {mark.column + 1}: not valid YAML: {exc.problem}"
    if exc.context:
        context = exc.context
        if exc.context_mark is not None and exc.context_mark.line != mark.line:
            context += f" from line {exc.context_mark.line + 1}"
        problem += f" ({context})"
    return ConfigError(file, "", problem)  # no field: the file is not YAML yet


def shipped_robots() -> list[str]:
    """The robots pvtflow ships (configs/robots/NAME.urdf), by name."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.urdf"))


def _robot_urdf(robot: _Fields, file: Path) -> Path:
    """The cell's URDF: ``robot.name`` names a shipped robot (so a copied cell file keeps working
    wherever it goes); ``robot.urdf`` is a file, relative to the cell file. A URDF not found that
    has a shipped robot's name says which file to copy along, or the ``name`` to give instead."""
    if ("name" in robot.data) == ("urdf" in robot.data):
        raise robot.error("name", "give the robot's name (a shipped robot) or its urdf (a file), one of them")
    if "name" in robot.data:
        name = robot.get("name", robot.string)
        urdf = ROBOTS_DIR / f"{name}.urdf"
        if not urdf.is_file():
            raise robot.error("name", f"no shipped robot {name!r} (shipped: {', '.join(shipped_robots())})")
        return urdf.resolve()
    urdf = (file.parent / robot.get("urdf", robot.string)).resolve()
    if urdf.is_file():
        return urdf
    hint = ""
    if urdf.stem in shipped_robots():
        hint = (
            f"; it is a shipped robot: write `robot: {{name: {urdf.stem}}}` instead, or copy "
            f"{ROBOTS_DIR / urdf.name} along (the path is relative to the cell file)"
        )
    raise robot.error("urdf", f"URDF file not found: {urdf}{hint}")


def parse_cell_config(data: Any, file: Path) -> CellConfig:
    top = _Fields(
        file, "", data, ("name", "robot", "bus", "axes", "planning", "simulated", "homing_order", "requires_homing")
    )
    name = top.get("name", top.string)

    robot = (
        _Fields(file, "robot", top.data.get("robot"), ("name", "urdf", "tcp_frame")) if "robot" in top.data else None
    )
    if robot is None:
        raise top.error("robot", "missing")
    urdf = _robot_urdf(robot, file)
    try:
        model = RobotModel.from_urdf(urdf)
    except ModelError as exc:
        raise robot.error("urdf", str(exc)) from None
    tcp_frame = robot.get("tcp_frame", robot.string, None)
    if tcp_frame is not None and not model.model.existFrame(tcp_frame):
        raise robot.error("tcp_frame", f"the URDF has no frame {tcp_frame!r}")

    bus = _parse_bus(file, top.data.get("bus", {}))
    planning = _parse_planning(file, top.data.get("planning", {}), tcp_frame, model)
    simulated = top.get("simulated", top.boolean, bus.interface in SIMULATION_INTERFACES)
    if simulated and bus.interface not in SIMULATION_INTERFACES:
        raise top.error(
            "simulated",
            f"simulated drives on interface {bus.interface} would answer with the real drives' node ids: "
            f"simulate on {' or '.join(sorted(SIMULATION_INTERFACES))}, or set simulated: false",
        )

    axes_data = top.get("axes", lambda k, v: v)
    if not isinstance(axes_data, list) or not axes_data:
        raise top.error("axes", "must be a non-empty list of axes")
    axes: list[AxisConfig] = []
    jerk: dict[str, float] = {}  # joint -> its axis's max_jerk
    for i, a in enumerate(axes_data):
        axis, max_jerk = _parse_axis(file, f"axes[{i}]", a, model, bus)
        axes.append(axis)
        if max_jerk is not None:
            jerk[axis.joint] = max_jerk

    seen_joint: dict[str, int] = {}
    seen_node: dict[int, int] = {}
    for i, a in enumerate(axes):
        if a.joint in seen_joint:
            raise ConfigError(
                file, f"axes[{i}].joint", f"joint {a.joint!r} already has an axis (axes[{seen_joint[a.joint]}])"
            )
        if a.node_id in seen_node:
            raise ConfigError(
                file, f"axes[{i}].node_id", f"duplicate node id {a.node_id} (also axes[{seen_node[a.node_id]}])"
            )
        seen_joint[a.joint] = i
        seen_node[a.node_id] = i
    if bus.master_node_id in seen_node:
        i = seen_node[bus.master_node_id]
        raise ConfigError(
            file,
            "bus.master_node_id",
            f"{bus.master_node_id} is the node id of axes[{i}] ({axes[i].joint}): the master's heartbeat "
            "needs a node id no drive uses",
        )
    for joint in model.joint_names:
        if joint not in seen_joint:
            raise ConfigError(file, "axes", f"joint {joint!r} of the URDF has no axis")

    homing = [a.joint for a in axes if a.homing is not None]
    order = _parse_homing_order(top, homing, [a.joint for a in axes])
    requires = top.get("requires_homing", top.boolean, bool(homing))
    if requires and not homing:
        raise top.error("requires_homing", "no axis has a homing section: nothing to home")
    if jerk:
        planning = replace(planning, max_jerk=tuple(jerk.get(j, math.inf) for j in model.joint_names))
    cell = CellConfig(name, file, urdf, bus, tuple(axes), planning, simulated, model, order, requires)
    _check_limits_consistent(file, cell)
    _check_bus_budget(file, cell)
    return cell


def _check_bus_budget(file: Path, cell: CellConfig) -> None:
    """The cell's traffic per SYNC period must fit its bus (axes.budget: 70 % of the bit rate)."""
    problem = bus_budget(cell).problem()
    if problem is not None:
        raise ConfigError(file, "bus", problem)


def _parse_homing_order(top: _Fields, homing: list[str], joints: list[str]) -> tuple[tuple[str, ...], ...]:
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


def _parse_bus(file: Path, data: Any) -> BusConfig:
    f = _Fields(
        file,
        "bus",
        data,
        (
            "interface",
            "channel",
            "bitrate",
            "sync_period_ms",
            "time_stamp",
            "heartbeat_ms",
            "heartbeat_timeout_factor",
            "master_node_id",
            "master_heartbeat_ms",
            "max_sync_gap_periods",
            "sync_priority",
            "tx_retry_ms",
            "quick_stop_confirm_ms",
            "records_per_sync",
            "tx_queue_frames",
            "status_every_syncs",
            "status_inhibit_ms",
            "status_event_timer_ms",
        ),
    )
    d = BusConfig()
    interface = f.get("interface", f.string, d.interface)
    if interface not in PYTHON_CAN_INTERFACES:
        raise f.error("interface", f"unknown python-can interface {interface!r}")
    channel = f.get("channel", lambda k, v: f.string(k, str(v)), d.channel)
    bitrate = f.get("bitrate", f.integer(10_000, 1_000_000), d.bitrate)
    sync = f.get("sync_period_ms", f.number(positive=True), d.sync_period_ms)
    if not 0.1 <= sync <= 255:
        raise f.error("sync_period_ms", f"{sync} ms is outside [0.1, 255]")
    factor = f.get("heartbeat_timeout_factor", f.number(positive=True), d.heartbeat_timeout_factor)
    if factor <= 1:
        raise f.error(
            "heartbeat_timeout_factor",
            f"{factor:g} would count a node lost between two of its heartbeats: must be above 1",
        )
    bus = BusConfig(
        interface=interface,
        channel=channel,
        bitrate=bitrate,
        sync_period_ms=sync,
        time_stamp=f.get("time_stamp", f.boolean, d.time_stamp),
        heartbeat_ms=f.get("heartbeat_ms", f.integer(1, 65535), d.heartbeat_ms),
        heartbeat_timeout_factor=factor,
        master_node_id=f.get("master_node_id", f.integer(1, 127), d.master_node_id),
        master_heartbeat_ms=f.get("master_heartbeat_ms", f.integer(1, 65535), d.master_heartbeat_ms),
        max_sync_gap_periods=f.get("max_sync_gap_periods", f.number(positive=True), d.max_sync_gap_periods),
        sync_priority=f.get("sync_priority", f.integer(0, 99), d.sync_priority),
        tx_retry_ms=f.get("tx_retry_ms", f.number(positive=True), d.tx_retry_ms),
        quick_stop_confirm_ms=f.get("quick_stop_confirm_ms", f.number(positive=True), d.quick_stop_confirm_ms),
        records_per_sync=f.get("records_per_sync", f.integer(1, 1000), d.records_per_sync),
        tx_queue_frames=f.get("tx_queue_frames", f.integer(2, 100000), d.tx_queue_frames),
        status_every_syncs=f.get("status_every_syncs", f.integer(1, 240), d.status_every_syncs),
        status_inhibit_ms=f.get("status_inhibit_ms", f.number(positive=True), d.status_inhibit_ms),
        status_event_timer_ms=f.get("status_event_timer_ms", f.integer(0, 65535), d.status_event_timer_ms),
    )
    if bus.status_inhibit_ms is not None and bus.status_inhibit_ms > 6553.5:
        raise f.error("status_inhibit_ms", f"{bus.status_inhibit_ms:g} ms: 0x1800:03 holds at most 6553.5 ms")
    if bus.max_sync_gap_periods is not None and bus.max_sync_gap_periods < 1.5:
        raise f.error(
            "max_sync_gap_periods",
            f"{bus.max_sync_gap_periods:g} periods: a gap of one period is every SYNC; at least 1.5",
        )
    if bus.master_consumer_time_ms > 0xFFFF:
        raise f.error(
            "master_heartbeat_ms",
            f"the drives would wait {bus.master_consumer_time_ms} ms (master_heartbeat_ms x heartbeat_timeout_factor) "
            "for the master's heartbeat: 0x1016 holds at most 65535 ms",
        )
    return bus


def _parse_planning(file: Path, data: Any, tcp_frame: str | None, model: RobotModel) -> PlanningConfig:
    f = _Fields(
        file,
        "planning",
        data,
        ("max_tcp_speed", "max_tcp_angular_speed", "torque_limits", "position_tolerance_qc", "budget_ms"),
    )
    max_tcp = f.get("max_tcp_speed", f.number(positive=True), None)
    if max_tcp is not None and tcp_frame is None:
        raise f.error("max_tcp_speed", "needs robot.tcp_frame to know which frame to limit")
    max_turn = f.get("max_tcp_angular_speed", f.number(positive=True), None)
    if max_turn is not None and tcp_frame is None:
        raise f.error("max_tcp_angular_speed", "needs robot.tcp_frame to know which frame to limit")
    torque = f.get("torque_limits", f.boolean, True)
    return PlanningConfig(
        tcp_frame=tcp_frame,
        max_tcp_speed=max_tcp,
        max_tcp_angular_speed=max_turn,
        torque_limits=torque and model.has_dynamics,
        position_tolerance_qc=f.get("position_tolerance_qc", f.number(positive=True), 1.0),
        budget_ms=f.get("budget_ms", f.number(positive=True), PlanningConfig.budget_ms),
    )


def _parse_axis(
    file: Path, where: str, data: Any, model: RobotModel, bus: BusConfig
) -> tuple[AxisConfig, float | None]:
    """The axis, and its joint's jerk limit for planning (joint units / s^3; None: unlimited)."""
    f = _Fields(
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

    s = _Fields(
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

    lf = _Fields(
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
        b = _Fields(file, f.path("buffer"), f.data["buffer"], ("underflow_warning", "overflow_warning"))
        size = profile.spec.buffer_records
        buffer = BufferConfig(
            underflow_warning=b.get("underflow_warning", b.integer(0, size - 1), buffer.underflow_warning),
            overflow_warning=b.get("overflow_warning", b.integer(1, size), buffer.overflow_warning),
        )
        if buffer.underflow_warning + 2 > buffer.overflow_warning:
            raise b.error("overflow_warning", "must be at least 2 above underflow_warning")
    homing = _parse_homing(f, profile, limits) if "homing" in f.data else None
    simulation = _parse_simulation(f) if "simulation" in f.data else None
    if homing is not None and (why := homing_stop_room(homing, scaling, simulation)) is not None:
        raise ConfigError(file, f.path("homing"), why)
    identity = None
    if "identity" in f.data:  # the drive's 0x1018:01/:02 where the profile's known drives do not list it
        i = _Fields(file, f.path("identity"), f.data["identity"], ("vendor_id", "product_code"))
        u32 = i.integer(0, 2**32 - 1)
        identity = (i.get("vendor_id", u32), i.get("product_code", u32))
    max_jerk = f.get("max_jerk", f.number(positive=True), None)
    axis = AxisConfig(joint, node_id, profile, scaling, limits, period, submode, buffer, homing, simulation, identity)
    return axis, max_jerk


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


def _parse_homing(f: _Fields, profile: DriveProfile, limits: DriveLimits) -> HomingConfig:
    """``axes[i].homing``: the method (its 0x6098 number or its name in axes.objects.HomingMethod) the
    profile has, speeds within the drive's 0x607F, the home offset, the hard-stop current threshold."""
    methods = profile.spec.homing_methods
    if not methods:
        raise f.error("homing", f"the {profile} profile has no homing mode (0x6060 = 6)")
    h = _Fields(f.file, f.path("homing"), f.data["homing"], HOMING_FIELDS)

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


def _parse_simulation(f: _Fields) -> AxisSimulation:
    """``axes[i].simulation``: the simulated machine around the axis (qc of the machine)."""
    keys = tuple(AxisSimulation.__dataclass_fields__)
    s = _Fields(f.file, f.path("simulation"), f.data["simulation"], keys)
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


def _check_limits_consistent(file: Path, cell: CellConfig) -> None:
    """The drive's 0x607D must leave the joint somewhere to be: an empty intersection is a typo."""
    limits = cell.joint_limits()
    for k, joint in enumerate(cell.joint_names):
        if limits.lower[k] >= limits.upper[k]:
            i = cell.axes.index(cell.axis_for_joint(joint))
            raise ConfigError(
                file,
                f"axes[{i}].limits",
                f"0x607D [{cell.axes[i].limits.min_position_qc}, {cell.axes[i].limits.max_position_qc}] qc "
                f"does not overlap the URDF range of {joint!r}",
            )
