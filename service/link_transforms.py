"""Every link of the robot in the world frame for a batch of joint positions at once.

The recording's ``/tf`` and the live view at rest (service/recording, service/live_rest.py) need
the links' placements for many samples; Pinocchio's ``framesForwardKinematics`` takes one
configuration per call, and the quaternion of each frame another call each. Here the chain is
walked once per batch with numpy: for each joint, parent placement x the joint's fixed placement
x its motion (a rotation about, or a translation along, its axis), all samples at once; then each
body frame's fixed placement on its joint, and the rotations as quaternions. The model's facts
(tree, placements, axes) are Pinocchio's own (``RobotModel.model``); a joint of another kind than
revolute or prismatic about one axis falls back on Pinocchio per sample (``LinkTransforms.compute``
gives the same numbers either way: tests/service/test_link_transforms.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


class LinkTransforms:
    """``LinkTransforms(model, joints).compute(q)``: q (batch, len(joints)) in the given joint order ->
    the names of the body frames and their translations (batch, frames, 3) and quaternions
    (batch, frames, 4: x, y, z, w) in the world frame."""

    def __init__(self, robot: Any, joints: tuple[str, ...]) -> None:
        import pinocchio as pin

        self._pin = pin
        self._robot = robot
        model = robot.model
        self._model = model
        self._column = np.array([robot.index(j) for j in joints])  # q's columns in the model's order
        self._dof = robot.dof
        self.frames = tuple(f.name for f in model.frames if f.type == pin.FrameType.BODY)
        self._frame_ids = [i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY]
        self._joints: list[tuple[int, int, str, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = []
        self.vectorised = True
        for i in range(1, model.njoints):
            kind, axis = _kind_and_axis(model.joints[i])
            if kind is None:
                self.vectorised = False
                break
            placement = model.jointPlacements[i]
            self._joints.append(
                (i, model.parents[i], kind, np.asarray(axis), placement.rotation.copy(), placement.translation.copy())
            )
            if model.joints[i].nq != 1:
                self.vectorised = False
        self._q_index = [model.joints[i].idx_q for i in range(model.njoints)]
        self._frame_parent = [model.frames[f].parentJoint for f in self._frame_ids]
        self._frame_rotation = np.array([model.frames[f].placement.rotation for f in self._frame_ids])
        self._frame_translation = np.array([model.frames[f].placement.translation for f in self._frame_ids])

    def compute(self, q: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        full = np.zeros((len(q), self._dof))
        full[:, self._column] = q
        if not self.vectorised:
            return self._per_sample(full)
        batch = len(q)
        rotation = {0: np.broadcast_to(np.eye(3), (batch, 3, 3))}
        translation = {0: np.zeros((batch, 3))}
        for i, parent, kind, axis, fixed_r, fixed_t in self._joints:
            r = rotation[parent] @ fixed_r
            t = translation[parent] + rotation[parent] @ fixed_t
            value = full[:, self._q_index[i]]
            if kind == "R":
                r = r @ _rotations(axis, value)
            else:
                t = t + (r @ axis) * value[:, None]
            rotation[i], translation[i] = r, t
        r = np.stack([rotation[p] for p in self._frame_parent], axis=1)  # (batch, frames, 3, 3)
        t = np.stack([translation[p] for p in self._frame_parent], axis=1)
        world_t = t + np.einsum("bfij,fj->bfi", r, self._frame_translation)
        world_r = np.einsum("bfij,fjk->bfik", r, self._frame_rotation)
        return world_t, _quaternions(world_r)

    def _per_sample(self, full: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pin, model = self._pin, self._model
        data = model.createData()
        t = np.zeros((len(full), len(self._frame_ids), 3))
        r = np.zeros((len(full), len(self._frame_ids), 3, 3))
        for b, q in enumerate(full):
            pin.framesForwardKinematics(model, data, q)
            for k, fid in enumerate(self._frame_ids):
                t[b, k], r[b, k] = data.oMf[fid].translation, data.oMf[fid].rotation
        return t, _quaternions(r)


def _kind_and_axis(joint: Any) -> tuple[str | None, tuple[float, ...]]:
    name = joint.shortname()
    for kind, prefix in (("R", "JointModelR"), ("P", "JointModelP")):
        if name in (f"{prefix}X", f"{prefix}Y", f"{prefix}Z"):
            return kind, _AXES[name[-1]]
    if name in ("JointModelRevoluteUnaligned", "JointModelPrismaticUnaligned"):
        return name[10], tuple(float(v) for v in joint.axis)
    return None, ()


def _rotations(axis: NDArray[np.float64], angle: NDArray[np.float64]) -> NDArray[np.float64]:
    """(batch, 3, 3): rotations by ``angle`` about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _quaternions(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 4) unit quaternions x, y, z, w (w >= 0) of rotation matrices (..., 3, 3), by the
    largest of the four diagonal combinations (numerically safe for every rotation)."""
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    candidates = np.stack(
        (1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22, 1.0 + m00 + m11 + m22), axis=-1
    )
    which = np.argmax(candidates, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(candidates, which[..., None], axis=-1)[..., 0], 1e-300))
    q = np.empty((*r.shape[:-2], 4))
    d21, d02, d10 = r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]
    a01, a02, a12 = r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1]
    rows = (
        (0.25 * s, a01 / s, a02 / s, d21 / s),
        (a01 / s, 0.25 * s, a12 / s, d02 / s),
        (a02 / s, a12 / s, 0.25 * s, d10 / s),
        (d21 / s, d02 / s, d10 / s, 0.25 * s),
    )
    for k, row in enumerate(rows):
        mask = which == k
        for c in range(4):
            q[..., c] = np.where(mask, row[c], q[..., c]) if k else row[c]
    q *= np.where(q[..., 3:4] < 0.0, -1.0, 1.0)
    return q
