"""The path before issue 13, kept for the benches' comparison only: the not-a-knot cubic spline
through the waypoints with the exact position-limit check, which refused a path that swings out of
the limits between waypoints inside them.

It is ``JointPath`` with no position limits to clamp against (then it is the spline, bit for bit),
checked against the real ones by the same exact check the planner keeps as its safety net.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError


def spline_path(waypoints: ArrayLike, limits: JointLimits) -> tuple[JointPath, bool]:
    """The not-a-knot spline through the waypoints, and whether the old planner accepted it (it
    stays inside ``limits`` between the waypoints)."""
    unbounded = JointLimits(
        limits.names,
        np.full(limits.dof, -np.inf),
        np.full(limits.dof, np.inf),
        limits.velocity,
        limits.acceleration,
        limits.effort,
    )
    path = JointPath(waypoints, unbounded)
    try:
        path.check_within(limits)
    except PlanError:
        return path, False
    return path, True


def arc_length(path: JointPath, samples: int = 20001) -> float:
    """The path's length in joint space (the integral of |q'(s)|; q' is continuous along it)."""
    s = np.linspace(0.0, path.length, samples)
    return float(np.trapezoid(np.linalg.norm(path(s, 1), axis=1), s))
