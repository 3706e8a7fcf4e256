"""The axes layer: CiA 402 drives on a CANopen bus running PVT programs, with no planner needed.

A program (``PvtProgram``, the JSON contract of docs/pvt-program.md) runs on a cell's drives through
``CellBus`` (the network, SYNC, heartbeats) and ``AxisGroup`` (configure, start on one SYNC, feed,
halt, recover); ``CellHoming`` homes the axes first (CiA 402 mode 6); ``SimulatedCell`` gives
simulated drives to run it on. Requires canopen, python-can,
numpy and numba only."""

from __future__ import annotations

from pvtflow.axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: ``import axes.scaling`` stays light)
_HOMES: dict[str, str] = {
    "AxisProgram": "pvtflow.axes.program",
    "PvtProgram": "pvtflow.axes.program",
    "ProgramFormatError": "pvtflow.axes.program",
    "program_mismatch": "pvtflow.axes.program",
    "axes_of": "pvtflow.axes.program",
    "DriveAxis": "pvtflow.axes.axis",
    "DriveProfile": "pvtflow.axes.drive_profile",
    "AxisConfig": "pvtflow.axes.config",
    "BufferConfig": "pvtflow.axes.config",
    "BusConfig": "pvtflow.axes.config",
    "Wiring": "pvtflow.axes.config",
    "AxisScaling": "pvtflow.axes.scaling",
    "DriveLimits": "pvtflow.axes.scaling",
    "BusError": "pvtflow.axes.bus_faults",
    "CellBus": "pvtflow.axes.bus",
    "AxisGroup": "pvtflow.axes.group",
    "GroupError": "pvtflow.axes.outcome",
    "Result": "pvtflow.axes.outcome",
    "RunResult": "pvtflow.axes.outcome",
    "SimulatedCell": "pvtflow.axes.sim.cell",
    "HomingConfig": "pvtflow.axes.config",
    "AxisSimulation": "pvtflow.axes.config",
    "CellHoming": "pvtflow.axes.homing",
    "HomingOutcome": "pvtflow.axes.homing",
    "HomingResult": "pvtflow.axes.homing",
    "homing_stages": "pvtflow.axes.homing",
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
