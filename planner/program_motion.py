"""A running program as a path and a timing: what the on-path stop, pause and override re-time (issue 37).

The path the axes are on is the one the drives make of the program's records (their own reconstruction,
``AxisProgram.reconstruction``), not the plan that made them: it is the path the tool is on, it exists for a
program given as a file as for a planned one, and it needs no planner state kept per motion. Its parameter s is
the program's time (seconds from the start SYNC), so the running motion is s' = 1, and a re-timing of it is in
the drives' own time from the start. The path is the C2 cubic spline through the reconstruction at every drive
ms (a linear interpolator's setpoints have no second derivative; an EPOS2's cubics are met to a fraction of a
count), in joint units.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline
from toppra.interpolator import AbstractGeometricPath

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.path import JointPath
from pvtflow.planner.trajectory import Trajectory

SAMPLE_MS = 1.0  # the drives sample their reconstruction every ms (axes.drive.interpolation)


class ProgramPath(JointPath):
    """The joints as the drives move them, s = program time in seconds (``JointPath``'s pieces layout)."""

    def __init__(self, program: PvtProgram) -> None:
        AbstractGeometricPath.__init__(self)
        end_ms = float(program.duration_ms)
        t_ms = np.arange(0.0, end_ms + 0.5 * SAMPLE_MS, SAMPLE_MS)
        if t_ms[-1] < end_ms:
            t_ms = np.append(t_ms, end_ms)
        q = np.column_stack([a.scaling.qc_to_position(a.reconstruction().position(t_ms)) for a in program.axes]).astype(
            float
        )
        s = t_ms / 1000.0
        spline = CubicSpline(s, q, axis=0, bc_type="clamped")  # at rest at both ends
        self.points: NDArray[np.float64] = q
        self.waypoint_s: NDArray[np.float64] = s
        self._pieces = (s, np.ascontiguousarray(spline.c))
        self.clamped = np.zeros(q.shape, dtype=bool)
        self.kinks = np.zeros(0)


def program_motion(program: PvtProgram, grid_ms: float = 1.0) -> Trajectory:
    """The program as it runs: its path (``ProgramPath``) at s' = 1, on a grid of ``grid_ms``."""
    path = ProgramPath(program)
    end = float(path.waypoint_s[-1])
    grid = np.arange(0.0, end, grid_ms / 1000.0)
    grid = np.append(grid, end) if grid[-1] < end else grid
    return Trajectory.from_path_velocities(path, grid, np.ones(len(grid)), tuple(a.joint for a in program.axes))
