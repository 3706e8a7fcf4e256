"""The on-path stop (issue 37, planner side): the rest of a running motion re-timed to rest as fast as the
joint limits allow, every axis at rest at the same instant, the joints on the planned path.

Why greedy deceleration: along a fixed path the soonest rest is reached by taking, at every point, the
largest path deceleration s'' the joint accelerations allow (0x60C5 through q'' = q'(s) s'' + q''(s) s'^2);
slowing down never breaks a velocity limit (0x607F), so velocity needs no check of its own. The profile
is piecewise constant s'' on the plan's own grid (a ``Trajectory``, like TOPP-RA's), so the drives'
records are sampled from it as from any plan. Pure: numbers in, numbers out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

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
    planned: Trajectory,
    running: Trajectory,
    t0: float,
    scale: float,
    limits: JointLimits,
    tries: int = 4,
    rest_at_end: bool = True,
    share: float = BRAKE_ACCELERATION_SHARE,
) -> Trajectory:
    """The rest of ``running`` from ``t0`` re-timed to ``scale`` (0.05..1) of ``planned``'s path speed.

    The path velocity at ``t0`` is the running one; from there it moves towards scale * planned s'(s) at
    the largest path acceleration or deceleration the joints allow, then follows it (a slowed-down feasible
    profile: velocities times scale, accelerations times scale^2). Time 0 of the result is ``t0``.
    ``rest_at_end``: s' = 0 at the path's end; a program's path (``planner.program_motion``, s = program time)
    is at rest there at any s' (q'(s) = 0), and a forced s' = 0 would brake its last interval hard. ``share``: of
    0x60C5 at the gridpoints to begin with, lowered until the dense check between them holds."""
    if not 0.05 <= scale <= 1.0:
        raise PlanError(PlanResult.INVALID_INPUT, f"scale must be in [0.05, 1.0], got {scale!r}", field="scale")
    for _ in range(tries):
        retimed = _override(planned, running, t0, scale, limits, share, rest_at_end)
        _, ra = retimed.limit_ratios(limits)
        if ra <= 1.0:
            break
        share *= 0.97 / ra
    return retimed


def _override(
    planned: Trajectory,
    running: Trajectory,
    t0: float,
    scale: float,
    limits: JointLimits,
    share: float,
    rest_at_end: bool = True,
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
    if rest_at_end:
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


# --- jerk-limited braking (a motion planned with a jerk limit) -----------------------------------------------
SCURVE_STEP_S = 1e-4  # the S-curve's integration step (its end found between two steps)
WINDOW_S = 0.01  # the span a drive's window jerk is judged over (planner.knots.window_jerk)
REST_SD = 1e-6  # a path velocity this small is rest (a braking ends at s' = 0 to rounding; the plan's s' = 1)


def _scurve(v0: float, a0: float, decel: float, jerk: float) -> tuple[NDArray[np.float64], ...]:
    """Path velocity to rest with s'' ramped at ``jerk`` to ``-decel`` and back to 0 as s' reaches 0: (t, s - s0,
    s', s'') at every integration step, the last at rest."""
    n = int(10.0 / SCURVE_STEP_S)
    dt = SCURVE_STEP_S
    ts, ss, vs, acc = [0.0], [0.0], [v0], [a0]
    s, v, a = 0.0, v0, a0
    for k in range(1, n):
        if a < 0.0 and v <= a * a / (2.0 * jerk) + 1e-12:
            a_next = min(a + jerk * dt, 0.0)  # the ramp out: s'' back to 0 as s' reaches 0
        elif a > -decel:
            a_next = max(a - jerk * dt, -decel)
        else:
            a_next = min(a + jerk * dt, -decel)
        v_next = v + 0.5 * (a + a_next) * dt
        if v_next <= 0.0:  # rest between two steps: where s' crosses 0
            f = v / max(v - v_next, 1e-300)
            ts.append((k - 1 + f) * dt)
            ss.append(s + 0.5 * v * f * dt)
            vs.append(0.0)
            acc.append(0.0)
            break
        s += 0.5 * (v + v_next) * dt
        v, a = v_next, a_next
        ts.append(k * dt)
        ss.append(s)
        vs.append(v)
        acc.append(a)
    return np.asarray(ts), np.asarray(ss), np.asarray(vs), np.asarray(acc)


def window_jerk_ratio(motion: Trajectory, stop: OnPathStop, max_jerk: NDArray[np.float64]) -> float:
    """The 10-ms-window joint jerk / ``max_jerk`` at most of the braking, with the motion's last window before
    it and the rest after it, at every ms."""
    braking = stop.trajectory
    before = motion.acceleration(np.clip(stop.t_start - WINDOW_S + np.arange(10) * 1e-3, 0.0, motion.duration))
    during = braking.acceleration(np.linspace(0.0, braking.duration, max(2, int(braking.duration * 1000.0) + 1)))
    acc = np.vstack((before, during, np.zeros((10, during.shape[1]))))
    window = np.abs(acc[10:] - acc[:-10]) / WINDOW_S
    return float(np.max(window / np.asarray(max_jerk, dtype=float)[None, :]))


def jerk_braking(motion: Trajectory, t0: float, decel: float, jerk: float) -> OnPathStop:
    """The S-curve braking from ``t0``: path jerk ``jerk`` (1/s^2), path deceleration ``decel`` (1/s) at most."""
    s0, sd0 = _s_at(motion, t0), _sd_at(motion, t0)
    i = int(np.clip(np.searchsorted(motion.breakpoints, t0, side="right") - 1, 0, len(motion.sdd) - 1))
    _, s, v, _ = _scurve(sd0, float(motion.sdd[i]) if sd0 > 0.0 else 0.0, decel, jerk)
    keep = np.concatenate(([True], np.diff(s) > 1e-12))
    grid = s0 + s[keep]
    if grid[-1] > float(motion.gridpoints[-1]) or len(grid) < 2:
        raise PlanError(PlanResult.INFEASIBLE, "the path ends before a jerk-limited braking would")
    braking = Trajectory.from_path_velocities(motion.path, grid, v[keep], motion.joint_names)
    return OnPathStop(braking, t0, t0 + braking.duration, s0, float(grid[-1]))


def jerk_braking_rates(
    motion: Trajectory,
    t0: float,
    limits: JointLimits,
    max_jerk: ArrayLike,
    share: float = 0.9,
    jerk_share: float | None = None,
    tries: int = 8,
) -> tuple[float, float]:
    """(path deceleration, path jerk) of the on-path braking of a motion planned with a jerk limit: an S-curve
    in path time (``jerk_braking``) from the running state to rest, both lowered until the joints hold
    ``share`` of 0x60C5 and ``jerk_share`` (default ``share``) of ``max_jerk`` (joint units/s^3, judged as the
    drives' window jerk over 10 ms).
    The last try is returned as is: the caller checks the records."""
    jmax = np.asarray(max_jerk, dtype=float)
    t0 = float(np.clip(t0, 0.0, motion.duration))
    qs = np.abs(motion.path(_s_at(motion, t0), 1))
    amax = np.asarray(limits.acceleration, dtype=float)
    moving = qs > 1e-12
    if not np.any(moving):
        raise PlanError(PlanResult.INFEASIBLE, "the path has no tangent where braking begins")
    js = share if jerk_share is None else jerk_share
    decel = share * float(np.min(amax[moving] / qs[moving]))
    jerk = js * float(np.min(jmax[moving] / qs[moving]))
    for _ in range(tries):
        stop = jerk_braking(motion, t0, decel, jerk)
        _, ra = stop.trajectory.limit_ratios(limits)
        rj = window_jerk_ratio(motion, stop, jmax)
        if ra <= share and rj <= js:
            break
        decel, jerk = _lowered(decel, ra, share), _lowered(jerk, rj, js)
    return decel, jerk


def _lowered(value: float, ratio: float, bound: float) -> float:
    """A ramp's acceleration or jerk lowered where its measured ratio passed ``bound`` (3 % under it: the
    ratio of the records, rounded to whole counts, follows the parameter only nearly)."""
    return value * 0.97 * bound / ratio if ratio > bound else value


# --- jerk-limited changes of speed (override and resume of a motion planned with a jerk limit) ----------------
def _speed_change(v0: float, a0: float, v1: float, accel: float, jerk: float) -> tuple[NDArray[np.float64], ...]:
    """Path velocity from ``v0`` (s'' ``a0``) to ``v1``: s'' ramped at ``jerk`` to at most ``accel`` (towards
    ``v1``), held, and ramped back to 0 as s' reaches ``v1``, the phases' lengths solved exactly (so that the
    change's length moves continuously with its rates: ``back_to_plan_on_grid`` bisects on them); (t, s - s0,
    s', s'') every ``SCURVE_STEP_S`` and at the phases' ends, the last at ``v1``."""
    d = 1.0 if v1 >= v0 else -1.0
    dv, b0 = d * (v1 - v0), d * a0  # in the direction of the change
    if b0 > 0.0 and b0 * b0 / (2.0 * jerk) > dv:
        raise PlanError(PlanResult.INFEASIBLE, "the path acceleration overshoots the new path speed")
    peak = math.sqrt((2.0 * jerk * dv + b0 * b0) / 2.0)
    hold = 0.0
    if peak > accel:
        peak = max(accel, b0)
        hold = (dv - (peak * peak - b0 * b0) / (2.0 * jerk) - peak * peak / (2.0 * jerk)) / peak
    if peak < b0 or hold < 0.0:
        raise PlanError(PlanResult.INFEASIBLE, "the path acceleration is above the change's")
    phases = ((peak - b0) / jerk, d * jerk), (hold, 0.0), (peak / jerk, -d * jerk)
    ts, ss, vs, acc = [0.0], [0.0], [v0], [a0]
    t, s, v, a = 0.0, 0.0, v0, a0
    for length, j in phases:
        if length <= 0.0:
            continue
        tau = np.append(np.arange(SCURVE_STEP_S, length, SCURVE_STEP_S), length)
        ts.extend(t + tau)
        ss.extend(s + v * tau + a * tau**2 / 2.0 + j * tau**3 / 6.0)
        vs.extend(v + a * tau + j * tau**2 / 2.0)
        acc.extend(a + j * tau)
        t, s, v, a = ts[-1], ss[-1], vs[-1], acc[-1]
    vs[-1], acc[-1] = v1, 0.0  # to rounding
    return np.asarray(ts), np.asarray(ss), np.asarray(vs), np.asarray(acc)


def jerk_override(
    planned: Trajectory, running: Trajectory, t0: float, scale: float, accel: float, jerk: float
) -> Trajectory:
    """The rest of ``running`` from ``t0`` re-timed to ``scale`` of ``planned``'s path speed with the change of
    speed an S-curve in path time (``_speed_change``: path acceleration ``accel`` 1/s, path jerk ``jerk`` 1/s^2),
    then on it to the path's end. For a program's path (``planner.program_motion``: the plan's s' = 1, so the
    scaled plan is one path speed); time 0 of the result is ``t0``."""
    if not 0.05 <= scale <= 1.0:
        raise PlanError(PlanResult.INVALID_INPUT, f"scale must be in [0.05, 1.0], got {scale!r}", field="scale")
    if np.ptp(planned.sd) > 1e-9:
        raise PlanError(PlanResult.INVALID_INPUT, "a jerk-limited change of speed needs a plan at one path speed")
    t0 = float(np.clip(t0, 0.0, running.duration))
    s0, sd0 = _s_at(running, t0), _sd_at(running, t0)
    i = int(np.clip(np.searchsorted(running.breakpoints, t0, side="right") - 1, 0, len(running.sdd) - 1))
    v1 = scale * float(planned.sd[0])
    if sd0 < REST_SD or t0 >= running.duration - 1e-9:  # at rest (a braking's end, to rounding): from rest
        sd0, a0 = 0.0, 0.0
    else:
        a0 = float(running.sdd[i])
    _, s, v, _ = _speed_change(sd0, a0, v1, accel, jerk)
    keep = np.concatenate(([True], np.diff(s) > 1e-12))
    grid, sd = s0 + s[keep], v[keep]
    sd[-1] = v1
    end = float(planned.gridpoints[-1])
    if grid[-1] >= end:
        raise PlanError(PlanResult.INFEASIBLE, "the path ends before the jerk-limited change of speed would")
    later = planned.gridpoints[planned.gridpoints > grid[-1] + 1e-9]
    grid = np.concatenate((grid, later))
    sd = np.concatenate((sd, np.full(len(later), v1)))
    return Trajectory.from_path_velocities(running.path, grid, sd, running.joint_names)


def ramp_window_jerk_ratio(whole: Trajectory, t0: float, t1: float, max_jerk: NDArray[np.float64]) -> float:
    """The 10-ms-window joint jerk / ``max_jerk`` at most of ``whole`` from ``t0`` to ``t1`` (a change of speed),
    with the window before and after it, at every ms."""
    t = np.clip(np.arange(t0 - WINDOW_S, t1 + WINDOW_S + 1e-9, 1e-3), 0.0, whole.duration)
    acc = whole.acceleration(t)
    window = np.abs(acc[10:] - acc[:-10]) / WINDOW_S
    return float(np.max(window / np.asarray(max_jerk, dtype=float)[None, :])) if len(window) else 0.0


def change_window_jerk(
    running: Trajectory, change: Trajectory, t0: float, t_ramp: float, max_jerk: NDArray[np.float64]
) -> float:
    """``ramp_window_jerk_ratio`` of a change of speed from ``t0`` that reaches its speed ``t_ramp`` later. From rest
    (a resume: a motion of its own, after a dwell) the window before it is rest, not the braking that ended there."""
    if _sd_at(running, t0) < REST_SD or t0 >= running.duration - 1e-9:
        return ramp_window_jerk_ratio(change, 0.0, t_ramp, max_jerk)
    return ramp_window_jerk_ratio(joined(running, change), t0, t0 + t_ramp, max_jerk)


def jerk_override_rates(
    planned: Trajectory,
    running: Trajectory,
    t0: float,
    scale: float,
    limits: JointLimits,
    max_jerk: ArrayLike,
    share: float = 0.9,
    jerk_share: float = 0.9,
    tries: int = 8,
) -> tuple[float, float]:
    """(path acceleration, path jerk) of the jerk-limited change of speed (``jerk_override``) from ``t0`` to
    ``scale``: both lowered until the joints hold ``share`` of 0x60C5 and ``jerk_share`` of ``max_jerk`` (the
    10-ms window) during the change (after it the scaled plan holds what the plan held). The last try is
    returned as is: the caller checks the records."""
    jmax = np.asarray(max_jerk, dtype=float)
    t0 = float(np.clip(t0, 0.0, running.duration))
    s0 = _s_at(running, t0)
    qs = np.abs(running.path(s0, 1))
    amax = np.asarray(limits.acceleration, dtype=float)
    moving = qs > 1e-12
    if not np.any(moving):
        raise PlanError(PlanResult.INFEASIBLE, "the path has no tangent where the change begins")
    accel = share * float(np.min(amax[moving] / qs[moving]))
    jerk = jerk_share * float(np.min(jmax[moving] / qs[moving]))
    v1 = scale * float(planned.sd[0])
    last = (accel, jerk)
    for k in range(tries):
        try:
            change = jerk_override(planned, running, t0, scale, accel, jerk)
        except PlanError:
            if k == 0:
                raise
            return last  # lowered until the change no longer fits the path: the last that did
        last = (accel, jerk)
        t_ramp = float(change.time_at(np.array([_ramp_end(change)]))[0])
        part = _head(change, t_ramp)
        _, ra = part.limit_ratios(limits)
        # where the change ends near the plan's own acceleration (q''(s) s'^2), what the plan holds is the bound
        _, ra_plan = Trajectory.from_path_velocities(
            part.path, part.gridpoints, np.full(len(part.gridpoints), v1), part.joint_names
        ).limit_ratios(limits)
        allowed = max(share, min(ra_plan, 1.0))
        rj = change_window_jerk(running, change, t0, t_ramp, jmax)
        if ra <= allowed and rj <= jerk_share:
            break
        accel, jerk = _lowered(accel, ra, allowed), _lowered(jerk, rj, jerk_share)
    return accel, jerk


# the factors of the first rates (``jerk_override_rates``) a jerk-limited change of speed is tried with where those
# do not hold the limits: late in the motion the change meets the plan's own deceleration, where the joints' jerk
# has a term 3 q''(s) s' s'' of the change's path acceleration, and lowering both rates together stretches the
# change further into it; a lower jerk at the same acceleration, or the reverse, may hold
RATE_FACTORS = (1.0, 0.75, 0.55, 0.4, 0.3, 0.2)


def _change_held(
    planned: Trajectory,
    running: Trajectory,
    t0: float,
    scale: float,
    accel: float,
    jerk: float,
    limits: JointLimits,
    jmax: NDArray[np.float64],
    share: float,
    jerk_share: float,
) -> float | None:
    """The motion's end (s) with the jerk-limited change at these rates, None where the change does not fit
    before the path's end or passes ``share`` of 0x60C5 (or what the plan holds where it ends, as in
    ``jerk_override_rates``) or ``jerk_share`` of the jerk limit (the 10-ms window) while it changes speed."""
    try:
        change = jerk_override(planned, running, t0, scale, accel, jerk)
        whole = joined(running, change)
    except PlanError:
        return None
    t_ramp = float(change.time_at(np.array([_ramp_end(change)]))[0])
    part = _head(change, t_ramp)
    _, ra = part.limit_ratios(limits)
    v1 = scale * float(planned.sd[0])
    _, ra_plan = Trajectory.from_path_velocities(
        part.path, part.gridpoints, np.full(len(part.gridpoints), v1), part.joint_names
    ).limit_ratios(limits)
    if ra > max(share, min(ra_plan, 1.0)) or change_window_jerk(running, change, t0, t_ramp, jmax) > jerk_share:
        return None
    return whole.duration


def jerk_change_rates(
    planned: Trajectory,
    running: Trajectory,
    t0: float,
    scale: float,
    limits: JointLimits,
    max_jerk: ArrayLike,
    share: float = 0.9,
    jerk_share: float = 0.9,
) -> list[tuple[float, float]]:
    """The (path acceleration, path jerk) pairs of a jerk-limited change of speed to ``scale`` from ``t0`` that
    hold ``share`` of 0x60C5 and ``jerk_share`` of ``max_jerk`` while the speed changes, the soonest end of the
    motion first: ``jerk_override_rates``' answer where it holds, else ``RATE_FACTORS`` of its first rates,
    each independently. Empty where none holds."""
    jmax = np.asarray(max_jerk, dtype=float)
    t0 = float(np.clip(t0, 0.0, running.duration))
    first = jerk_override_rates(planned, running, t0, scale, limits, jmax, share, jerk_share)
    if _change_held(planned, running, t0, scale, *first, limits, jmax, share, jerk_share) is not None:
        return [first]
    qs = np.abs(running.path(_s_at(running, t0), 1))
    moving = qs > 1e-12
    amax = np.asarray(limits.acceleration, dtype=float)
    accel = share * float(np.min(amax[moving] / qs[moving]))
    jerk = jerk_share * float(np.min(jmax[moving] / qs[moving]))
    held = []
    for fa in RATE_FACTORS:
        for fj in RATE_FACTORS:
            end = _change_held(planned, running, t0, scale, accel * fa, jerk * fj, limits, jmax, share, jerk_share)
            if end is not None:
                held.append((end, accel * fa, jerk * fj))
    return [(a, j) for _, a, j in sorted(held)]


def _ramp_end(change: Trajectory) -> float:
    """Where a ``jerk_override`` change reaches its path speed (s)."""
    off = np.nonzero(np.abs(change.sd - change.sd[-1]) > 1e-12)[0]
    return float(change.gridpoints[min(int(off[-1]) + 1, len(change.gridpoints) - 1)]) if len(off) else 0.0


def _head(change: Trajectory, t: float) -> Trajectory:
    """``change`` up to its gridpoint at or after time ``t``."""
    n = int(np.searchsorted(change.breakpoints, t - 1e-12)) + 1
    n = max(2, min(n, len(change.gridpoints)))
    return Trajectory.from_path_velocities(change.path, change.gridpoints[:n], change.sd[:n], change.joint_names)


def joined(running: Trajectory, change: Trajectory) -> Trajectory:
    """``running`` until where ``change`` begins on the path, then ``change``: one trajectory, the motion as
    the drives run it after an override."""
    s0 = float(change.gridpoints[0])
    before = running.gridpoints < s0 - 1e-12
    grid = np.concatenate([running.gridpoints[before], change.gridpoints])
    sd = np.concatenate([running.sd[before], change.sd])
    if sd[-1] != 0.0 and grid[-1] < running.gridpoints[-1]:
        raise PlanError(PlanResult.INFEASIBLE, "the change does not reach the motion's end")
    return Trajectory.from_path_velocities(running.path, grid, sd, running.joint_names)
