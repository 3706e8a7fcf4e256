"""service/link_transforms.py: every link's placement for a batch of joint positions, as Pinocchio's
forward kinematics gives it one configuration at a time."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from pvtflow.service.config import CONFIG_DIR, load_cell_config
from pvtflow.service.link_transforms import LinkTransforms


@pytest.mark.parametrize("name", ["arm6", "gantry3"])
def test_a_batch_equals_pinocchio_sample_by_sample(name):
    cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
    joints = tuple(a.joint for a in cell.ordered_axes())
    links = LinkTransforms(cell.model, joints)
    assert links.vectorised
    lim = cell.joint_limits()
    q = np.random.default_rng(3).uniform(lim.lower, lim.upper, (40, len(joints)))
    translations, rotations = links.compute(q)
    model = cell.model.model
    data = model.createData()
    ids = [model.getFrameId(f) for f in links.frames]
    for b, row in enumerate(q):
        full = np.zeros(cell.model.dof)
        for joint, value in zip(joints, row, strict=True):
            full[cell.model.index(joint)] = value
        pin.framesForwardKinematics(model, data, full)
        for k, fid in enumerate(ids):
            assert translations[b, k] == pytest.approx(data.oMf[fid].translation, abs=1e-12)
            quat = pin.Quaternion(data.oMf[fid].rotation).coeffs()  # x, y, z, w
            sign = 1.0 if quat[3] >= 0 else -1.0
            assert rotations[b, k] == pytest.approx(sign * quat, abs=1e-12)
    assert {"base_link", "tool0"} <= set(links.frames)
