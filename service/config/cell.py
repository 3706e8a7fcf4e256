"""A cell as its file describes it: the robot, its CAN bus, its axes, the planning settings.

What the rest of pvtflow asks of a cell (its joint order, its axes in that order, its home position,
its joint limits) is answered here; reading the file is service.config.reader.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.config import AxisConfig, BusConfig
from pvtflow.axes.master.homing import homing_stages
from pvtflow.planner.limits import JointLimits, joint_limits_from_drives
from pvtflow.planner.model import RobotModel
from pvtflow.planner.speed_band import DEFAULT_SPEED_BAND


@dataclass(frozen=True)
class PlanningConfig:
    tcp_frame: str | None = None
    max_tcp_speed: float | None = None  # m/s
    max_tcp_angular_speed: float | None = None  # rad/s
    torque_limits: bool = True  # only where the URDF has effort limits and masses
    position_tolerance_qc: float = 1.0
    budget_ms: float = 200.0  # a plan's deadline when its request sets none (service/cell_planner.py)
    speed_band: float = DEFAULT_SPEED_BAND  # planner.speed_band: the path speed's drop allowed for fewer records
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
        """The stages to home ``joints`` (None: every axis with homing) in (axes.master.homing.homing_stages)."""
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
        """Joint-space limits: the drives' (through the scaling, a fixed-period drive's velocity and
        acceleration times ``BusConfig.planning_share``) merged with the URDF's."""
        axes = self.ordered_axes()
        shares = [self.bus.planning_share(a.profile.fixed_period) for a in axes]
        return joint_limits_from_drives(
            self.joint_names, [a.scaling for a in axes], [a.limits for a in axes], shares
        ).merged_with(JointLimits.from_model(self.model))
