"""The robot as Pinocchio sees it: joint order, URDF limits, kinematics and inverse dynamics."""

from __future__ import annotations

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
        """|linear velocity| of ``frame``'s origin for each row of q, qd: one kinematics pass per row,
        no Jacobian matrix (what a TCP speed limit needs, many times per plan)."""
        fid = self.frame_id(frame)
        model, data = self.model, self.data
        out = np.empty(len(q))
        for k, (qk, vk) in enumerate(zip(np.asarray(q, dtype=float), np.asarray(qd, dtype=float), strict=True)):
            pin.forwardKinematics(model, data, qk, vk)
            out[k] = np.sqrt(np.dot(v := pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear, v))
        return out

    def inverse_dynamics(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> NDArray[np.float64]:
        """Joint torques/forces (RNEA) needed for qdd at (q, qd), gravity included."""
        return pin.rnea(
            self.model, self.data, np.asarray(q, dtype=float), np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)
        ).copy()
