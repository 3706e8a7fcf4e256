"""The planner: pure computation (numbers in, numbers out; no I/O).

``Planner`` (settings once) plans ``PlanInput`` waypoints into a time-optimal trajectory
(``PlanOutput``, ``PlanResult``); ``build_program`` places the drives' records (a ``PvtProgram`` of
axes.drive.program); ``validate_program`` checks any program against its drives' rules."""

from __future__ import annotations

from pvtflow.axes.front_door import lazy_exports
from pvtflow.planner.kernel_cache import install as _install_kernel_cache

_install_kernel_cache()  # before any planner module compiles a kernel

# public name -> the module that defines it (loaded on first use: ``import planner.validate`` loads no robot model)
_HOMES: dict[str, str] = {
    "PlanInput": "pvtflow.planner.plan",
    "PlanOutput": "pvtflow.planner.plan",
    "Planner": "pvtflow.planner.plan",
    "PlanError": "pvtflow.planner.path",
    "PlanResult": "pvtflow.planner.path",
    "BuildError": "pvtflow.planner.build",
    "build_program": "pvtflow.planner.build",
    "ValidationReport": "pvtflow.planner.validate",
    "validate_program": "pvtflow.planner.validate",
    "RobotModel": "pvtflow.planner.model",
    "JointLimits": "pvtflow.planner.limits",
}
__all__ = [
    "BuildError",
    "JointLimits",
    "PlanError",
    "PlanInput",
    "PlanOutput",
    "PlanResult",
    "Planner",
    "RobotModel",
    "ValidationReport",
    "build_program",
    "validate_program",
]

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
