"""The on-path stop (issue 37, planner side): the rest of a running motion re-timed to rest as fast as the
joint limits allow, every axis at rest at the same instant, the joints on the planned path.

Why greedy deceleration: along a fixed path the soonest rest is reached by taking, at every point, the
largest path deceleration s'' the joint accelerations allow (0x60C5 through q'' = q'(s) s'' + q''(s) s'^2);
slowing down never breaks a velocity limit (0x607F), so velocity needs no check of its own. The profile
is piecewise constant s'' on the plan's own grid (a ``Trajectory``, like TOPP-RA's), so the drives'
records are sampled from it as from any plan. Pure: numbers in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import PlanError, PlanResult
from pvtflow.planner.trajectory import Trajectory

# Share of 0x60C5 the braking plans with: the constraint is held at the gridpoints, the margin covers
# the curvature of the path between them (checked afterwards by ``Trajectory.limit_ratios``).
BRAKE_ACCELERATION_SHARE = 0.97


@dataclass(frozen=True)
class OnPathStop:
    """The braking: ``trajectory`` starts at path position ``s_start`` with the running motion's path
    velocity at ``t_start`` (its time 0 is ``t_start`` of the motion) and ends at rest at ``t_end``."""

    trajectory: Trajectory
    t_start: float
    t_end: float
    s_start: float
    s_end: float

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start


def _max_deceleration(qs: NDArray[np.float64], qss: NDArray[np.float64], x: float, amax: NDArray[np.float64]) -> float:
    """The most negative s'' with |q'(s) s'' + q''(s) x| <= amax for every joint (x = s'^2).

    Where the joints' intervals do not meet (high curvature at speed) the least bad s'' is taken; the
    limit check afterwards tells."""
    lo, hi = -np.inf, np.inf
    for d, c, a in zip(qs, qss, amax, strict=True):
        if abs(d) < 1e-12:
            continue
        b1, b2 = (-a - c * x) / d, (a - c * x) / d
        lo, hi = max(lo, min(b1, b2)), min(hi, max(b1, b2))
    if not np.isfinite(lo):
        raise PlanError(PlanResult.INFEASIBLE, "the path has no tangent where braking begins")
    return min(lo, hi) if lo <= hi else hi


def brake_on_path(motion: Trajectory, t0: float, limits: JointLimits, tries: int = 4) -> OnPathStop:
    """``_brake`` with the acceleration share lowered until the dense limit check holds (the greedy pass
    holds the limits at the gridpoints only); the last try is returned as is, the caller checks it."""
    share = BRAKE_ACCELERATION_SHARE
    for _ in range(tries):
        stop = _brake(motion, t0, limits, share)
        _, ra = stop.trajectory.limit_ratios(limits)
        if ra <= 1.0:
            break
        share *= 0.97 / ra
    return stop


def _brake(motion: Trajectory, t0: float, limits: JointLimits, share: float) -> OnPathStop:
    """The fastest stop along ``motion``'s path beginning at ``t0`` (the end of what the drives already hold).

    The joints follow the planned path exactly (q = path(s)), the path velocity at ``t0`` is the motion's,
    and all axes come to rest at ``t_end``. A ``t0`` at or after the motion's end is the motion itself."""
    t0 = float(np.clip(t0, 0.0, motion.duration))
    amax = np.asarray(limits.acceleration, dtype=float) * share
    s0 = float(_s_at(motion, t0))
    sd0 = float(_sd_at(motion, t0))
    later = motion.gridpoints[motion.gridpoints > s0 + 1e-12]
    grid, xs = [s0], [sd0 * sd0]
    s_end = float(motion.gridpoints[-1])
    if sd0 > 0.0:
        for s_next in later:
            s, x = grid[-1], xs[-1]
            u = _max_deceleration(motion.path(s, 1), motion.path(s, 2), x, amax)
            if u >= 0.0:  # the limits allow no slowing here: follow at constant path speed
                u = 0.0
            x_next = x + 2.0 * (s_next - s) * u
            if x_next <= 0.0:
                s_end = s - x / (2.0 * u)
                grid.append(s_end)
                xs.append(0.0)
                break
            grid.append(float(s_next))
            xs.append(x_next)
        else:  # the path ends before the brake would: the motion's own remainder is its fastest stop
            grid, xs = [s0, *map(float, later)], [sd0 * sd0, *map(float, motion.sd[-len(later) :] ** 2)]
    gridpoints = np.asarray(grid, dtype=float)
    if len(gridpoints) < 2:
        raise PlanError(PlanResult.INFEASIBLE, "the motion is already at its end")
    sd = np.sqrt(np.maximum(np.asarray(xs), 0.0))
    braking = Trajectory.from_path_velocities(motion.path, gridpoints, sd, motion.joint_names)
    return OnPathStop(braking, t0, t0 + braking.duration, s0, float(gridpoints[-1]))


def _s_at(motion: Trajectory, t: float) -> float:
    """s(t) on the motion's grid (s'' constant per interval)."""
    i = int(np.clip(np.searchsorted(motion.breakpoints, t, side="right") - 1, 0, len(motion.sdd) - 1))
    dt = t - motion.breakpoints[i]
    return float(motion.gridpoints[i] + motion.sd[i] * dt + 0.5 * motion.sdd[i] * dt * dt)


def _sd_at(motion: Trajectory, t: float) -> float:
    """s'(t) on the motion's grid."""
    i = int(np.clip(np.searchsorted(motion.breakpoints, t, side="right") - 1, 0, len(motion.sdd) - 1))
    return float(max(motion.sd[i] + motion.sdd[i] * (t - motion.breakpoints[i]), 0.0))


def quick_stop_time(motion: Trajectory, t0: float, limits: JointLimits) -> float:
    """The off-path (halt) stop's duration from ``t0``: each axis brakes on its own 0x60C5, the last one
    decides."""
    qd = motion.velocity(np.array([t0]))[0]
    return float(np.max(np.abs(qd) / np.asarray(limits.acceleration, dtype=float)))


def _bounds(
    qs: NDArray[np.float64], qss: NDArray[np.float64], x: float, amax: NDArray[np.float64]
) -> tuple[float, float]:
    lo, hi = -np.inf, np.inf
    for d, c, a in zip(qs, qss, amax, strict=True):
        if abs(d) < 1e-12:
            continue
        b1, b2 = (-a - c * x) / d, (a - c * x) / d
        lo, hi = max(lo, min(b1, b2)), min(hi, max(b1, b2))
    return lo, hi


def override(
    planned: Trajectory, running: Trajectory, t0: float, scale: float, limits: JointLimits, tries: int = 4
) -> Trajectory:
    """The rest of ``running`` from ``t0`` re-timed to ``scale`` (0.05..1) of ``planned``'s path speed.

    The path velocity at ``t0`` is the running one; from there it moves towards scale * planned s'(s) at
    the largest path acceleration or deceleration the joints allow, then follows it (a slowed-down feasible
    profile: velocities times scale, accelerations times scale^2). Time 0 of the result is ``t0``."""
    if not 0.05 <= scale <= 1.0:
        raise PlanError(PlanResult.INVALID_INPUT, f"scale must be in [0.05, 1.0], got {scale!r}", field="scale")
    share = BRAKE_ACCELERATION_SHARE
    for _ in range(tries):
        retimed = _override(planned, running, t0, scale, limits, share)
        _, ra = retimed.limit_ratios(limits)
        if ra <= 1.0:
            break
        share *= 0.97 / ra
    return retimed


def _override(
    planned: Trajectory, running: Trajectory, t0: float, scale: float, limits: JointLimits, share: float
) -> Trajectory:
    amax = np.asarray(limits.acceleration, dtype=float) * share
    t0 = float(np.clip(t0, 0.0, running.duration))
    s0, sd0 = _s_at(running, t0), _sd_at(running, t0)
    later = planned.gridpoints[planned.gridpoints > s0 + 1e-12]
    target = (scale * planned.sd[-len(later) :]) ** 2
    grid, xs = [s0, *map(float, later)], [sd0 * sd0]
    # s'^2 is linear in s between gridpoints (s'' constant): the scaled plan at s0 and at every later gridpoint
    here = [scale * scale * float(np.interp(s0, planned.gridpoints, planned.sd**2)), *map(float, target)]
    for i, s_next in enumerate(later):
        s, x = grid[i], xs[-1]
        lo, hi = _bounds(running.path(s, 1), running.path(s, 2), x, amax)
        step = 2.0 * (s_next - s)
        if abs(x - here[i]) <= 1e-9 * max(1.0, x):
            xs.append(float(target[i]))  # on the scaled plan: follow it (a feasible profile)
        elif x > target[i]:
            xs.append(max(x + step * min(lo, 0.0), target[i]))
        else:
            xs.append(min(x + step * max(hi, 0.0), target[i]))
    xs[-1] = 0.0
    sd = np.sqrt(np.maximum(np.asarray(xs), 0.0))
    return Trajectory.from_path_velocities(running.path, np.asarray(grid, dtype=float), sd, running.joint_names)


def stopped_motion(motion: Trajectory, stop: OnPathStop) -> Trajectory:
    """The whole motion as the drives run it with the stop: ``motion`` until ``stop.t_start``, then the
    braking (one trajectory from rest to rest, what the knot placement samples into every profile's records)."""
    before = motion.gridpoints < stop.s_start - 1e-12
    grid = np.concatenate([motion.gridpoints[before], stop.trajectory.gridpoints])
    sd = np.concatenate([motion.sd[before], stop.trajectory.sd])
    return Trajectory.from_path_velocities(motion.path, grid, sd, motion.joint_names)


def resume(motion: Trajectory, paused: OnPathStop, limits: JointLimits) -> Trajectory:
    """From rest where ``paused`` ended to ``motion``'s end: the largest path acceleration the joints allow
    until the planned profile is reached, then the planned profile (under it, every constraint the plan held
    holds; the ramp itself is held to the joint limits). Time 0 of the result is the moment of resuming."""
    return override(motion, paused.trajectory, paused.trajectory.duration, 1.0, limits)
