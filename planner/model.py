"""The robot as Pinocchio sees it: joint order, URDF limits, kinematics and inverse dynamics."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray


class ModelError(ValueError):
    """The URDF cannot be used as a pvtflow robot."""


@dataclass(frozen=True)
class JointInfo:
    name: str
    kind: str  # "revolute" | "prismatic"
    lower: float
    upper: float
    velocity: float  # inf where the URDF gives none
    effort: float  # inf where the URDF gives none


class RobotModel:
    """A Pinocchio model whose every joint is one actuated axis (revolute or prismatic).

    Joints are kept in Pinocchio's order (the URDF's tree order); ``index(name)`` maps a joint
    name to its column in every q, qd, qdd this class takes or returns.
    """

    def __init__(self, model: pin.Model, source: str = "") -> None:
        self.model = model
        self.data = model.createData()
        self.source = source
        if model.nq != model.nv:
            raise ModelError(
                f"{source}: continuous, floating or spherical joints are not axes; "
                "every joint must be revolute or prismatic"
            )
        joints: list[JointInfo] = []
        for jid in range(1, model.njoints):
            joint = model.joints[jid]
            if joint.nq != 1:
                raise ModelError(f"{source}: joint {model.names[jid]!r} has {joint.nq} coordinates; only 1-DoF joints")
            shortname = joint.shortname()
            kind = "prismatic" if shortname.startswith(("JointModelP", "JointModelPrismatic")) else "revolute"
            i = joint.idx_q
            vel = float(model.velocityLimit[joint.idx_v])
            eff = float(model.effortLimit[joint.idx_v])
            joints.append(
                JointInfo(
                    name=model.names[jid],
                    kind=kind,
                    lower=float(model.lowerPositionLimit[i]),
                    upper=float(model.upperPositionLimit[i]),
                    velocity=vel if vel > 0 and np.isfinite(vel) else np.inf,
                    effort=eff if eff > 0 and np.isfinite(eff) else np.inf,
                )
            )
        self.joints: tuple[JointInfo, ...] = tuple(joints)
        self._index = {j.name: k for k, j in enumerate(joints)}
        # batched RNEA (one Pinocchio call for a whole grid), created on first use
        self._pool: pin.ModelPool | None = None
        self._probe_pools: dict[tuple[int, bool], pin.ModelPool] = {}

    @classmethod
    def from_urdf(cls, path: str | Path) -> RobotModel:
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"{path}: URDF file not found")
        try:
            model = pin.buildModelFromUrdf(str(path))
        except (RuntimeError, ValueError) as exc:
            raise ModelError(f"{path}: not a readable URDF ({exc})") from None
        return cls(model, str(path))

    @classmethod
    def from_urdf_string(cls, text: str, source: str = "<urdf>") -> RobotModel:
        try:
            model = pin.buildModelFromXML(text)
        except (RuntimeError, ValueError) as exc:
            raise ModelError(f"{source}: not a readable URDF ({exc})") from None
        return cls(model, source)

    # --- joints ------------------------------------------------------------------------------
    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def index(self, joint_name: str) -> int:
        try:
            return self._index[joint_name]
        except KeyError:
            raise KeyError(f"unknown joint {joint_name!r} (the robot has {', '.join(self.joint_names)})") from None

    @property
    def has_dynamics(self) -> bool:
        """True when torque limits mean something: every joint has an effort limit and the links mass."""
        masses = [inertia.mass for inertia in self.model.inertias[1:]]
        return all(np.isfinite(j.effort) for j in self.joints) and sum(masses) > 0

    # --- kinematics and dynamics ----------------------------------------------------------------
    def frame_id(self, frame: str) -> int:
        if not self.model.existFrame(frame):
            raise KeyError(f"unknown frame {frame!r}")
        return self.model.getFrameId(frame)

    def frame_placement(self, q: ArrayLike, frame: str) -> NDArray[np.float64]:
        """4x4 homogeneous transform of ``frame`` in the world at configuration q."""
        fid = self.frame_id(frame)
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return self.data.oMf[fid].homogeneous.copy()

    def frame_jacobian(self, q: ArrayLike, frame: str) -> NDArray[np.float64]:
        """6xN Jacobian of ``frame``'s origin, linear part first, in world-aligned axes."""
        fid = self.frame_id(frame)
        q = np.asarray(q, dtype=float)
        return pin.computeFrameJacobian(self.model, self.data, q, fid, pin.LOCAL_WORLD_ALIGNED).copy()

    def frame_speeds(self, q: ArrayLike, qd: ArrayLike, frame: str) -> NDArray[np.float64]:
        """|linear velocity| of ``frame``'s origin for each row of q, qd (what a TCP speed limit needs,
        hundreds of times per plan): one batched RNEA, no Python loop.

        A unit point mass at the frame's origin, and nothing else, has the mass matrix J^T J (J the
        origin's linear Jacobian): its kinetic energy is |J qd|^2 / 2. So |v|^2 = qd . M(q) qd with
        M(q) qd = rnea(q, 0, qd) of that model without gravity: exact, and batched by Pinocchio.
        """
        q, qd = self._rows(q), self._rows(qd)
        m_qd = self._rnea_rows(self._probe_pool(self.frame_id(frame), rotation=False), q, np.zeros_like(qd), qd)
        return np.sqrt(np.maximum(np.einsum("ij,ij->i", qd, m_qd), 0.0))

    def frame_angular_speeds(self, q: ArrayLike, qd: ArrayLike, frame: str) -> NDArray[np.float64]:
        """|angular velocity| of ``frame`` for each row of q, qd: the same batched RNEA as
        ``frame_speeds``, on a model whose only inertia is a unit rotational one (no mass) on the
        frame's body: its kinetic energy is |omega|^2 / 2, whatever the body's orientation."""
        q, qd = self._rows(q), self._rows(qd)
        m_qd = self._rnea_rows(self._probe_pool(self.frame_id(frame), rotation=True), q, np.zeros_like(qd), qd)
        return np.sqrt(np.maximum(np.einsum("ij,ij->i", qd, m_qd), 0.0))

    def mass_matrix_bound(self) -> float:
        """An upper bound on |M(q) v| / |v| (the largest eigenvalue of the mass matrix) at every q
        within the position limits: what a change of the joint accelerations alone can change the
        torques by (planner.constraints.TorqueCheck). inf where the limits leave it unbounded.

        M(q) = sum over bodies l of J_l^T G_l J_l (J_l: body l's spatial Jacobian in its own frame,
        G_l its spatial inertia there, a constant), so |M| <= sum_l max eig(G_l) |J_l|_F^2. The
        column of J_l for joint k (k = l or an ancestor) is the joint's unit twist seen from body
        l's origin: a revolute joint's (axis, axis x (o_l - o_k)) has |.|^2 <= 1 + |o_l - o_k|^2,
        a prismatic joint's (0, axis) 1; and |o_l - o_k| is at most the sum, over the joints
        between them, of each one's placement offset (plus its stroke, for a prismatic one)."""
        model = self.model
        reach = np.zeros(model.njoints)
        for jid in range(1, model.njoints):
            reach[jid] = np.linalg.norm(model.jointPlacements[jid].translation)
            if self.joints[jid - 1].kind == "prismatic":
                reach[jid] += max(abs(self.joints[jid - 1].lower), abs(self.joints[jid - 1].upper))
        total = 0.0
        for body in range(1, model.njoints):
            columns, distance, k = 0.0, 0.0, body
            while k > 0:
                columns += 1.0 + distance * distance
                distance += reach[k]
                k = model.parents[k]
            total += float(np.linalg.eigvalsh(model.inertias[body].matrix()).max()) * columns
        return total if np.isfinite(total) else math.inf

    def inverse_dynamics(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> NDArray[np.float64]:
        """Joint torques/forces (RNEA) needed for qdd at (q, qd), gravity included."""
        return pin.rnea(
            self.model, self.data, np.asarray(q, dtype=float), np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)
        ).copy()

    def inverse_dynamics_rows(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> NDArray[np.float64]:
        """``inverse_dynamics`` for each row of (n, dof) q, qd, qdd, in one Pinocchio call: a torque
        constraint needs three RNEAs per gridpoint, and a Python call per RNEA costs more than the RNEA."""
        if self._pool is None:
            self._pool = pin.ModelPool(self.model, 1)
        return self._rnea_rows(self._pool, self._rows(q), self._rows(qd), self._rows(qdd))

    # --- helpers -------------------------------------------------------------------------------
    def _rows(self, x: ArrayLike) -> NDArray[np.float64]:
        x = np.ascontiguousarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.dof:
            raise ValueError(f"expected an (n, {self.dof}) array, got shape {x.shape}")
        return x

    @staticmethod
    def _rnea_rows(
        pool: pin.ModelPool, q: NDArray[np.float64], qd: NDArray[np.float64], qdd: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        if not (q.shape == qd.shape == qdd.shape):
            raise ValueError(f"q, qd, qdd must have the same shape, got {q.shape}, {qd.shape}, {qdd.shape}")
        tau = np.empty_like(q)
        if len(q):
            # (n, dof) C-ordered rows are Pinocchio's column-major (dof, n) batch: no copies
            pin.rneaInParallel(1, pool, q.T, qd.T, qdd.T, tau.T)
        return tau

    def _probe_pool(self, fid: int, rotation: bool) -> pin.ModelPool:
        """A copy of the model with no inertia and no gravity but, on frame ``fid``'s body, a unit
        point mass at the frame's origin (``frame_speeds``) or, with ``rotation``, a unit rotational
        inertia without mass (``frame_angular_speeds``)."""
        pool = self._probe_pools.get((fid, rotation))
        if pool is None:
            frame = self.model.frames[fid]
            model = pin.Model(self.model)
            model.gravity = pin.Motion.Zero()
            for jid in range(model.njoints):
                model.inertias[jid] = pin.Inertia.Zero()
            if rotation:
                probe = pin.Inertia(0.0, np.zeros(3), np.eye(3))
            else:
                probe = pin.Inertia(1.0, frame.placement.translation.copy(), np.zeros((3, 3)))
            model.inertias[frame.parentJoint] = probe
            pool = self._probe_pools[(fid, rotation)] = pin.ModelPool(model, 1)
        return pool
