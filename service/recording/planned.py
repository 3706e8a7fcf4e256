"""A run's plan as the drives execute it: the ``/axis/<joint>/planned`` channel and the following error's reference.

Each axis's program is sampled as its drive interpolates it: ``AxisProgram.reconstruction()``
(axes/drive/interpolation.py, the one cubic) on the drive's own 1 kHz grid from the start SYNC, in counts
and joint units. The samples are written ``PLANNED_LEAD_MS`` ahead of the run and the rest when the
run is over or the recording closes: a whole plan at once is tens of thousands of messages, the
writer would fall seconds behind the bus, and a kill -9 would lose the actual data it had not
reached. The same samples give the planned position the following error is measured against.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.interpolation import DRIVE_SAMPLE_MS
from pvtflow.service.recording.channels import PLANNED_SCHEMA, encode_planned

if TYPE_CHECKING:
    from pvtflow.axes.drive.program import AxisProgram
    from pvtflow.axes.drive.scaling import AxisScaling

PLANNED_LEAD_MS = 250.0  # the planned channel is written this far ahead of the run (a chunk's span)

LogEncoded = Callable[[str, dict, float, bytes], None]  # topic, schema, bus time (s), message


class PlannedRun:
    """One run's programs sampled on the drives' grid from ``t0_s`` (the start SYNC's bus time)."""

    def __init__(
        self,
        programs: Sequence[AxisProgram],
        scaling: Sequence[AxisScaling],
        joints: Sequence[str],
        t0_s: float,
    ) -> None:
        self.programs = programs
        self.t0_s = t0_s
        self._topics = [f"/axis/{joint}/planned" for joint in joints]
        self._cubics = [prog.reconstruction() for prog in programs]
        # per axis: t, position, velocity, acceleration, joint units (lists: the writer reads them one by one)
        self._samples: list[tuple[list[float], ...]] = []
        self._qc: list[NDArray[np.float64]] = []  # the positions again, for lookups by index
        for cubic, axis_scaling in zip(self._cubics, scaling, strict=True):
            t = cubic.sample_times(DRIVE_SAMPLE_MS)
            p = np.asarray(cubic.position(t), dtype=float)
            columns = (t, p, cubic.velocity(t), cubic.acceleration(t), axis_scaling.qc_to_position(p))
            self._samples.append(tuple(np.asarray(c, dtype=float).tolist() for c in columns))
            self._qc.append(p)
        self._next = [0] * len(self._samples)

    def position_at(self, i: int, t_ms: NDArray[np.float64]) -> NDArray[np.float64]:
        """Axis i's planned positions at program times t_ms: the sample of the drive's grid where a time
        is on it (a SYNC period of whole ms), else the reconstruction itself."""
        p = self._qc[i]
        k = np.rint(t_ms / DRIVE_SAMPLE_MS)
        on_grid = (np.abs(k * DRIVE_SAMPLE_MS - t_ms) < 1e-9) & (k >= 0) & (k < len(p))
        if on_grid.all():
            return p[k.astype(int)]
        off = np.asarray(self._cubics[i].position(t_ms), dtype=float)
        return np.where(on_grid, p[np.clip(k, 0, len(p) - 1).astype(int)], off)

    def write_until(self, t_ms: float, log_encoded: LogEncoded) -> None:
        """The samples up to program time ``t_ms`` not written yet, at their bus times."""
        t0 = self.t0_s
        for i, (t, p, v, a, q) in enumerate(self._samples):
            stop = bisect.bisect_right(t, t_ms)
            topic = self._topics[i]
            for k in range(self._next[i], stop):
                log_encoded(topic, PLANNED_SCHEMA, t0 + t[k] / 1000.0, encode_planned(t[k], p[k], v[k], a[k], q[k]))
            self._next[i] = max(self._next[i], stop)
