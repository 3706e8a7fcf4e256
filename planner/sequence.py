"""A motion sequence: PTP, LIN and CIRC items blended into one joint path (issue 38).

Each item goes from where the previous one ends (the start for the first) to its goal: ``ptp`` a
straight line in joint space to ``target`` (joints) or to the inverse-kinematics solution of
``pose``; ``lin`` the tool on a straight line to ``pose`` (orientation by slerp); ``circ`` the tool
on the circular arc through ``via`` (or about ``center``) to ``pose``. An item with ``blend_radius``
r > 0 does not stop at its goal: the tool leaves the item's path where it enters the sphere of
radius r about the goal and joins the next item's path where it leaves that sphere, on a joint-space
cubic Hermite curve tangent to both paths (its tangents scaled to the chord between the two points,
so that the curve stays close to the corner's triangle, which lies inside the sphere). Outside the
spheres the joint samples lie on the items' paths (lines and arcs: within ``LineTolerance``, checked
on the joint path itself as for poses). The whole sequence is one joint path, timed once by the
planner (TOPP-RA, then jerk-limited timing when asked): every limit holds inside the blends as
elsewhere, and the validator checks the drives' reconstruction as for every program.

Blend spheres never overlap and are never shrunk: the sum of two neighbours' radii above the
distance between their goals, or a radius above half of its own item's or the next item's length,
is refused naming both items. An item that cannot be planned refuses the sequence naming it
(``details["item"]``) with the same results as poses (planner/cartesian.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from pvtflow.planner.cartesian import (
    CartesianResult,
    LineTolerance,
    MoveKind,
    PoseSolver,
    ToolLine,
    ToolPath,
    check_poses,
    pose_placement,
)
from pvtflow.planner.path import PlanError, PlanResult

MOTIONS = ("ptp", "lin", "circ")
ITEM_FIELDS = frozenset({"motion", "target", "pose", "via", "center", "blend_radius", "label"})
# An arc's center must be this close to equidistant from its two ends (m).
ARC_TOLERANCE = 1e-4
# A PTP item's joint line is sampled at least this finely (rad or m), and so is a blend.
PTP_STEP = 0.1
BLEND_STEP = 0.05
MIN_BLEND_SAMPLES = 8
# The tool's distances from an exact stop (m) where samples are added on both sides of it.
STOP_SAMPLES = (0.0002, 0.001, 0.004)
# A ptp item's tool path is measured on its joint line sampled this finely (rad or m).
PTP_CHECK_STEP = 0.002
# Where a path crosses a sphere is found on this many samples, then by bisection.
CROSSING_SAMPLES = 64
CROSSING_ITERATIONS = 40


@dataclass(frozen=True)
class SequenceItem:
    """One checked item: ``goal`` the tool placement it ends at (PTP with ``target``: None until solved)."""

    motion: str
    blend_radius: float
    label: str | None
    target: NDArray[np.float64] | None = None  # ptp joints
    pose: NDArray[np.float64] | None = None
    via: NDArray[np.float64] | None = None  # circ: a point on the arc
    center: NDArray[np.float64] | None = None  # circ: the arc's center


def _refuse(i: int, message: str, result: Any = PlanResult.INVALID_INPUT, **details: object) -> PlanError:
    return PlanError(result, f"sequence item {i}: {message}", item=i, **details)


def _point(i: int, name: str, value: object) -> NDArray[np.float64]:
    try:
        p = np.array(value, dtype=float)
    except (TypeError, ValueError):
        p = np.array([])
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise _refuse(i, f"{name} must be [x, y, z] (3 finite numbers, m), got {value!r}", field=name)
    return p


def check_items(items: object, dof: int) -> list[SequenceItem]:
    """The sequence's items checked (PlanError INVALID_INPUT naming the item and the field at fault)."""
    if not isinstance(items, Sequence) or isinstance(items, str) or not items:
        raise PlanError(PlanResult.INVALID_INPUT, "sequence must be a non-empty list of items")
    out = []
    for i, raw in enumerate(items):
        if not isinstance(raw, dict):
            raise _refuse(i, 'an item is an object {"motion": "ptp" | "lin" | "circ", ...}')
        unknown = sorted(set(raw) - ITEM_FIELDS)
        if unknown:
            raise _refuse(i, f"unknown field {unknown[0]!r}", field=unknown[0])
        motion = raw.get("motion")
        if motion not in MOTIONS:
            raise _refuse(i, f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}", field="motion")
        r = raw.get("blend_radius", 0.0)
        if isinstance(r, bool) or not isinstance(r, int | float) or not math.isfinite(r) or r < 0:
            raise _refuse(i, f"blend_radius must be a number >= 0 (m), got {r!r}", field="blend_radius")
        label = raw.get("label")
        if label is not None and not isinstance(label, str):
            raise _refuse(i, f"label must be a string, got {label!r}", field="label")
        pose = None
        if "pose" in raw:
            try:
                pose = check_poses([raw["pose"]])[0]
            except PlanError as exc:
                raise _refuse(i, f"pose: {exc.message.removeprefix('pose 0: ')}", field="pose") from None
        target = None
        if "target" in raw:
            try:
                target = np.array(raw["target"], dtype=float)
            except (TypeError, ValueError):
                target = np.array([])
            if target.shape != (dof,) or not np.all(np.isfinite(target)):
                raise _refuse(i, f"target must be {dof} finite joint values", field="target")
        via = _point(i, "via", raw["via"]) if "via" in raw else None
        center = _point(i, "center", raw["center"]) if "center" in raw else None
        if motion == "ptp":
            if (target is None) == (pose is None):
                raise _refuse(i, "a ptp item has a target (joints) or a pose, one of them", field="target")
            if via is not None or center is not None:
                raise _refuse(i, "via and center are for circ items", field="via" if via is not None else "center")
        else:
            if pose is None:
                raise _refuse(i, f"a {motion} item needs a pose", field="pose")
            if target is not None:
                raise _refuse(i, "target (joints) is for ptp items", field="target")
            if motion == "lin" and (via is not None or center is not None):
                raise _refuse(i, "via and center are for circ items", field="via" if via is not None else "center")
            if motion == "circ" and (via is None) == (center is None):
                raise _refuse(i, "a circ item has a via point or a center, one of them", field="via")
        last = i == len(items) - 1
        out.append(SequenceItem(motion, 0.0 if last else float(r), label, target, pose, via, center))
    return out


class ToolArc:
    """The commanded circular motion from placement ``a`` to ``b``: the position on the arc about
    ``center`` (normal ``axis``, angle ``sweep``), the orientation by slerp, both in step with u."""

    def __init__(self, a: pin.SE3, b: pin.SE3, center: NDArray[np.float64], axis: NDArray[np.float64], sweep: float):
        self.a, self.b = a.copy(), b.copy()
        self.center, self.axis, self.sweep = center, axis, sweep
        self.arm = a.translation - center
        self.radius = float(np.linalg.norm(self.arm))
        self.length = self.radius * sweep
        self.turn = pin.log3(a.rotation.T @ b.rotation)
        self.angle = float(np.linalg.norm(self.turn))

    @classmethod
    def through(cls, i: int, a: pin.SE3, b: pin.SE3, via: NDArray | None, center: NDArray | None) -> ToolArc:
        """The arc from a to b through ``via`` or about ``center`` (PlanError naming item i when there is none)."""
        p0, p1 = a.translation, b.translation
        if via is not None:
            ab, ac = via - p0, p1 - p0
            n = np.cross(ab, ac)
            nn = float(n @ n)
            if nn < 1e-12 * max(1e-12, float(ab @ ab) * float(ac @ ac)) or nn < 1e-16:
                raise _refuse(i, "the start, via and pose of a circ are on one line: no arc through them", field="via")
            c = p0 + (np.cross(n, ab) * float(ac @ ac) + np.cross(ac, n) * float(ab @ ab)) / (2.0 * nn)
            axis = n / math.sqrt(nn)
        else:
            assert center is not None
            c = center
            r0, r1 = float(np.linalg.norm(p0 - c)), float(np.linalg.norm(p1 - c))
            if abs(r0 - r1) > ARC_TOLERANCE:
                raise _refuse(
                    i,
                    f"the start and the pose are {r0:.4f} m and {r1:.4f} m from the center: not one circle",
                    field="center",
                )
            n = np.cross(p0 - c, p1 - c)
            if float(np.linalg.norm(n)) < 1e-9 * max(r0 * r1, 1e-12):
                raise _refuse(
                    i, "with a center, the arc's ends must not be opposite (or equal): use via", field="center"
                )
            axis = n / float(np.linalg.norm(n))
        ra, rc = p0 - c, p1 - c
        sweep = math.atan2(float(np.cross(ra, rc) @ axis), float(ra @ rc))
        if sweep <= 0.0:
            sweep += 2.0 * math.pi
        return cls(a, b, c, axis, sweep)

    def position(self, u: float) -> NDArray[np.float64]:
        rot = pin.exp3(u * self.sweep * self.axis)
        return self.center + rot @ self.arm

    def at(self, u: float) -> pin.SE3:
        return pin.SE3(self.a.rotation @ pin.exp3(u * self.turn), self.position(u))

    def twist(self, u: float) -> NDArray[np.float64]:
        rotation = self.a.rotation @ pin.exp3(u * self.turn)
        dp = self.sweep * np.cross(self.axis, self.position(u) - self.center)
        return np.concatenate((rotation.T @ dp, self.turn))

    def deviation(self, placement: pin.SE3, tolerance: LineTolerance) -> tuple[float, float, float]:
        """(position m, orientation rad, u): u from the position's angle about the axis (from the
        orientation when the arc has no length)."""
        p = placement.translation
        rel = self.a.rotation.T @ placement.rotation
        if self.length > 0.0:
            d = p - self.center
            phi = math.atan2(float(np.cross(self.arm, d) @ self.axis), float(self.arm @ d))
            if phi < -0.5 * (2.0 * math.pi - self.sweep):
                phi += 2.0 * math.pi
            u = phi / self.sweep
        else:
            u = float(np.dot(pin.log3(rel), self.turn)) / (self.angle * self.angle) if self.angle > 0 else 0.0
        u = min(max(u, 0.0), 1.0)
        dp = float(np.linalg.norm(p - self.position(u)))
        dr = float(np.linalg.norm(pin.log3(pin.exp3(-u * self.turn) @ rel)))
        return dp, dr, u


class Piece:
    """The stretch [u0, u1] of a line or an arc, itself parametrized by u in [0, 1] (the same
    interface as ToolLine, so that the pose solver marches and checks it as a line)."""

    def __init__(self, curve: ToolLine | ToolArc, u0: float, u1: float) -> None:
        self.curve, self.u0, self.u1 = curve, u0, u1
        self.span = u1 - u0
        self.a, self.b = curve.at(u0), curve.at(u1)
        self.length = curve.length * self.span
        self.angle = curve.angle * self.span

    def at(self, u: float) -> pin.SE3:
        return self.curve.at(self.u0 + u * self.span)

    def twist(self, u: float) -> NDArray[np.float64]:
        return self.curve.twist(self.u0 + u * self.span) * self.span

    def deviation(self, placement: pin.SE3, tolerance: LineTolerance) -> tuple[float, float, float]:
        dp, dr, u = self.curve.deviation(placement, tolerance)
        return dp, dr, min(max((u - self.u0) / self.span, 0.0), 1.0)


class JointLine:
    """A ptp item's stretch [u0, u1] of its joint line, as the tool goes along it: the same
    interface as ToolLine, so that the joint path through its samples is checked against the tool's
    path there (the spline through the samples bends off the joint line next to a blend, else)."""

    def __init__(self, fk: Callable[[NDArray[np.float64]], pin.SE3], qa: NDArray, qb: NDArray, u0: float, u1: float):
        self.fk, self.qa, self.step = fk, qa, qb - qa
        self.u0, self.span = u0, u1 - u0
        n = max(2, math.ceil(float(np.max(np.abs(self.step))) * max(self.span, 1e-9) / PTP_CHECK_STEP))
        self.grid = np.linspace(0.0, 1.0, n + 1)
        self.placements = [self.at(float(u)) for u in self.grid]
        self.points = np.array([m.translation for m in self.placements])
        self.a, self.b = self.placements[0], self.placements[-1]
        self.length = float(np.sum(np.linalg.norm(np.diff(self.points, axis=0), axis=1)))
        self.angle = 0.0

    def joints(self, u: float) -> NDArray[np.float64]:
        return self.qa + (self.u0 + u * self.span) * self.step

    def at(self, u: float) -> pin.SE3:
        return self.fk(self.joints(u))

    def deviation(self, placement: pin.SE3, tolerance: LineTolerance) -> tuple[float, float, float]:
        p = placement.translation
        a, ab = self.points[:-1], np.diff(self.points, axis=0)
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30), 0.0, 1.0)
        d = np.linalg.norm(a + t[:, None] * ab - p, axis=1)
        k = int(np.argmin(d))
        u = float(self.grid[k] + t[k] * (self.grid[k + 1] - self.grid[k]))
        dr = float(np.linalg.norm(pin.log3(self.at(u).rotation.T @ placement.rotation)))
        return float(d[k]), dr, u


class Unchecked:
    """A joint-space stretch (a PTP line, a blend): the tool's distance to it is not a tool path's."""

    def deviation(self, placement: pin.SE3, tolerance: LineTolerance) -> tuple[float, float, float]:
        return 0.0, 0.0, 0.0


@dataclass(frozen=True)
class SequencePath:
    """The joint path of a sequence and, per item, the index of its last joint sample (where the
    next item takes over: its goal, or the middle of its blend)."""

    tool: ToolPath
    item_end: list[int]
    goals: list[pin.SE3]
    # per item: its tool path (a ToolLine, ToolArc or, for ptp, JointLine)
    paths: list[Any]
    radii: list[float]


def _crossing(f: Callable[[float], float], r: float, from_end: bool) -> float:
    """The u in [0, 1] where the distance f(u) crosses r: the last crossing into the sphere
    about the end (``from_end``), else the first crossing out of the sphere about the start."""
    us = np.linspace(0.0, 1.0, CROSSING_SAMPLES + 1)
    d = np.array([f(float(u)) for u in us])
    if from_end:
        outside = np.flatnonzero(d >= r)
        k = int(outside[-1]) if len(outside) else 0
        lo, hi = float(us[k]), float(us[min(k + 1, len(us) - 1)])
    else:
        outside = np.flatnonzero(d >= r)
        k = int(outside[0]) if len(outside) else len(us) - 1
        lo, hi = float(us[max(k - 1, 0)]), float(us[k])
    for _ in range(CROSSING_ITERATIONS):
        mid = 0.5 * (lo + hi)
        if (f(mid) >= r) == from_end:
            lo = mid
        else:
            hi = mid
    return hi if from_end else lo


class SequenceSolver:
    """Sequence items -> one joint path, through the pose solver's inverse kinematics and checks."""

    def __init__(self, poses: PoseSolver) -> None:
        self.poses = poses
        self.ik = poses.ik

    def _position(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(self.ik.fk(q).translation, dtype=float)

    def _goals(self, q0: NDArray[np.float64], items: list[SequenceItem]) -> list[pin.SE3]:
        goals = []
        for i, item in enumerate(items):
            if item.target is not None:
                lo, hi = self.ik.lower, self.ik.upper
                out = np.flatnonzero((item.target < lo - 1e-9) | (item.target > hi + 1e-9))
                if len(out):
                    name = self.ik.robot.joint_names[int(out[0])]
                    raise _refuse(
                        i, f"target: joint {name} is outside its limits", PlanResult.WAYPOINT_OUT_OF_LIMITS, joint=name
                    )
                goals.append(self.ik.fk(item.target))
            else:
                assert item.pose is not None
                goals.append(pose_placement(item.pose))
        return goals

    def _check_radii(self, start: pin.SE3, items: list[SequenceItem], goals: list[pin.SE3]) -> None:
        """Overlapping blend spheres are refused naming both items (never shrunk)."""
        lengths = []
        here = start.translation
        for _item, goal in zip(items, goals, strict=True):
            lengths.append(float(np.linalg.norm(goal.translation - here)))
            here = goal.translation
        for i in range(len(items) - 1):
            r, r_next = items[i].blend_radius, items[i + 1].blend_radius
            if r <= 0.0:
                continue
            gap = float(np.linalg.norm(goals[i + 1].translation - goals[i].translation))
            if r + r_next > gap:
                raise PlanError(
                    PlanResult.INVALID_INPUT,
                    f"sequence items {i} and {i + 1}: their blend radii {r:g} m + {r_next:g} m exceed the "
                    f"{gap:.4g} m between their goals (blend spheres must not overlap; radii are never shrunk)",
                    item=i,
                    items=[i, i + 1],
                    field="blend_radius",
                )
            for j in (i, i + 1):
                if r > 0.5 * lengths[j]:
                    raise PlanError(
                        PlanResult.INVALID_INPUT,
                        f"sequence items {i} and {i + 1}: item {i}'s blend radius {r:g} m is more than half of "
                        f"item {j}'s length {lengths[j]:.4g} m",
                        item=i,
                        items=[i, i + 1],
                        field="blend_radius",
                    )

    def check(self, start: object, raw_items: object) -> tuple[NDArray[np.float64], list[SequenceItem], list[pin.SE3]]:
        """The start, the items and their goals, checked as a whole (PlanError naming the item at fault):
        every field, every goal's inverse kinematics, the blend spheres."""
        q0 = np.asarray(start, dtype=float)
        if q0.shape != self.ik.lower.shape or not np.all(np.isfinite(q0)):
            raise PlanError(PlanResult.INVALID_INPUT, f"start must be {len(self.ik.lower)} finite joint values")
        items = check_items(raw_items, len(q0))
        goals = self._goals(q0, items)
        self._check_radii(self.ik.fk(q0), items, goals)
        return q0, items, goals

    def solve(self, start: object, raw_items: object) -> SequencePath:
        """The joint path of the sequence from joint positions ``start``."""
        q0, items, goals = self.check(start, raw_items)
        here = self.ik.fk(q0)

        qs: list[NDArray[np.float64]] = [q0]
        seg_of: list[int] = [-1]
        fraction: list[float] = [0.0]
        segments: dict[int, Any] = {}
        seg_item: dict[int, int] = {}
        paths: list[Any] = []
        q_goal = q0
        pending: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # (q, joint tangent) blend start
        r_prev = 0.0
        for i, item in enumerate(items):
            goal = goals[i]
            r = item.blend_radius
            try:
                piece_qs, piece_us, curve, q_goal_i, tangents = self._item(i, item, here, goal, q_goal, r_prev, r)
            except PlanError as exc:
                if "item" in exc.details:
                    raise
                raise PlanError(exc.result, f"sequence item {i}: {exc.message}", item=i, **exc.details) from None
            piece_qs, piece_us = self._near_stops(i, curve, piece_qs, piece_us, i > 0 and r_prev == 0.0, r == 0.0)
            if pending is not None:  # the blend from the previous item's piece into this one's
                self._blend(pending, (piece_qs[0], tangents[0]), i - 1, i, qs, seg_of, fraction, segments, seg_item)
                qs.append(piece_qs[0])
                seg_of.append(seg_of[-1])
                fraction.append(1.0)
            seg = len(segments)
            segments[seg] = curve
            seg_item[seg] = i
            qs.extend(piece_qs[1:])
            seg_of.extend([seg] * (len(piece_qs) - 1))
            fraction.extend(piece_us[1:])
            pending = (piece_qs[-1], tangents[1]) if r > 0.0 else None
            paths.append(JointLine(self.ik.fk, q_goal, q_goal_i, 0.0, 1.0) if item.motion == "ptp" else curve.curve)
            q_goal, r_prev, here = q_goal_i, r, goal
        # drop repeated samples (a piece of no length)
        keep = [0] + [k for k in range(1, len(qs)) if float(np.max(np.abs(qs[k] - qs[k - 1]))) > 1e-9]
        qs = [qs[k] for k in keep]
        seg_of = [seg_of[k] for k in keep]
        fraction = [fraction[k] for k in keep]
        if len(qs) < 2:
            raise PlanError(PlanResult.REPEATED_WAYPOINT, "the sequence does not move: the tool is at every goal")
        try:
            tool = self.poses._verified(segments, qs, seg_of, fraction)
        except PlanError as exc:
            seg = int(exc.details.get("pose", 0))  # type: ignore[call-overload]
            i = seg_item.get(seg, 0)
            details = {k: v for k, v in exc.details.items() if k != "pose"}
            raise PlanError(exc.result, f"sequence item {i}: {exc.message}", item=i, **details) from None
        item_of = np.array([seg_item.get(int(s), 0) for s in tool.pose_of])
        item_end = [int(np.flatnonzero(item_of <= i)[-1]) for i in range(len(items))]
        radii = [item.blend_radius for item in items]
        return SequencePath(ToolPath(tool.path, item_of, tool.fraction, MoveKind.LINEAR), item_end, goals, paths, radii)

    def deviations(
        self, sequence: SequencePath, qs: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """For joint positions ``qs`` (M, dof) along a sequence's motion: the tool's distance to the
        nearest item path [m], its orientation's distance from that path's [rad], and whether it is
        outside every blend sphere (where it must be on the paths). A ptp item's tool path is its
        joint line's, sampled every PTP_CHECK_STEP."""
        tol = self.poses.tolerance
        centers = [g.translation for g, r in zip(sequence.goals, sequence.radii, strict=True) if r > 0.0]
        radii = [r for r in sequence.radii if r > 0.0]
        dp_out, dr_out, outside = [], [], []
        for q in np.asarray(qs, dtype=float):
            placement = self.ik.fk(q)
            p = placement.translation
            best = (math.inf, 0.0)
            for path in sequence.paths:
                dp, dr, _ = path.deviation(placement, tol)
                if dp < best[0]:
                    best = (dp, dr)
            dp_out.append(best[0])
            dr_out.append(best[1])
            outside.append(all(float(np.linalg.norm(p - c)) > r for c, r in zip(centers, radii, strict=True)))
        return np.array(dp_out), np.array(dr_out), np.array(outside)

    def _item(
        self,
        i: int,
        item: SequenceItem,
        here: pin.SE3,
        goal: pin.SE3,
        q_here: NDArray[np.float64],
        r_in: float,
        r_out: float,
    ) -> tuple[list[NDArray[np.float64]], list[float], Any, NDArray[np.float64], tuple[NDArray, NDArray]]:
        """Item i's samples between the sphere it starts in (r_in) and the one it ends in (r_out):
        (joint samples, their u on the piece, the piece, the joint goal, joint tangents d q/du at both ends)."""
        if item.motion == "ptp":
            return self._ptp(i, item, goal, q_here, r_in, r_out, here)
        curve: ToolLine | ToolArc
        curve = ToolLine(here, goal) if item.motion == "lin" else ToolArc.through(i, here, goal, item.via, item.center)
        p0, p1 = here.translation, goal.translation
        u_in = _crossing(lambda u: float(np.linalg.norm(curve.at(u).translation - p0)), r_in, False) if r_in else 0.0
        # the march goes on to the goal: its end is where the next item starts from (the same branch)
        march = Piece(curve, u_in, 1.0)
        q_start = q_here if u_in == 0.0 else self._solve(i, curve.at(u_in), q_here)
        us, line_qs = self.poses._sample_line(march, q_start, i)
        q_goal = line_qs[-1]
        u_glob = [u_in + u * (1.0 - u_in) for u in us]
        u_out = 1.0
        if r_out > 0.0:
            u_out = _crossing(lambda u: float(np.linalg.norm(curve.at(u).translation - p1)), r_out, True)
        keep = [k for k, u in enumerate(u_glob) if u < u_out - 1e-9]
        piece_qs = [line_qs[k] for k in keep]
        if u_out < 1.0:
            seed = line_qs[keep[-1] + 1] if keep[-1] + 1 < len(line_qs) else piece_qs[-1]
            piece_qs.append(self._solve(i, curve.at(u_out), seed))
        else:
            piece_qs.append(q_goal)
        u_keep = [u_glob[k] for k in keep] + [u_out]
        piece = Piece(curve, u_in, u_out)
        piece_us = [(u - u_in) / (u_out - u_in) for u in u_keep]
        t0 = self._rate(piece, 0.0, piece_qs[0])
        t1 = self._rate(piece, 1.0, piece_qs[-1])
        return piece_qs, piece_us, piece, q_goal, (t0, t1)

    def _near_stops(
        self, i: int, piece: Any, qs: list[NDArray[np.float64]], us: list[float], at_start: bool, at_end: bool
    ) -> tuple[list[NDArray[np.float64]], list[float]]:
        """Samples added close to an exact stop (a corner of the path): the joint path's spline
        through a corner overshoots it by a share of the neighbouring samples' distance, so the
        samples next to it are STOP_SAMPLES away (a reversal, LIN down then up, would otherwise
        overshoot the goal by more than the tolerance)."""
        if piece.length <= 0.0:
            return qs, us
        extra = []
        for d in STOP_SAMPLES:
            f = d / piece.length
            if f >= 0.25:
                continue
            if at_start:
                extra.append(f)
            if at_end:
                extra.append(1.0 - f)
        if not extra:
            return qs, us
        pairs = list(zip(us, qs, strict=True))
        for u in extra:
            k = int(np.argmin([abs(u - x) for x in us]))
            if abs(us[k] - u) < 0.25 * min(STOP_SAMPLES) / piece.length:
                continue
            q = piece.joints(u) if isinstance(piece, JointLine) else self._solve(i, piece.at(u), qs[k])
            pairs.append((u, q))
        pairs.sort(key=lambda x: x[0])
        return [q for _, q in pairs], [u for u, _ in pairs]

    def _rate(self, piece: Piece, u: float, q: NDArray[np.float64]) -> NDArray[np.float64]:
        from pvtflow.planner.ik import joint_rates

        sol = self.ik.solve(piece.at(u), q)
        jac = sol.jacobian if sol.jacobian is not None else self.ik.solve(piece.at(u), q).jacobian
        return joint_rates(jac, piece.twist(u), self.ik.options.damping)

    def _solve(self, i: int, placement: pin.SE3, seed: NDArray[np.float64]) -> NDArray[np.float64]:
        sol = self.ik.solve(placement, seed)
        if sol.ok and sol.sigma_min >= self.ik.options.singular_value:
            return sol.q
        raise _refuse(i, "the path at its blend sphere is out of reach or singular", CartesianResult.UNREACHABLE)

    def _ptp(
        self,
        i: int,
        item: SequenceItem,
        goal: pin.SE3,
        q_here: NDArray[np.float64],
        r_in: float,
        r_out: float,
        here: pin.SE3,
    ) -> tuple[list[NDArray[np.float64]], list[float], Any, NDArray[np.float64], tuple[NDArray, NDArray]]:
        if item.target is not None:
            q_goal = item.target
        else:
            found = self.poses._solve_anywhere(goal, q_here)
            if found is None:
                xyz = ", ".join(f"{x:.4g}" for x in goal.translation)
                raise _refuse(
                    i,
                    f"the pose is out of the arm's reach within its joint limits (at [{xyz}] m)",
                    CartesianResult.UNREACHABLE,
                )
            q_goal = found
        step = q_goal - q_here

        def q_at(u: float) -> NDArray[np.float64]:
            return q_here + u * step

        p0, p1 = here.translation, goal.translation
        u_in = _crossing(lambda u: float(np.linalg.norm(self._position(q_at(u)) - p0)), r_in, False) if r_in else 0.0
        u_out = _crossing(lambda u: float(np.linalg.norm(self._position(q_at(u)) - p1)), r_out, True) if r_out else 1.0
        span = max(u_out - u_in, 0.0)
        n = max(1, math.ceil(float(np.max(np.abs(step))) * span / PTP_STEP))
        us = list(np.linspace(0.0, 1.0, n + 1))
        qs = [q_at(u_in + u * span) for u in us]
        return qs, us, JointLine(self.ik.fk, q_here, q_goal, u_in, u_in + span), q_goal, (step * span, step * span)

    def _blend(
        self,
        a: tuple[NDArray[np.float64], NDArray[np.float64]],
        b: tuple[NDArray[np.float64], NDArray[np.float64]],
        item_a: int,
        item_b: int,
        qs: list[NDArray[np.float64]],
        seg_of: list[int],
        fraction: list[float],
        segments: dict[int, Any],
        seg_item: dict[int, int],
    ) -> None:
        """The joint-space cubic Hermite from a (end of item_a's piece) to b (start of item_b's):
        its tangents point along both paths, scaled so that the tool moves as far along them per
        unit of the curve's parameter as the chord between the two points is long. Its first half
        counts as item_a's, its second as item_b's."""
        (qa, da), (qb, db) = a, b
        pa, pb = self._position(qa), self._position(qb)
        chord = float(np.linalg.norm(pb - pa))
        # a reversal (the next item leaves back along the way it came) has no chord: a blend of the radius
        scale = max(chord, 1e-3)
        ta = da * (scale / max(self._tool_rate(qa, da), 1e-12))
        tb = db * (scale / max(self._tool_rate(qb, db), 1e-12))
        span = float(np.max(np.abs(qb - qa))) + 0.25 * float(np.max(np.abs(ta)) + np.max(np.abs(tb)))
        n = max(MIN_BLEND_SAMPLES, 2 * math.ceil(0.5 * span / BLEND_STEP))
        first, second = len(segments), len(segments) + 1
        segments[first], segments[second] = Unchecked(), Unchecked()
        seg_item[first], seg_item[second] = item_a, item_b
        for k in range(1, n):
            w = k / n
            h00, h10, h01, h11 = 2 * w**3 - 3 * w**2 + 1, w**3 - 2 * w**2 + w, -2 * w**3 + 3 * w**2, w**3 - w**2
            qs.append(h00 * qa + h10 * ta + h01 * qb + h11 * tb)
            seg_of.append(first if w <= 0.5 else second)
            fraction.append(w)
        seg_of[-1] = second  # the interval into b below is the second half's

    def _tool_rate(self, q: NDArray[np.float64], d: NDArray[np.float64]) -> float:
        """How fast the tool point moves along joint direction d at q (m per unit of d)."""
        eps = 1e-6 / max(float(np.max(np.abs(d))), 1e-12)
        return float(np.linalg.norm(self._position(q + eps * d) - self._position(q))) / eps


__all__ = ["MOTIONS", "SequenceItem", "SequencePath", "SequenceSolver", "ToolArc", "check_items"]
