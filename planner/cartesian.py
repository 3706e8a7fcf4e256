"""Tool poses -> joint waypoints: straight tool lines (or joint moves) solved with inverse kinematics.

A pose is ``[x, y, z, qx, qy, qz, qw]`` of the tool frame in the robot's base frame (m, unit
quaternion). A *linear* motion moves the tool on the straight line from where it is to the first
pose, then from pose to pose, its orientation turning by slerp along each line. The line is
turned into joint waypoints by inverse kinematics (planner/ik.py), each solution seeded from the
previous one along the line, so the arm never changes branch mid-line. The samples are placed
adaptively: a step along the line is kept when the tool, at the joint-space midpoint of the step,
is within ``LineTolerance`` of the line (and no joint turns more than ``MAX_JOINT_STEP`` over it),
else it is shortened. The joint path (planner/path.py) passes through every sample; its
cubic pieces follow the joint-space curve closer than the straight joint interpolation this
check bounds.

A *joint* motion solves each pose once (seeded from the previous solution; other seeds only when
that fails) and hands the solutions on as waypoints.

What cannot be done is refused with a :class:`CartesianResult` that names the pose and how far
along the line towards it (``fraction``) it failed; nothing is planned then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, StrEnum

import numpy as np
import pinocchio as pin
from numba import njit
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.ik import IkSolution, IkSolver, IkStatus, joint_rates
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.path import JointPath, PlanError, PlanResult

POSE_LENGTH = 7  # x, y, z, qx, qy, qz, qw
# A quaternion whose norm is this close to 1 is normalized; further off, it is refused (a typo, or
# a quaternion in another convention), rather than silently turned into some other orientation.
QUATERNION_TOLERANCE = 1e-3
# The first step along a line is no longer than these (later steps adapt to the tolerance).
MAX_LINE_STEP = 0.05  # m
MAX_TURN_STEP = 0.25  # rad
# No joint turns more than this between two samples (a branch change shows as a large joint step
# for a small tool step: halving never ends it, and the line is refused as singular).
MAX_JOINT_STEP = 0.2  # rad or m
# The shortest step along a line (a fraction of it) before the line is refused.
MIN_LINE_STEP = 1e-5
# Rounds of adding samples where the joint path between two samples leaves the tolerance.
MAX_VERIFY_ROUNDS = 16
# Next to a corner the spline's error peaks between the quarter points it is checked at: checked
# against this share of the tolerance there.
CORNER_MARGIN = 0.9
# After the first check of the joint path, the intervals this close to an added sample are checked again.
RECHECK_SPAN = 4
# Seeds tried for a pose the previous solution does not lead to (joint motions, reachability).
RESTARTS = 24


class CartesianResult(Enum):
    """Why poses have no joint path (PlanError.result; the values are the service's result codes).

    Kept next to the code that finds them: planner/path.py's PlanResult holds the joint-space
    outcomes.
    """

    UNREACHABLE = "unreachable"  # a pose, or a stretch of a line, out of the arm's reach
    SINGULAR = "singular"  # a line through (or too close to) a singularity, or a change of branch
    JOINT_LIMIT = "joint_limit"  # a line that needs a joint past its position limit


class MoveKind(StrEnum):
    """How the tool goes from pose to pose (a plan request's ``motion``)."""

    LINEAR = "linear"  # straight lines, orientation by slerp
    JOINT = "joint"  # a joint path through the inverse-kinematics solutions


@dataclass(frozen=True)
class LineTolerance:
    """How far the tool may be from the commanded line between two samples of the joint path."""

    position: float = 5e-5  # m (0.05 mm)
    orientation: float = math.radians(0.05)  # rad


def check_poses(poses: ArrayLike) -> NDArray[np.float64]:
    """The poses as an (N, 7) array with unit quaternions, or a PlanError naming the pose at fault."""
    try:
        p = np.array(poses, dtype=float)
    except (TypeError, ValueError):
        raise PlanError(PlanResult.INVALID_INPUT, "poses must be a list of [x, y, z, qx, qy, qz, qw]") from None
    if p.size == 0:
        raise PlanError(PlanResult.INVALID_INPUT, "poses: at least one pose is needed")
    if p.ndim != 2 or p.shape[1] != POSE_LENGTH:
        shape = p.shape[1] if p.ndim == 2 else p.shape
        raise PlanError(
            PlanResult.INVALID_INPUT,
            f"each pose is [x, y, z, qx, qy, qz, qw] (7 numbers), got {shape}",
        )
    bad = np.argwhere(~np.isfinite(p))
    if len(bad):
        i, j = (int(x) for x in bad[0])
        raise PlanError(PlanResult.INVALID_INPUT, f"pose {i}[{j}]: {p[i, j]} is not a finite number", pose=i)
    norms = np.linalg.norm(p[:, 3:], axis=1)
    off = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
    if len(off):
        i = int(off[0])
        raise PlanError(
            PlanResult.INVALID_INPUT,
            f"pose {i}: the quaternion [qx, qy, qz, qw] has norm {norms[i]:.6g}, not 1 "
            f"(within {QUATERNION_TOLERANCE:g})",
            pose=i,
            norm=float(norms[i]),
        )
    p[:, 3:] /= norms[:, None]
    return p


def pose_placement(pose: ArrayLike) -> pin.SE3:
    """[x, y, z, qx, qy, qz, qw] (unit quaternion) -> a Pinocchio SE3."""
    v = np.asarray(pose, dtype=float)
    return pin.XYZQUATToSE3(v)


def placement_pose(placement: pin.SE3) -> NDArray[np.float64]:
    """A Pinocchio SE3 -> [x, y, z, qx, qy, qz, qw] (qw >= 0)."""
    v = np.asarray(pin.SE3ToXYZQUAT(placement), dtype=float)
    if v[6] < 0.0:
        v[3:] = -v[3:]
    return v


class ToolLine:
    """The commanded motion from placement ``a`` to ``b``: position on the straight line, the
    orientation turning about one fixed axis (slerp), both in step with one parameter u in [0, 1]."""

    def __init__(self, a: pin.SE3, b: pin.SE3) -> None:
        self.a, self.b = a.copy(), b.copy()
        self.start = a.translation.copy()
        self.offset = b.translation - a.translation
        self.length = float(np.linalg.norm(self.offset))
        self.turn = pin.log3(a.rotation.T @ b.rotation)  # rotation vector, in a's axes
        self.angle = float(np.linalg.norm(self.turn))

    def at(self, u: float) -> pin.SE3:
        """The commanded placement at u."""
        return pin.SE3(self.a.rotation @ pin.exp3(u * self.turn), self.start + u * self.offset)

    def twist(self, u: float) -> NDArray[np.float64]:
        """d/du of the commanded placement at u, in its own axes (linear, angular): R(u)^T times the
        offset, and the turn (R(u) = R_a exp(u turn) turns about the same body axis throughout)."""
        rotation = self.a.rotation @ pin.exp3(u * self.turn)
        return np.concatenate((rotation.T @ self.offset, self.turn))

    def deviation(self, placement: pin.SE3, tolerance: LineTolerance) -> tuple[float, float, float]:
        """How far ``placement`` is from the line: (position m, orientation rad, u).

        u is the placement's progress along the line, from its position (projected on the line)
        and its orientation (projected on the turn), each weighted by how precisely it tells the
        progress (length / position tolerance, angle / orientation tolerance); the deviations are
        from the commanded placement at that u.
        """
        p = placement.translation
        u_p, w_p = 0.0, 0.0
        if self.length > 0.0:
            u_p = float(np.dot(p - self.start, self.offset)) / (self.length * self.length)
            w_p = (self.length / tolerance.position) ** 2
        u_r, w_r = 0.0, 0.0
        rel = self.a.rotation.T @ placement.rotation  # the orientation in a's axes
        if self.angle > 0.0:
            u_r = float(np.dot(pin.log3(rel), self.turn)) / (self.angle * self.angle)
            w_r = (self.angle / tolerance.orientation) ** 2
        u = (w_p * u_p + w_r * u_r) / (w_p + w_r) if w_p + w_r > 0.0 else 0.0
        u = min(max(u, 0.0), 1.0)
        dp = _distance(p, self.start + u * self.offset)
        dr = float(np.linalg.norm(pin.log3(pin.exp3(-u * self.turn) @ rel)))
        return dp, dr, u


@njit(cache=True)
def _distance(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


@dataclass(frozen=True)
class ToolPath:
    """The joint path of poses: ``path`` through N joint samples from the start on
    (``path.points``); ``pose_of[k]``: the index of the pose sample k moves towards (-1 for the
    start), ``fraction[k]``: how far along that line."""

    path: JointPath
    pose_of: NDArray[np.int64]
    fraction: NDArray[np.float64]
    motion: MoveKind


class PoseSolver:
    """Poses -> joint waypoints for one robot, its tool frame and its joint limits."""

    def __init__(self, ik: IkSolver, limits: JointLimits, tolerance: LineTolerance | None = None) -> None:
        self.ik = ik
        self.limits = limits
        self.tolerance = tolerance or LineTolerance()
        self._rng_seeds = self._restart_seeds()

    def _restart_seeds(self) -> NDArray[np.float64]:
        """Fixed seeds spread over the joint ranges (the same on every call: plans are repeatable)."""
        lo, hi = self.ik.lower, self.ik.upper
        rng = np.random.default_rng(14)
        mid = 0.5 * (lo + hi)
        return np.vstack((mid, lo + (hi - lo) * rng.uniform(0.1, 0.9, (RESTARTS, len(lo)))))

    def solve(self, start: ArrayLike, poses: ArrayLike, motion: MoveKind | str = MoveKind.LINEAR) -> ToolPath:
        """The joint waypoints of the motion from joint positions ``start`` through ``poses``."""
        motion = MoveKind(motion)
        p = check_poses(poses)
        q0 = np.asarray(start, dtype=float)
        if q0.shape != self.ik.lower.shape or not np.all(np.isfinite(q0)):
            raise PlanError(PlanResult.INVALID_INPUT, f"start must be {len(self.ik.lower)} finite joint values")
        targets = [pose_placement(v) for v in p]
        if motion is MoveKind.LINEAR:
            return self._linear(q0, targets)
        return self._joint(q0, targets)

    # --- linear ----------------------------------------------------------------------------------
    def _linear(self, q0: NDArray[np.float64], targets: list[pin.SE3]) -> ToolPath:
        qs, pose_of, fraction = [q0], [-1], [0.0]
        lines: dict[int, ToolLine] = {}
        here = self.ik.fk(q0)
        for i, target in enumerate(targets):
            line = ToolLine(here, target)
            if not self._moves(line):
                continue  # already there (e.g. the first pose is where the tool is)
            us, line_qs = self._sample_line(line, qs[-1], i)
            qs.extend(line_qs[1:])
            pose_of.extend([i] * (len(us) - 1))
            fraction.extend(us[1:])
            lines[i] = line
            here = target
        if len(qs) < 2:
            raise PlanError(PlanResult.REPEATED_WAYPOINT, "the tool is already at every pose: nothing to move")
        return self._verified(lines, qs, pose_of, fraction)

    def _verified(
        self, lines: dict[int, ToolLine], qs: list[NDArray[np.float64]], pose_of: list[int], fraction: list[float]
    ) -> ToolPath:
        """The joint path through the samples, with a sample added wherever the tool, halfway
        between two samples on that path, is not within tolerance of its line (the samples were
        placed on a cubic estimate of it: this checks the path itself).

        The first pass checks every interval; after it, the intervals within ``RECHECK_SPAN`` of an
        added sample (a cubic spline's change from one more knot fades by about 4x per interval).
        """
        tol = self.tolerance
        check = range(len(qs) - 1)
        for _ in range(MAX_VERIFY_ROUNDS):
            path = JointPath(np.array(qs), self.limits)
            s = path.waypoint_s
            # where two lines meet, the spline rounds the corner: its error peaks off the middle there
            corners = [j for j in range(1, len(qs) - 1) if pose_of[j] != pose_of[j + 1]]
            ks, fs, margin = [], [], []
            for k in check:
                near_corner = any(abs(k - j) <= 2 for j in corners)
                for f in (0.25, 0.5, 0.75) if near_corner else (0.5,):
                    ks.append(k)
                    fs.append(f)
                    margin.append(CORNER_MARGIN if near_corner else 1.0)
            k_arr, f_arr = np.array(ks, dtype=np.int64), np.array(fs)
            points = path(s[k_arr] + f_arr * (s[k_arr + 1] - s[k_arr]))
            bad: list[tuple[int, NDArray[np.float64]]] = []
            for k, q, m in zip(ks, points, margin, strict=True):
                if bad and bad[-1][0] == k:
                    continue  # this interval gets a sample anyway
                dp, dr, _ = lines[pose_of[k + 1]].deviation(self.ik.fk(q), tol)
                if dp > m * tol.position or dr > m * tol.orientation:
                    bad.append((k, path(0.5 * (s[k] + s[k + 1]))))
            if not bad:
                return ToolPath(path, np.array(pose_of), np.array(fraction), MoveKind.LINEAR)
            for k, q in reversed(bad):  # from the end: the indices before k stay valid
                pose = pose_of[k + 1]
                u0 = fraction[k] if pose_of[k] == pose else 0.0
                um = 0.5 * (u0 + fraction[k + 1])
                qm = self._solve_on_line(lines[pose], um, q, pose)
                qs.insert(k + 1, qm)
                pose_of.insert(k + 1, pose)
                fraction.insert(k + 1, um)
            # the added samples' new indices: bad[i] moved on by the i samples added before it
            added = [k + 1 + i for i, (k, _) in enumerate(bad)]
            near = {j for a in added for j in range(a - RECHECK_SPAN - 1, a + RECHECK_SPAN + 1)}
            check = sorted(j for j in near if 0 <= j < len(qs) - 1)
        k = bad[0][0]
        raise self._refusal(
            CartesianResult.SINGULAR,
            pose_of[k + 1],
            fraction[k + 1],
            "the joint path cannot be made to follow the line there (a sharp turn of the joints)",
        )

    def _moves(self, line: ToolLine) -> bool:
        return line.length > 0.1 * self.tolerance.position or line.angle > 0.1 * self.tolerance.orientation

    def _sample_line(
        self, line: ToolLine, q_start: NDArray[np.float64], pose: int
    ) -> tuple[list[float], list[NDArray[np.float64]]]:
        """Samples (u, q) along the line, q continuous from ``q_start``.

        An adaptive march: the next sample is solved from the last one (moved on by its joint rates
        along the line), and kept when the tool at the midpoint of the cubic between the two
        samples (Hermite: both positions, both joint rates; what the joint path's spline through
        them follows) is within tolerance of the line and no joint turned more than MAX_JOINT_STEP.
        The step then grows or shrinks by how close to the tolerance it came (a cubic's midpoint
        error goes as the step to the fourth).
        """
        tol, damping = self.tolerance, self.ik.options.damping
        h = 1.0 / max(1, math.ceil(max(line.length / MAX_LINE_STEP, line.angle / MAX_TURN_STEP)))
        us, qs = [0.0], [q_start]
        u, q = 0.0, q_start
        start = self.ik.solve(line.at(0.0), q_start)  # the Jacobian there (q_start is the solution)
        if start.jacobian is None:
            raise self._line_refusal(start, pose, 0.0)
        rate = joint_rates(start.jacobian, line.twist(0.0), damping)  # dq/du
        failure: IkSolution | None = None
        while u < 1.0:
            if h < MIN_LINE_STEP:
                raise self._stuck(line, failure, pose, u, q)
            fastest = float(np.max(np.abs(rate)))
            if fastest * h > 0.9 * MAX_JOINT_STEP:  # the joints' rates say how long a step may be
                h = 0.9 * MAX_JOINT_STEP / fastest
            u1 = min(1.0, u + h)
            d = u1 - u
            sol = self.ik.solve(line.at(u1), q + rate * d)
            if not sol.ok or sol.jacobian is None or sol.sigma_min < self.ik.options.singular_value:
                failure = sol
                h *= 0.25
                continue
            failure = None
            if float(np.max(np.abs(sol.q - q))) > MAX_JOINT_STEP:
                h *= 0.5
                continue
            rate1 = joint_rates(sol.jacobian, line.twist(u1), damping)
            mid = 0.5 * (q + sol.q) + (d / 8.0) * (rate - rate1)
            dp, dr, _ = line.deviation(self.ik.fk(mid), tol)
            ratio = max(dp / tol.position, dr / tol.orientation)
            grow = min(2.0, max(0.3, (0.6 / max(ratio, 1e-8)) ** 0.25))
            h *= grow
            if ratio > 1.0:
                continue
            u, q, rate = u1, sol.q, rate1
            us.append(u)
            qs.append(q)
        return us, qs

    def _solve_on_line(self, line: ToolLine, u: float, seed: NDArray[np.float64], pose: int) -> NDArray[np.float64]:
        sol = self.ik.solve(line.at(u), seed)
        if sol.ok and sol.sigma_min >= self.ik.options.singular_value:
            return sol.q
        raise self._stuck(line, sol, pose, u, seed)

    def _stuck(
        self, line: ToolLine, failure: IkSolution | None, pose: int, u: float, q: NDArray[np.float64]
    ) -> PlanError:
        """Why the march along ``line`` cannot go on from u (at q)."""
        if failure is not None:
            if not failure.ok and not self._reachable(line.b, q):
                return self._unreachable(pose, line.b)
            return self._line_refusal(failure, pose, u)
        return self._refusal(
            CartesianResult.SINGULAR,
            pose,
            u,
            "the arm cannot follow the line continuously there (a singularity or a change of branch: "
            f"smallest singular value of the Jacobian {self.ik.sigma_min(q):.2g})",
        )

    def _line_refusal(self, sol: IkSolution, pose: int, u: float) -> PlanError:
        names = self.ik.robot.joint_names
        if sol.status is IkStatus.JOINT_LIMIT and sol.joint is not None:
            return self._refusal(
                CartesianResult.JOINT_LIMIT,
                pose,
                u,
                f"the line needs joint {names[sol.joint]} past its position limit",
                joint=names[sol.joint],
            )
        if sol.status is IkStatus.SINGULAR or sol.sigma_min < self.ik.options.singular_value:
            return self._refusal(
                CartesianResult.SINGULAR,
                pose,
                u,
                f"the line passes through a singularity (smallest singular value of the Jacobian {sol.sigma_min:.2g})",
            )
        return self._refusal(
            CartesianResult.UNREACHABLE,
            pose,
            u,
            f"the line leaves the arm's reach (the closest solution is {sol.position_error * 1000:.3g} mm and "
            f"{math.degrees(sol.orientation_error):.3g} deg away)",
        )

    @staticmethod
    def _refusal(result: CartesianResult, pose: int, u: float, why: str, **details: object) -> PlanError:
        return PlanError(
            result,
            f"the tool line to pose {pose}, {100.0 * u:.1f} % of the way: {why}",
            pose=pose,
            fraction=round(float(u), 4),
            **details,
        )

    def _unreachable(self, pose: int, target: pin.SE3) -> PlanError:
        xyz = ", ".join(f"{x:.4g}" for x in target.translation)
        return PlanError(
            CartesianResult.UNREACHABLE,
            f"pose {pose} is out of the arm's reach within its joint limits (at [{xyz}] m)",
            pose=pose,
            fraction=1.0,
        )

    def _reachable(self, target: pin.SE3, seed: NDArray[np.float64]) -> bool:
        return self._solve_anywhere(target, seed) is not None

    def _solve_anywhere(self, target: pin.SE3, seed: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """A solution for ``target`` from ``seed``, else from the restart seeds (the one closest to
        ``seed``); None when none converges."""
        sol = self.ik.solve(target, seed)
        if sol.ok:
            return sol.q
        found = [s.q for s in (self.ik.solve(target, r) for r in self._rng_seeds) if s.ok]
        if not found:
            return None
        return min(found, key=lambda q: float(np.sum((q - seed) ** 2)))

    # --- joint -----------------------------------------------------------------------------------
    def _joint(self, q0: NDArray[np.float64], targets: list[pin.SE3]) -> ToolPath:
        qs, pose_of = [q0], [-1]
        here = self.ik.fk(q0)
        for i, target in enumerate(targets):
            if not self._moves(ToolLine(here, target)):
                continue
            q = self._solve_anywhere(target, qs[-1])
            if q is None:
                raise self._unreachable(i, target)
            qs.append(q)
            pose_of.append(i)
            here = target
        if len(qs) < 2:
            raise PlanError(PlanResult.REPEATED_WAYPOINT, "the tool is already at every pose: nothing to move")
        return ToolPath(JointPath(np.array(qs), self.limits), np.array(pose_of), np.ones(len(qs)), MoveKind.JOINT)


__all__ = [
    "POSE_LENGTH",
    "QUATERNION_TOLERANCE",
    "CartesianResult",
    "LineTolerance",
    "MoveKind",
    "PoseSolver",
    "ToolLine",
    "ToolPath",
    "check_poses",
    "placement_pose",
    "pose_placement",
]
