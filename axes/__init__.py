"""The axes layer: CiA 402 drives on a CANopen bus running PVT programs, with no planner needed.

A program (``PvtProgram``, the JSON contract of docs/pvt-program.md) runs on a cell's drives through
``CellBus`` (the network, SYNC, heartbeats) and ``AxisGroup`` (configure, start on one SYNC, feed,
halt, recover); ``CellHoming`` homes the axes first (CiA 402 mode 6); ``SimulatedCell`` gives
simulated drives to run it on. Requires canopen, python-can,
numpy and numba only."""

from __future__ import annotations

from pvtflow.axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: ``import axes.drive.scaling`` stays light)
_HOMES: dict[str, str] = {
    "AxisProgram": "pvtflow.axes.drive.program",
    "PvtProgram": "pvtflow.axes.drive.program",
    "ProgramFormatError": "pvtflow.axes.drive.program",
    "program_mismatch": "pvtflow.axes.drive.program",
    "axes_of": "pvtflow.axes.drive.program",
    "DriveAxis": "pvtflow.axes.drive.axis",
    "DriveProfile": "pvtflow.axes.drive.drive_profile",
    "AxisConfig": "pvtflow.axes.drive.config",
    "BufferConfig": "pvtflow.axes.drive.config",
    "BusConfig": "pvtflow.axes.drive.config",
    "Wiring": "pvtflow.axes.drive.config",
    "AxisScaling": "pvtflow.axes.drive.scaling",
    "DriveLimits": "pvtflow.axes.drive.scaling",
    "BusError": "pvtflow.axes.master.bus.faults",
    "CellBus": "pvtflow.axes.master.bus.cell_bus",
    "AxisGroup": "pvtflow.axes.master.group.axis_group",
    "GroupError": "pvtflow.axes.master.group.outcome",
    "Result": "pvtflow.axes.master.group.outcome",
    "RunResult": "pvtflow.axes.master.group.outcome",
    "SimulatedCell": "pvtflow.axes.sim.cell",
    "HomingConfig": "pvtflow.axes.drive.config",
    "AxisSimulation": "pvtflow.axes.drive.config",
    "CellHoming": "pvtflow.axes.master.homing",
    "HomingOutcome": "pvtflow.axes.master.homing",
    "HomingResult": "pvtflow.axes.master.homing",
    "homing_stages": "pvtflow.axes.master.homing",
}
__all__ = [
    "AxisConfig",
    "AxisGroup",
    "AxisProgram",
    "AxisScaling",
    "AxisSimulation",
    "BufferConfig",
    "BusConfig",
    "BusError",
    "CellBus",
    "CellHoming",
    "DriveAxis",
    "DriveLimits",
    "DriveProfile",
    "GroupError",
    "HomingConfig",
    "HomingOutcome",
    "HomingResult",
    "ProgramFormatError",
    "PvtProgram",
    "Result",
    "RunResult",
    "SimulatedCell",
    "Wiring",
    "axes_of",
    "homing_stages",
    "program_mismatch",
]

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
