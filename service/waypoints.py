"""Waypoint files: pvtflow's own JSON and the shape of a ROS ``trajectory_msgs/JointTrajectory``.

Accepted (JSON, or YAML for the ROS shape; the file's content decides, not its extension):

- pvtflow: ``{"joint_names": [...], "waypoints": [[q1, ..., qn], ...]}`` (``joint_names`` optional:
  without it the values are in the cell's joint order), or a bare list of lists;
- ROS JointTrajectory: ``{"joint_names": [...], "points": [{"positions": [...], ...}, ...]}``,
  also wrapped as ``{"trajectory": {...}}`` or ``{"joint_trajectory": {...}}`` (as in a
  ``rostopic echo`` / ``ros2 topic echo`` dump or a MoveIt result). Only the positions are used:
  pvtflow computes its own timing. Points' ``time_from_start`` are not lower bounds the planner could
  hold per segment (TOPP-RA times the whole path at once, and a segment slowed alone would change the
  velocities at its ends), so they are dropped out loud: :func:`ros_time_from_start` gives the file's
  last one, and ``pvtflow plan`` / ``pvtflow request plan`` warn with it.

- tool poses: ``{"poses": [[x, y, z, qx, qy, qz, qw], ...], "motion": "linear", "start": [q1, ..., qn]}``
  (``motion``: linear, the default, or joint; ``start``: joint values, or "current" where a service
  knows where the axes are; ``joint_names`` optional, the order of ``start``): read by
  :func:`load_motion` as :class:`PoseTargets`.

Joint values are reordered by name into the cell's joint order. Every problem is a
:class:`WaypointError` naming the file and the place in it, never a traceback.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from pvtflow.planner.cartesian import MoveKind, check_poses
from pvtflow.planner.path import PlanError

POSE_FILE_FIELDS = ("poses", "motion", "start", "joint_names")


class WaypointError(ValueError):
    """A waypoint file that cannot be used; the message says which file and where."""


@dataclass(frozen=True)
class PoseTargets:
    """A pose file: the tool poses (N, 7, unit quaternions), how to go through them, and the joint
    positions to start from (None: where the axes are)."""

    poses: NDArray[np.float64]
    motion: str
    start: NDArray[np.float64] | None


def load_motion(path: str | Path, joint_names: Sequence[str], min_count: int = 2) -> NDArray[np.float64] | PoseTargets:
    """The waypoints of ``path`` (as :func:`load_waypoints`), or its poses when it is a pose file."""
    data = _read(path)
    if isinstance(data, dict) and "poses" in data:
        return poses_from_data(data, joint_names, str(path))
    return waypoints_from_data(data, joint_names, str(path), min_count)


def poses_from_data(data: dict[str, Any], joint_names: Sequence[str], source: str) -> PoseTargets:
    """A pose file's content, checked (the poses by the planner's own rules)."""
    unknown = sorted(set(data) - set(POSE_FILE_FIELDS))
    if unknown:
        raise WaypointError(f"{source}: unknown field {unknown[0]!r} (a pose file has {', '.join(POSE_FILE_FIELDS)})")
    rows = data["poses"]
    if not isinstance(rows, list) or not rows:
        raise WaypointError(f"{source}: poses: must be a non-empty list of [x, y, z, qx, qy, qz, qw]")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 7:
            got = f"{len(row)} values" if isinstance(row, list) else repr(row)
            raise WaypointError(f"{source}: poses[{i}]: must be [x, y, z, qx, qy, qz, qw], got {got}")
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise WaypointError(f"{source}: poses[{i}][{j}]: must be a finite number, got {x!r}")
    try:
        poses = check_poses(rows)
    except PlanError as exc:
        raise WaypointError(f"{source}: poses: {exc.message}") from None
    motion = data.get("motion", MoveKind.LINEAR.value)
    if motion not in [m.value for m in MoveKind]:
        raise WaypointError(f"{source}: motion: must be linear or joint, got {motion!r}")
    start = data.get("start", "current")
    if start == "current":
        return PoseTargets(poses, motion, None)
    if not isinstance(start, list):
        raise WaypointError(f'{source}: start: must be a list of joint values or "current", got {start!r}')
    names = data.get("joint_names")
    try:
        rows_in_order = waypoints_from_data(
            {"waypoints": [start], **({"joint_names": names} if names is not None else {})}, joint_names, source, 1
        )
    except WaypointError as exc:  # the joint values' own checks, worded for the start
        raise WaypointError(str(exc).replace("waypoints[0]", "start")) from None
    return PoseTargets(poses, motion, rows_in_order[0])


def ros_time_from_start(path: str | Path) -> float | None:
    """The last ``time_from_start`` (s) of a ROS JointTrajectory file whose points carry any that is not 0
    (None: no times, or not such a file). ROS 1 ``{secs, nsecs}``, ROS 2 ``{sec, nanosec}`` or seconds."""
    try:
        data = _read(path)
    except WaypointError:
        return None
    if isinstance(data, dict):
        for key in ("trajectory", "joint_trajectory"):
            if isinstance(data.get(key), dict):
                data = data[key]
                break
    points = data.get("points") if isinstance(data, dict) else None
    if not isinstance(points, list):
        return None
    times = [_seconds(p.get("time_from_start")) for p in points if isinstance(p, dict)]
    known = [x for x in times if x is not None]
    return max(known) if known and max(known) > 0 else None


def _seconds(value: Any) -> float | None:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, dict):
        whole = value.get("secs", value.get("sec", 0))
        frac = value.get("nsecs", value.get("nanosec", 0))
        if all(isinstance(x, int | float) and not isinstance(x, bool) for x in (whole, frac)):
            return float(whole) + float(frac) * 1e-9
    return None


def dropped_times_warning(path: str | Path, duration_s: float | None = None) -> str | None:
    """The warning for a file whose ``time_from_start`` pvtflow does not use (None: it has none)."""
    last = ros_time_from_start(path)
    if last is None:
        return None
    planned = f" ({duration_s:.3f} s here)" if duration_s is not None else ""
    return (
        f"warning: {path}: the points' time_from_start (the last {last:g} s) are not used: pvtflow times the "
        f"motion itself, time-optimal within the limits{planned}; slow it down with --velocity-scale / "
        "--acceleration-scale"
    )


@dataclass(frozen=True)
class SequenceTargets:
    """A sequence file (``{"start": "current" | [joints], "sequence": [items]}``, the plan request's
    object): the items as written (planner/sequence.py checks them) and the start (None: current)."""

    items: list[Any]
    start: NDArray[np.float64] | None


def load_sequence(path: str | Path, joint_names: Sequence[str]) -> SequenceTargets:
    """A motion sequence file, JSON or YAML (WaypointError saying what is wrong with its shape)."""
    data, source = _read(path), str(path)
    if not isinstance(data, dict) or "sequence" not in data:
        raise WaypointError(f'{source}: a sequence file is {{"start": ..., "sequence": [items]}}')
    unknown = sorted(set(data) - {"sequence", "start", "joint_names"})
    if unknown:
        raise WaypointError(f"{source}: unknown field {unknown[0]!r}")
    items = data["sequence"]
    if not isinstance(items, list) or not items:
        raise WaypointError(f"{source}: sequence: must be a non-empty list of items")
    start = data.get("start", "current")
    if start == "current":
        return SequenceTargets(items, None)
    if not isinstance(start, list):
        raise WaypointError(f'{source}: start: must be a list of joint values or "current", got {start!r}')
    names = data.get("joint_names")
    try:
        rows = waypoints_from_data(
            {"waypoints": [start], **({"joint_names": names} if names is not None else {})}, joint_names, source, 1
        )
    except WaypointError as exc:
        raise WaypointError(str(exc).replace("waypoints[0]", "start")) from None
    return SequenceTargets(items, rows[0])


def load_waypoints(path: str | Path, joint_names: Sequence[str], min_count: int = 2) -> NDArray[np.float64]:
    """(N, dof) waypoints from ``path`` in the order of ``joint_names``; at least ``min_count`` of them
    (2 for a motion planned on its own; 1 for the service, which starts from where the axes are)."""
    return waypoints_from_data(_read(path), joint_names, str(path), min_count)


def _read(path: str | Path) -> Any:
    """The JSON or YAML content of a waypoint file."""
    file = Path(path)
    if not file.is_file():
        raise WaypointError(f"{file}: {'is a directory' if file.is_dir() else 'file not found'}")
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise WaypointError(f"{file}: cannot read: {exc}") from None
    return _parse(text, str(file))


def parse_waypoints(
    text: str, joint_names: Sequence[str], source: str = "waypoints", min_count: int = 2
) -> NDArray[np.float64]:
    """Waypoints from JSON or YAML text (see the module doc for the accepted shapes)."""
    return waypoints_from_data(_parse(text, source), joint_names, source, min_count)


def _parse(text: str, source: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        try:
            return yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise WaypointError(f"{source}: neither JSON nor YAML ({str(exc).splitlines()[0]})") from None


def waypoints_from_data(
    data: Any, joint_names: Sequence[str], source: str = "waypoints", min_count: int = 2
) -> NDArray[np.float64]:
    if isinstance(data, dict):
        for key in ("trajectory", "joint_trajectory"):
            if key in data and isinstance(data[key], dict) and "points" in data[key]:
                data = data[key]
                break
    if isinstance(data, list):
        names, rows, kind = None, data, "waypoints"
        where = ""
    elif isinstance(data, dict) and "points" in data:
        names = data.get("joint_names")
        points = data["points"]
        if not isinstance(points, list) or not points:
            raise WaypointError(f"{source}: points: must be a non-empty list of trajectory points")
        rows = []
        for i, pt in enumerate(points):
            if not isinstance(pt, dict) or "positions" not in pt:
                raise WaypointError(f"{source}: points[{i}]: needs 'positions' (a JointTrajectoryPoint)")
            rows.append(pt["positions"])
        kind, where = "points", ".positions"
    elif isinstance(data, dict) and "waypoints" in data:
        names = data.get("joint_names")
        rows, kind, where = data["waypoints"], "waypoints", ""
    else:
        raise WaypointError(
            f"{source}: not a waypoint file: expected {{'waypoints': [[...], ...]}} or a ROS JointTrajectory "
            "{'joint_names': [...], 'points': [{'positions': [...]}, ...]}"
        )
    if not isinstance(rows, list) or not rows:
        raise WaypointError(f"{source}: {kind}: must be a non-empty list")

    dof = len(joint_names)
    if names is not None:
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise WaypointError(f"{source}: joint_names: must be a list of strings")
        if len(set(names)) != len(names):
            raise WaypointError(f"{source}: joint_names: a joint is listed twice")
        unknown = [n for n in names if n not in joint_names]
        if unknown:
            raise WaypointError(
                f"{source}: joint_names: unknown joint {unknown[0]!r} (the cell has {', '.join(joint_names)})"
            )
        missing = [n for n in joint_names if n not in names]
        if missing:
            raise WaypointError(f"{source}: joint_names: joint {missing[0]!r} of the cell is missing")
        order = [names.index(n) for n in joint_names]
        width = len(names)
    else:
        order = list(range(dof))
        width = dof

    out = np.empty((len(rows), dof))
    for i, row in enumerate(rows):
        here = f"{source}: {kind}[{i}]{where}"
        if not isinstance(row, list) or len(row) != width:
            got = f"{len(row)} values" if isinstance(row, list) else repr(row)
            raise WaypointError(f"{here}: must be a list of {width} joint values, got {got}")
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise WaypointError(f"{here}[{j}]: must be a finite number, got {x!r}")
        out[i] = [float(row[k]) for k in order]
    if len(out) < min_count:
        raise WaypointError(f"{source}: a motion needs at least {min_count} waypoints, got {len(out)}")
    return out
