"""Inverse kinematics of the tool frame with Pinocchio: damped least squares, joint limits held.

One solve is Newton's method on the frame's pose error (``log6`` of the error transform, mapped by
``Jlog6`` onto the frame Jacobian), damped (Levenberg-Marquardt) so that a step near a singularity
stays bounded, with every iterate clipped into the joint position limits. The solver never jumps:
it walks from its seed, so a caller that seeds each solution with the previous one along a tool
line keeps the arm on one branch. How a solve ended is an :class:`IkStatus`, never an exception:
the caller (planner/cartesian.py) knows which pose and how far along the line, and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import pinocchio as pin
from numba import njit
from numpy.typing import ArrayLike, NDArray

from pvtflow.planner.model import RobotModel


class IkStatus(Enum):
    """How one inverse-kinematics solve ended."""

    CONVERGED = "converged"
    JOINT_LIMIT = "joint_limit"  # the pose needs a joint past its position limit
    SINGULAR = "singular"  # stuck where the Jacobian loses rank
    UNREACHABLE = "unreachable"  # no convergence from this seed (out of reach, or another branch)


@dataclass(frozen=True)
class IkOptions:
    position_tolerance: float = 1e-6  # m: a solution is this close to the target
    orientation_tolerance: float = 1e-5  # rad
    max_iterations: int = 60
    max_step: float = 0.5  # rad or m: the largest joint step of one iteration
    damping: float = 1e-6  # Levenberg-Marquardt damping added to J J^T
    # smallest singular value of the frame Jacobian (m/rad and rad/rad mixed: the tool's own scale)
    # below which a solution is a singularity: the joint speeds for a tool speed grow as 1 / sigma
    singular_value: float = 1e-3


@dataclass(frozen=True)
class IkSolution:
    q: NDArray[np.float64]
    status: IkStatus
    position_error: float  # m, |p - p_target|
    orientation_error: float  # rad, angle of R^T R_target
    iterations: int
    sigma_min: float  # smallest singular value of the frame Jacobian at q
    joint: int | None = None  # for JOINT_LIMIT: the joint held at its limit
    jacobian: NDArray[np.float64] | None = None  # 6 x dof frame Jacobian at q (LOCAL: the tool's own axes)

    @property
    def ok(self) -> bool:
        return self.status is IkStatus.CONVERGED


class IkSolver:
    """Solves for the pose of one frame of one robot inside joint position limits."""

    def __init__(
        self,
        model: RobotModel,
        frame: str,
        lower: ArrayLike,
        upper: ArrayLike,
        options: IkOptions | None = None,
    ) -> None:
        self.robot = model
        self.model = model.model
        self.data = self.model.createData()
        self.frame = frame
        self.fid = model.frame_id(frame)
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.options = options or IkOptions()

    def fk(self, q: ArrayLike) -> pin.SE3:
        """The frame's placement in the base frame at q."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.updateFramePlacement(self.model, self.data, self.fid).copy()

    def sigma_min(self, q: ArrayLike) -> float:
        """Smallest singular value of the frame Jacobian at q (0 at a singularity)."""
        pin.computeJointJacobians(self.model, self.data, np.asarray(q, dtype=float))
        return _sigma_min(pin.getFrameJacobian(self.model, self.data, self.fid, pin.LOCAL))

    def solve(self, target: pin.SE3, seed: ArrayLike) -> IkSolution:
        """Newton / damped least squares from ``seed`` towards ``target``, inside the limits."""
        opt = self.options
        model, data, fid = self.model, self.data, self.fid
        lower, upper = self.lower, self.upper
        q = np.clip(np.asarray(seed, dtype=float), lower, upper)
        jac = np.zeros((6, self.robot.dof))
        held = -1
        dp = dr = np.inf
        it = 0
        for it in range(opt.max_iterations + 1):
            pin.computeJointJacobians(model, data, q)  # forward kinematics included
            error = pin.updateFramePlacement(model, data, fid).actInv(target)  # identity when there
            err = pin.log6(error).vector  # (v, w): at the small errors that end a solve, v is the offset
            jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL)
            dp, dr = _norm3(err[:3]), _norm3(err[3:])
            if dp <= opt.position_tolerance and dr <= opt.orientation_tolerance:
                return IkSolution(q, IkStatus.CONVERGED, dp, dr, it, _sigma_min(jac), None, jac.copy())
            if it == opt.max_iterations:
                break
            q, held = _dls_step(pin.Jlog6(error.inverse()) @ jac, err, q, lower, upper, opt.damping, opt.max_step)
        sigma = _sigma_min(jac)
        if held >= 0:
            return IkSolution(q, IkStatus.JOINT_LIMIT, dp, dr, it, sigma, held)
        if sigma < opt.singular_value:
            return IkSolution(q, IkStatus.SINGULAR, dp, dr, it, sigma)
        return IkSolution(q, IkStatus.UNREACHABLE, dp, dr, it, sigma)


@njit(cache=True)
def joint_rates(jac: NDArray[np.float64], twist: NDArray[np.float64], damping: float) -> NDArray[np.float64]:
    """The joint rates that move the frame by ``twist`` (its own axes, like the LOCAL Jacobian ``jac``):
    damped least squares J^T (J J^T + lambda I)^-1 twist, exact where J has full rank."""
    return jac.T @ np.linalg.solve(jac @ jac.T + damping * np.eye(6), twist)


@njit(cache=True)
def _norm3(v: NDArray[np.float64]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


@njit(cache=True)
def _dls_step(
    jac: NDArray[np.float64],
    err: NDArray[np.float64],
    q: NDArray[np.float64],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    damping: float,
    max_step: float,
) -> tuple[NDArray[np.float64], int]:
    """One damped least-squares step J^T (J J^T + lambda I)^-1 e, clipped into the limits.

    A joint on a limit that the step pushes past it is held there and the step is solved again
    without it (else the clip would bend the step off the error's direction). Returns the new q and
    the first joint held (-1: none).
    """
    n = len(q)
    free = np.ones(n, dtype=np.bool_)
    held = -1
    for _ in range(n):
        j = jac[:, free]
        step_free = j.T @ np.linalg.solve(j @ j.T + damping * np.eye(6), err)
        step = np.zeros(n)
        step[free] = step_free
        pushed = -1
        for k in range(n):
            if free[k] and ((q[k] <= lower[k] and step[k] < 0.0) or (q[k] >= upper[k] and step[k] > 0.0)):
                pushed = k
                break
        if pushed < 0:
            break
        free[pushed] = False
        if held < 0:
            held = pushed
    largest = np.max(np.abs(step))
    if largest > max_step:  # far from the target the linearization is poor: a shorter step, same direction
        step = step * (max_step / largest)
    out = np.empty(n)
    for k in range(n):
        out[k] = min(max(q[k] + step[k], lower[k]), upper[k])
    return out, held


@njit(cache=True)
def _sigma_min(jac: NDArray[np.float64]) -> float:
    return np.linalg.svd(np.ascontiguousarray(jac))[1][-1]


__all__ = ["IkOptions", "IkSolution", "IkSolver", "IkStatus", "joint_rates"]
