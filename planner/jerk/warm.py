"""The jerk-limited timing's warm start, from the TOPP-RA solution of the same path: its s'^2
brought to rest where the jerk-limited motion must be at rest, the program's grid (even in that
profile's time) and the start of the solve, slowed down to well inside the jerk rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.jerk.nlp import FRACTIONS, Rows
from pvtflow.planner.path import JointPath
from pvtflow.planner.timing import Trajectory

# intervals between two rests at least: one constant jerk per interval needs 3 to stop again (+, -, +)
MIN_REST_TO_REST = 4

_START_JERK_SLACK = 0.3  # the start's joint jerk at most this fraction of the limit (see ``warm_start``)
# a jump of the path's second derivative at a waypoint above this is a C1 joint, not round-off
CURVATURE_JUMP = 1e-8


@dataclass(frozen=True)
class WarmProfile:
    """The TOPP-RA solution's s'^2 along the path, brought to rest where the jerk-limited motion
    must be at rest (the ends and every C1 waypoint, ``curvature_jumps``): the program's grid
    and its start come from it."""

    s: NDArray[np.float64]  # samples along the path
    x: NDArray[np.float64]  # s'^2 there
    t: NDArray[np.float64]  # time there, for s'' constant between samples

    @classmethod
    def of(cls, warm: Trajectory, stops: NDArray[np.float64]) -> WarmProfile:
        length = warm.gridpoints[-1]
        s = np.union1d(np.union1d(warm.gridpoints, np.linspace(0.0, length, 1001)), stops)
        x = np.interp(s, warm.gridpoints, warm.sd**2)
        if len(stops):
            # braking into and out of each stop at a typical path acceleration of the TOPP-RA solution
            # (of its accelerating intervals where it cruises on most: a zero would stop it everywhere)
            accel = np.percentile(np.abs(warm.sdd), 75)
            if accel <= 0.0 and np.any(warm.sdd != 0.0):
                accel = np.percentile(np.abs(warm.sdd[warm.sdd != 0.0]), 75)
            distance = np.min(np.abs(s[:, None] - stops[None, :]), axis=1)
            x = np.minimum(x, 2.0 * accel * distance)
        v = np.sqrt(np.maximum(x, 0.0))
        with np.errstate(divide="ignore"):
            dt = 2.0 * np.diff(s) / (v[:-1] + v[1:])
        return cls(s, x, np.concatenate(([0.0], np.cumsum(np.where(np.isfinite(dt), dt, 0.0)))))

    def grid(self, waypoint_s: NDArray[np.float64], rests: NDArray[np.float64], n: int) -> NDArray[np.float64]:
        """n intervals: every waypoint, and between two waypoints points evenly spaced in this
        profile's time (the intervals shared out by the time spent between them), at least
        ``MIN_REST_TO_REST`` between two rests (``rests``: a subset of the waypoints).

        Even in time, not in s: the grid is dense where the motion is slow, where its
        accelerations and their switches are, and where most of the duration is; each jerk
        switch needs a gridpoint.
        """
        segments = len(waypoint_s) - 1
        section = np.searchsorted(rests, waypoint_s[:-1], side="right") - 1  # the rest-to-rest part of each segment
        floor = np.ones(segments, dtype=int)
        for k in range(len(rests) - 1):
            inside = np.flatnonzero(section == k)
            longest = inside[np.argmax(np.diff(waypoint_s)[inside])]
            floor[longest] += max(0, MIN_REST_TO_REST - len(inside))
        if n < floor.sum():
            raise ValueError(f"{n} intervals cannot hold {segments} waypoint segments and {len(rests) - 2} stops")
        tw = np.interp(waypoint_s, self.s, self.t)
        share = np.diff(tw) / tw[-1] * n
        count = np.maximum(floor, np.floor(share)).astype(int)
        while count.sum() > n:
            count[np.argmax(np.where(count > floor, count - share, -np.inf))] -= 1
        while count.sum() < n:
            count[np.argmax(share - count)] += 1
        parts = [np.interp(np.linspace(tw[i], tw[i + 1], c + 1)[1:-1], self.t, self.s) for i, c in enumerate(count)]
        return np.sort(np.concatenate((waypoint_s, *parts)))


def curvature_jumps(path: JointPath) -> NDArray[np.float64]:
    """|q_ss(s+) - q_ss(s-)| at every inner waypoint, (N - 2, dof): where the path is C1 only.

    There q'' = q_ss s'^2 + q_s s'' jumps by (q_ss+ - q_ss-) s'^2 whatever s'' does (one scalar
    cannot cancel a jump in dof directions): a finite jerk passes such a waypoint at rest.
    """
    x, c = path.pieces
    h = np.diff(x)[:-1, None]
    end = 6.0 * c[0, :-1] * h + 2.0 * c[1, :-1]  # q_ss at the end of each piece but the last
    return np.abs(2.0 * c[1, 1:] - end)


def rests_of(path: JointPath) -> NDArray[np.float64]:
    """Where the jerk-limited motion is at rest, in s: both ends and every waypoint where the path
    is C1 only (``curvature_jumps`` above ``CURVATURE_JUMP``)."""
    stops = path.waypoint_s[1:-1][np.any(curvature_jumps(path) > CURVATURE_JUMP, axis=1)]
    return np.concatenate(([0.0], stops, [path.length]))


def warm_start(
    profile: WarmProfile, grid: NDArray[np.float64], rows: Rows, max_jerk: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The program's variables along ``profile`` on ``grid``, within the speed bounds: s' and a
    smoothed s'' (TOPP-RA's jumps between its intervals) at the gridpoints, the times between
    them, the jerk that joins the s'', and the middles that follow from those.

    Slowed down uniformly until its joint jerk at the interval starts is at most
    ``_START_JERK_SLACK`` of the limit: a start inside the jerk rows, with room to speed up. From a
    start far outside them (a limit far below the TOPP-RA profile's jerk) the solvers spend their
    time in restoration; from one near or on them, fatrop's iterations have a long tail
    (bench/RESULTS.md)."""
    x = np.minimum(np.interp(grid, profile.s, profile.x), rows.sd_max**2)
    sd = np.sqrt(np.maximum(x, 0.0))
    a = 0.5 * np.gradient(x, grid)
    a[rows.sd_max == 0.0] = 0.0
    a[[0, -1]] = 0.0
    h = np.diff(grid) / np.maximum(0.5 * (sd[:-1] + sd[1:]), 1e-3 * np.max(sd))
    j = np.diff(a) / h
    v, u = sd[:-1, None], a[:-1, None]
    jerk = rows.q3 * v**3 + 3.0 * rows.q2 * v * u + rows.q1 * j[:, None]
    k = np.cbrt(max(1.0, float(np.max(np.abs(jerk) / max_jerk) / _START_JERK_SLACK)))
    sd, a, h, j = sd / k, a / (k * k), h * k, j / (k * k * k)
    v, u = sd[:-1], a[:-1]
    tau = [f * h for f in FRACTIONS]
    sigma = [t * (v + t * (0.5 * u + t * j / 6.0)) for t in tau]
    speed = [np.maximum(v + t * (u + 0.5 * j * t), 0.0) for t in tau]
    stages = np.column_stack((v, u, h, j, *sigma, *speed))
    return np.concatenate((stages.ravel(), [0.0, 0.0]))
