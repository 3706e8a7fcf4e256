"""Reading a cell file: the YAML, its top level, and the checks across sections once the cell is whole.

The sections have a module each (robot, bus, axis, homing); here they are put together, every joint
of the URDF given one axis, node ids unique, the drives' limits overlapping the URDF's, and the
cell's traffic within its bus (axes.master.budget).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from pvtflow.axes.drive.config import SIMULATION_INTERFACES, AxisConfig
from pvtflow.axes.master.budget import bus_budget
from pvtflow.configs import DEFAULT_CELL, shipped_cell, shipped_cells
from pvtflow.planner.model import ModelError, RobotModel
from pvtflow.service.config.axis_section import parse_axis
from pvtflow.service.config.bus_section import parse_bus
from pvtflow.service.config.cell import CellConfig
from pvtflow.service.config.fields import ConfigError, Fields
from pvtflow.service.config.homing_section import parse_homing_order
from pvtflow.service.config.robot_section import parse_planning, robot_urdf


def load_cell_config(path: str | Path | None = None) -> CellConfig:
    """Read and check a cell YAML file, or the shipped cell ``path`` names (``arm6``), or the demo arm cell
    when no path is given."""
    file = cell_file(path)
    if not file.is_file():
        hint = f" (nor a shipped cell: {', '.join(shipped_cells())})" if file.parent == Path() else ""
        raise ConfigError(file, "", f"file not found{hint}")
    try:
        data = yaml.safe_load(file.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(file, "", f"not UTF-8 text (byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise _yaml_error(file, exc) from None
    return parse_cell_config(data, file)


def cell_file(path: str | Path | None) -> Path:
    """The file ``--config`` names: a file where there is one, else the shipped cell of that name (a bare name such
    as ``arm6``, so that a regular install needs no path into its site-packages), the demo arm cell when none."""
    if path is None:
        return DEFAULT_CELL
    file = Path(path)
    shipped = shipped_cell(file.name) if file.parent == Path() and not file.exists() else None
    return shipped if shipped is not None else file


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


def parse_cell_config(data: Any, file: Path) -> CellConfig:
    top = Fields(
        file, "", data, ("name", "robot", "bus", "axes", "planning", "simulated", "homing_order", "requires_homing")
    )
    name = top.get("name", top.string)

    robot = Fields(file, "robot", top.data.get("robot"), ("name", "urdf", "tcp_frame")) if "robot" in top.data else None
    if robot is None:
        raise top.error("robot", "missing")
    urdf = robot_urdf(robot, file)
    try:
        model = RobotModel.from_urdf(urdf)
    except ModelError as exc:
        raise robot.error("urdf", str(exc)) from None
    tcp_frame = robot.get("tcp_frame", robot.string, None)
    if tcp_frame is not None and not model.model.existFrame(tcp_frame):
        raise robot.error("tcp_frame", f"the URDF has no frame {tcp_frame!r}")

    bus = parse_bus(file, top.data.get("bus", {}))
    planning = parse_planning(file, top.data.get("planning", {}), tcp_frame, model)
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
        axis, max_jerk = parse_axis(file, f"axes[{i}]", a, model, bus)
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
    order = parse_homing_order(top, homing, [a.joint for a in axes])
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
    """The cell's traffic per SYNC period must fit its bus (axes.master.budget: 70 % of the bit rate)."""
    problem = bus_budget(cell).problem()
    if problem is not None:
        raise ConfigError(file, "bus", problem)


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
