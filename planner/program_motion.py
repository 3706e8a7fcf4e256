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

import itertools

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline
from toppra.interpolator import AbstractGeometricPath

from pvtflow.axes.drive.program import AxisProgram, PvtProgram
from pvtflow.planner.path import JointPath
from pvtflow.planner.trajectory import Trajectory


def _axis_pieces(axis: AxisProgram) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One axis's reconstruction as pieces (breakpoints in ms, coefficients (4, n) highest power first, qc
    over ms): the drive's own cubics (EPOS2, Parker), or for a linear interpolator the C2 cubic through its
    setpoints (its corners have no second derivative to brake along)."""
    rec = axis.reconstruction()
    if rec.interpolation.cubic:
        breaks = np.concatenate((rec.start, [rec.end_time]))
        c = np.vstack((rec.c3, rec.c2, rec.c1, rec.c0))
    else:
        t = np.concatenate((rec.start[:1], rec.start + rec.duration))
        spline = CubicSpline(t, rec.position(t), bc_type="clamped")
        breaks, c = spline.x, spline.c
    if breaks[0] > 0.0:  # the dwell before the first segment: the start position, held
        breaks = np.concatenate(([0.0], breaks))
        c = np.hstack((np.array([[0.0], [0.0], [0.0], [c[3, 0]]]), c))
    # after its last segment the axis holds its end position (while another axis may still move)
    c = np.hstack((c, np.array([[0.0], [0.0], [0.0], [rec.end_position]])))
    return np.append(breaks, np.inf), c


def _rebased(breaks: NDArray[np.float64], c: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.float64]:
    """The pieces' coefficients re-based to start at every ``at`` (each on the piece that holds it)."""
    i = np.clip(np.searchsorted(breaks, at, side="right") - 1, 0, c.shape[1] - 1)
    tau = at - breaks[i]
    c3, c2, c1, c0 = c[:, i]
    return np.vstack(
        (c3, c2 + 3.0 * c3 * tau, c1 + tau * (2.0 * c2 + 3.0 * c3 * tau), c0 + tau * (c1 + tau * (c2 + tau * c3)))
    )


class ProgramPath(JointPath):
    """The joints as the drives move them, s = program time in seconds (``JointPath``'s pieces layout):
    every axis's reconstruction exactly, on the union of the axes' breakpoints (whole ms)."""

    def __init__(self, program: PvtProgram) -> None:
        AbstractGeometricPath.__init__(self)
        pieces = [_axis_pieces(a) for a in program.axes]
        end = max(b[-2] for b, _ in pieces)
        breaks = np.unique(np.concatenate([b[:-1] for b, _ in pieces]))
        breaks = breaks[breaks < end - 1e-9]
        coef = np.empty((4, len(breaks), len(pieces)))
        for j, ((b, c), a) in enumerate(zip(pieces, program.axes, strict=True)):
            r = _rebased(b, c, breaks)
            r[3] -= a.scaling.position_offset_qc
            r /= a.scaling.qc_per_joint_unit
            coef[:, :, j] = r * np.array([1e9, 1e6, 1e3, 1.0])[:, None]  # per ms -> per s
        s = np.append(breaks, end) / 1000.0
        self.waypoint_s: NDArray[np.float64] = s
        self._pieces = (s, np.ascontiguousarray(coef))
        self.points: NDArray[np.float64] = np.asarray(self(s))
        self.clamped = np.zeros(self.points.shape, dtype=bool)
        self.kinks = np.zeros(0)


def program_motion(program: PvtProgram, max_step_ms: float = 10.0) -> Trajectory:
    """The program as it runs: its path (``ProgramPath``) at s' = 1, on a grid of the path's breakpoints (every
    grid interval on one piece) at most ``max_step_ms`` apart (the re-timings hold their limits at the
    gridpoints and check between them)."""
    path = ProgramPath(program)
    breaks_ms = np.round(path.waypoint_s * 1000.0)
    fill = [np.linspace(a, b, int(np.ceil((b - a) / max_step_ms)) + 1)[:-1] for a, b in itertools.pairwise(breaks_ms)]
    grid = np.append(np.concatenate(fill), breaks_ms[-1]) / 1000.0
    return Trajectory.from_path_velocities(path, grid, np.ones(len(grid)), tuple(a.joint for a in program.axes))
