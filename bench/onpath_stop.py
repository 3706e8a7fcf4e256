"""On-path stop vs quick stop (issue 37, planner side), on arm6 and gantry3.

Per stop moment (10..90 % of a full-speed move): the tool's largest distance to the planned tool path
while braking (on-path: the braking trajectory; quick: each axis on its own 0x60C5 from the same state),
both braking durations, the braking's limit fractions, and the latency of ``brake_on_path`` and of
``override`` (p50/p99). Run: PYTHONPATH=. python3 bench/onpath_stop.py
"""

from __future__ import annotations

import time

import numpy as np

from pvtflow.planner.onpath_stop import brake_on_path, override, quick_stop_time
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import planner_for_cell
from pvtflow.service.config import CONFIG_DIR, load_cell_config

MOVES = {
    "arm6": np.array(
        [[0.0, -1.0, 1.2, 0.3, -0.2, 0.0], [1.1, 0.2, -0.4, -0.6, 0.5, 1.0], [-0.5, 0.6, 0.3, 0.8, -0.7, -1.2]]
    ),
    "gantry3": None,
}


def _tool(model, q: np.ndarray) -> np.ndarray:
    return np.array([model.frame_placement(qi, "tool0")[:3, 3] for qi in q])


def _distance_mm(points: np.ndarray, path_points: np.ndarray) -> float:
    d = np.linalg.norm(points[:, None, :] - path_points[None, :, :], axis=2).min(axis=1)
    return float(d.max() * 1000.0)


def _quick_positions(q0: np.ndarray, v0: np.ndarray, amax: np.ndarray, n: int = 200) -> np.ndarray:
    tstop = np.abs(v0) / amax
    t = np.linspace(0.0, tstop.max(), n)[:, None]
    tt = np.minimum(t, tstop[None, :])
    return q0 + v0 * tt - 0.5 * np.sign(v0) * amax * tt * tt


def main() -> None:
    for name in ("arm6", "gantry3"):
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        limits = cell.joint_limits()
        wp = MOVES[name]
        if wp is None:
            wp = limits.lower + (limits.upper - limits.lower) * np.array(
                [[0.25] * limits.dof, [0.75] * limits.dof, [0.3, 0.7, 0.5][: limits.dof]]
            )
        motion = planner_for_cell(cell).plan(PlanInput(wp)).trajectory
        # the planned tool path, densely in s (the distances below are upper bounds by this sampling)
        dense = motion.path(np.linspace(motion.gridpoints[0], motion.gridpoints[-1], 40000))
        path_tool = _tool(cell.model, dense)
        amax = np.asarray(limits.acceleration, dtype=float)
        print(f"{name}: move {motion.duration * 1000:.0f} ms")
        print("  at  | on-path mm | quick mm | on-path ms | quick ms | vel frac | acc frac")
        brake_lat, over_lat = [], []
        for f in (0.1, 0.3, 0.5, 0.7, 0.9):
            t0 = f * motion.duration
            for _ in range(20):
                a = time.perf_counter()
                stop = brake_on_path(motion, t0, limits)
                brake_lat.append(time.perf_counter() - a)
                a = time.perf_counter()
                override(motion, motion, t0, 0.3, limits)
                over_lat.append(time.perf_counter() - a)
            b = stop.trajectory
            on = _distance_mm(_tool(cell.model, b.position(np.linspace(0.0, b.duration, 200))), path_tool)
            q0, v0 = motion.position(t0), motion.velocity(t0)
            quick = _distance_mm(_tool(cell.model, _quick_positions(q0, v0, amax)), path_tool)
            rv, ra = b.limit_ratios(limits)
            qt = quick_stop_time(motion, t0, limits)
            times = f"{stop.duration * 1000:10.1f} | {qt * 1000:8.1f}"
            print(f"  {f:.1f} | {on:10.3f} | {quick:8.3f} | {times} | {rv:8.3f} | {ra:8.3f}")
        for label, lat in (("brake_on_path", brake_lat), ("override", over_lat)):
            ms = np.array(lat) * 1000.0
            print(f"  {label} latency: p50 {np.percentile(ms, 50):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms")


if __name__ == "__main__":
    main()
