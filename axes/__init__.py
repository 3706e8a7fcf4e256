"""The axes layer: CiA 402 drives on a CANopen bus running PVT programs, with no planner needed.

A program (``PvtProgram``, the JSON contract of docs/pvt-program.md) runs on a cell's drives through
``CellBus`` (the network, SYNC, heartbeats) and ``AxisGroup`` (configure, start on one SYNC, feed,
halt, recover); ``CellHoming`` homes the axes first (CiA 402 mode 6); ``SimulatedCell`` gives
simulated drives to run it on. Requires canopen, python-can,
numpy and numba only."""

from __future__ import annotations

from axes.front_door import lazy_exports

# public name -> the module that defines it (loaded on first use: ``import axes.scaling`` stays light)
_HOMES: dict[str, str] = {
    "AxisProgram": "axes.program",
    "PvtProgram": "axes.program",
    "ProgramFormatError": "axes.program",
    "program_mismatch": "axes.program",
    "axes_of": "axes.program",
    "DriveAxis": "axes.axis",
    "DriveProfile": "axes.drive_profile",
    "AxisConfig": "axes.config",
    "BufferConfig": "axes.config",
    "BusConfig": "axes.config",
    "Wiring": "axes.config",
    "AxisScaling": "axes.scaling",
    "DriveLimits": "axes.scaling",
    "BusError": "axes.bus_faults",
    "CellBus": "axes.bus",
    "AxisGroup": "axes.group",
    "GroupError": "axes.outcome",
    "Result": "axes.outcome",
    "RunResult": "axes.outcome",
    "SimulatedCell": "axes.sim.cell",
    "HomingConfig": "axes.config",
    "AxisSimulation": "axes.config",
    "CellHoming": "axes.homing",
    "HomingOutcome": "axes.homing",
    "HomingResult": "axes.homing",
    "homing_stages": "axes.homing",
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
